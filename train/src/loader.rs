//! Batches decoded on worker threads ahead of the training step.
//!
//! Decoding a sample (PNG image and depth map, resize, augmentation) is serial work that the
//! step would otherwise wait for; on a GPU it can starve the device. Workers take batches in
//! order, each decodes a whole batch, and the step takes them in order, at most `ahead` batches
//! beyond the one it is on. What a batch holds depends only on the run's seed, the epoch and
//! the batch's position (the augmentation of each sample is drawn from its own stream), never on
//! which worker decoded it or when, so a resumed run sees exactly the batches of an
//! uninterrupted one.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use crate::data::{DataError, DepthDataset, DepthItem, Jitter};

/// One batch as decoded: each sample's index in the split and its item or its error.
pub type DecodedBatch = Vec<(usize, Result<DepthItem, DataError>)>;

/// An epoch's batches, decoded ahead.
pub struct BatchLoader {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
    /// The batch `next` hands out next.
    next: usize,
    end: usize,
    /// Decoding inline (no workers).
    inline: Option<Job>,
}

/// What decoding one batch needs.
#[derive(Clone)]
struct Job {
    data: Arc<DepthDataset>,
    /// The epoch's sample order.
    order: Arc<Vec<usize>>,
    batch: usize,
    seed: u64,
    epoch: u64,
}

impl Job {
    fn decode(&self, b: usize) -> DecodedBatch {
        let ids = &self.order[b * self.batch..((b + 1) * self.batch).min(self.order.len())];
        ids.iter().map(|&i| (i, self.data.load(i, Some(Jitter::draw(self.seed, self.epoch, i as u64))))).collect()
    }
}

struct Shared {
    state: Mutex<State>,
    changed: Condvar,
}

struct State {
    /// The next batch a worker takes.
    next_start: usize,
    /// The batch the step waits for (workers stay at most `ahead` beyond it).
    wanted: usize,
    ready: BTreeMap<usize, DecodedBatch>,
    stop: bool,
    /// A worker's panic (a bug: decoding reports bad samples as errors), passed on to the step
    /// rather than leaving it waiting.
    panicked: Option<String>,
}

impl BatchLoader {
    /// Batches `first..` of an epoch over `order` (samples of `data`, `batch` at a time, the last
    /// one shorter), decoded by `workers` threads at most `ahead` batches ahead. With no workers
    /// each batch is decoded when asked for.
    pub fn new(
        data: Arc<DepthDataset>,
        order: Vec<usize>,
        batch: usize,
        [seed, epoch]: [u64; 2],
        first: usize,
        workers: usize,
        ahead: usize,
    ) -> Self {
        let end = order.len().div_ceil(batch.max(1));
        let job = Job { data, order: Arc::new(order), batch: batch.max(1), seed, epoch };
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                next_start: first,
                wanted: first,
                ready: BTreeMap::new(),
                stop: false,
                panicked: None,
            }),
            changed: Condvar::new(),
        });
        let ahead = ahead.max(1);
        let threads = (0..workers)
            .map(|k| {
                let (shared, job) = (shared.clone(), job.clone());
                std::thread::Builder::new()
                    .name(format!("loader {k}"))
                    .spawn(move || work(&shared, &job, end, ahead))
                    .expect("spawning a loader thread")
            })
            .collect::<Vec<_>>();
        let inline = threads.is_empty().then_some(job);
        BatchLoader { shared, workers: threads, next: first, end, inline }
    }

    /// The next batch in order, `None` after the last.
    pub fn next_batch(&mut self) -> Option<DecodedBatch> {
        if self.next >= self.end {
            return None;
        }
        let b = self.next;
        self.next += 1;
        if let Some(job) = &self.inline {
            return Some(job.decode(b));
        }
        let mut state = self.shared.state.lock().expect("loader lock");
        state.wanted = b;
        self.shared.changed.notify_all();
        loop {
            if let Some(message) = &state.panicked {
                panic!("a loader thread panicked: {message}");
            }
            if let Some(items) = state.ready.remove(&b) {
                state.wanted = b + 1;
                self.shared.changed.notify_all();
                return Some(items);
            }
            state = self.shared.changed.wait(state).expect("loader lock");
        }
    }
}

fn work(shared: &Shared, job: &Job, end: usize, ahead: usize) {
    loop {
        let b = {
            let mut state = shared.state.lock().expect("loader lock");
            loop {
                if state.stop || state.next_start >= end {
                    return;
                }
                if state.next_start < state.wanted + ahead {
                    break;
                }
                state = shared.changed.wait(state).expect("loader lock");
            }
            state.next_start += 1;
            state.next_start - 1
        };
        let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job.decode(b)));
        let mut state = shared.state.lock().expect("loader lock");
        match decoded {
            Ok(items) => {
                state.ready.insert(b, items);
            }
            Err(p) => {
                state.panicked = Some(model::backend::panic_message(p.as_ref()));
                state.stop = true;
            }
        }
        shared.changed.notify_all();
    }
}

impl Drop for BatchLoader {
    fn drop(&mut self) {
        if let Ok(mut state) = self.shared.state.lock() {
            state.stop = true;
        }
        self.shared.changed.notify_all();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}
