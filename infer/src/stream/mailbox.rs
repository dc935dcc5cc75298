//! The one-frame handover between the capture thread and the network's thread.

use std::sync::{Condvar, Mutex, MutexGuard};

use super::Arrived;
use super::source::Delivery;

/// Most problems kept by text (the count goes on).
const PROBLEMS_KEPT: usize = 20;

/// What the capture side counted.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Counts {
    /// Frames that arrived: decoded, dropped or unreadable.
    pub arrived: u64,
    /// Stale frames dropped for newer ones (live sources).
    pub dropped: u64,
    /// Frames that could not be used.
    pub unreadable: u64,
    /// The first problems, each naming its frame.
    pub problems: Vec<String>,
}

struct State {
    frame: Option<Arrived>,
    closed: bool,
    counts: Counts,
}

pub(crate) struct Mailbox {
    delivery: Delivery,
    state: Mutex<State>,
    changed: Condvar,
}

impl Mailbox {
    pub fn new(delivery: Delivery) -> Self {
        Mailbox {
            delivery,
            state: Mutex::new(State { frame: None, closed: false, counts: Counts::default() }),
            changed: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic on the other side already ends the stream; the counts stay readable.
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Hands over a frame. Live: a frame still waiting is dropped for it. Every: waits until
    /// the network has taken the previous one (or the mailbox is closed, which drops `frame`).
    pub fn put(&self, frame: Arrived) {
        let mut state = self.lock();
        state.counts.arrived += 1;
        if self.delivery == Delivery::Every {
            while state.frame.is_some() && !state.closed {
                state = self.changed.wait(state).unwrap_or_else(|p| p.into_inner());
            }
        }
        if state.closed {
            return;
        }
        if state.frame.replace(frame).is_some() {
            state.counts.dropped += 1;
        }
        self.changed.notify_all();
    }

    /// The next frame, waiting for one; `None` once closed and empty.
    pub fn take(&self) -> Option<Arrived> {
        let mut state = self.lock();
        loop {
            if let Some(frame) = state.frame.take() {
                self.changed.notify_all();
                return Some(frame);
            }
            if state.closed {
                return None;
            }
            state = self.changed.wait(state).unwrap_or_else(|p| p.into_inner());
        }
    }

    /// `n` frames went stale at the source, unread.
    pub fn skipped(&self, n: u64) {
        let mut state = self.lock();
        state.counts.arrived += n;
        state.counts.dropped += n;
    }

    /// A frame that could not be read or decoded, with the reason (naming it).
    pub fn unreadable(&self, problem: String) {
        self.lock().counts.arrived += 1;
        self.failed(problem);
    }

    /// A frame handed over that the network's side could not use.
    pub fn failed(&self, problem: String) {
        eprintln!("skipped: {problem}");
        let mut state = self.lock();
        state.counts.unreadable += 1;
        if state.counts.problems.len() < PROBLEMS_KEPT {
            state.counts.problems.push(problem);
        }
    }

    /// No more frames will be put; the one waiting is still taken.
    pub fn close(&self) {
        self.lock().closed = true;
        self.changed.notify_all();
    }

    pub fn is_closed(&self) -> bool {
        self.lock().closed
    }

    pub fn counts(&self) -> Counts {
        self.lock().counts.clone()
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;

    fn frame(name: &str) -> Arrived {
        Arrived { name: name.into(), arrived: Instant::now(), image: image::RgbImage::new(1, 1) }
    }

    #[test]
    fn live_keeps_the_newest_and_counts_the_dropped() {
        let mailbox = Mailbox::new(Delivery::Live);
        for name in ["a", "b", "c"] {
            mailbox.put(frame(name));
        }
        assert_eq!(mailbox.take().unwrap().name, "c");
        mailbox.skipped(2);
        mailbox.unreadable("d: broken".into());
        let counts = mailbox.counts();
        assert_eq!((counts.arrived, counts.dropped, counts.unreadable), (6, 4, 1));
        assert_eq!(counts.problems, ["d: broken"]);
        mailbox.put(frame("e"));
        mailbox.close();
        // Closing keeps the waiting frame, then ends.
        assert_eq!(mailbox.take().unwrap().name, "e");
        assert!(mailbox.take().is_none());
    }

    #[test]
    fn every_waits_for_the_network_and_loses_nothing() {
        let mailbox = Mailbox::new(Delivery::Every);
        let names: Vec<String> = (0..50).map(|i| format!("{i:03}")).collect();
        let got = std::thread::scope(|scope| {
            scope.spawn(|| {
                for name in &names {
                    mailbox.put(frame(name));
                }
                mailbox.close();
            });
            let mut got = Vec::new();
            while let Some(f) = mailbox.take() {
                // A slow network: the producer must wait, not replace.
                std::thread::sleep(Duration::from_micros(200));
                got.push(f.name);
            }
            got
        });
        assert_eq!(got, names);
        assert_eq!(mailbox.counts().dropped, 0);
    }

    #[test]
    fn closing_releases_a_waiting_producer() {
        let mailbox = Mailbox::new(Delivery::Every);
        mailbox.put(frame("a"));
        std::thread::scope(|scope| {
            let producer = scope.spawn(|| mailbox.put(frame("b")));
            std::thread::sleep(Duration::from_millis(20));
            mailbox.close();
            producer.join().unwrap();
        });
        assert_eq!(mailbox.take().unwrap().name, "a");
        assert!(mailbox.take().is_none());
    }
}
