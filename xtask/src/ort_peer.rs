//! ONNX Runtime as a peer process that times one forward at a time on request, so that a
//! benchmark can alternate its runs with flex's: on a shared machine whose speed drifts by
//! tens of percent over a minute, two sides timed one after the other compare two machines.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use anyhow::{Context, Result, bail};
use formats::stats::Summary;

/// `peers/onnx_runtime.py`, running.
pub struct OrtPeer {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    /// ONNX Runtime's version, as the peer reports it.
    pub version: String,
}

impl OrtPeer {
    /// Starts the peer on `model` (an ONNX file) for inputs of `channels` x `hw` with `threads`.
    pub fn start(python: &str, model: &str, channels: usize, [h, w]: [usize; 2], threads: usize) -> Result<Self> {
        let script = crate::peer::script("onnx_runtime.py");
        let [c, h, w, t] = [channels, h, w, threads].map(|v| v.to_string());
        let mut child = Command::new(python)
            .arg(&script)
            .args(["--model", model, "--channels", &c, "--height", &h, "--width", &w])
            .args(["--threads", &t])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("running {python} {script}"))?;
        let (stdin, stdout) = (child.stdin.take().expect("piped"), child.stdout.take().expect("piped"));
        let mut peer = OrtPeer { child, stdin, stdout: BufReader::new(stdout), version: String::new() };
        let ready = peer.line()?;
        let Some(version) = ready.strip_prefix("ready version=") else {
            bail!("peer {script} did not start: {ready:?}");
        };
        peer.version = version.to_string();
        Ok(peer)
    }

    fn line(&mut self) -> Result<String> {
        let mut line = String::new();
        if self.stdout.read_line(&mut line)? == 0 {
            let status = self.child.wait()?;
            bail!("the ONNX Runtime peer ended ({status}); its errors are above");
        }
        Ok(line.trim().to_string())
    }

    /// Milliseconds of one forward of a batch of `batch` images (the peer warms up on the
    /// first request of each batch size).
    pub fn forward_ms(&mut self, batch: usize) -> Result<f64> {
        writeln!(self.stdin, "{batch}")?;
        self.stdin.flush()?;
        let line = self.line()?;
        line.strip_prefix("forward_ms=")
            .and_then(|v| v.parse().ok())
            .with_context(|| format!("the ONNX Runtime peer answered {line:?}"))
    }
}

impl Drop for OrtPeer {
    fn drop(&mut self) {
        // Its loop would end when its input closes; the benchmark is done with it either way.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Both sides' times, one pair per repetition, and the ratio of each pair.
pub struct Interleaved {
    pub ours: Summary,
    pub peer: Summary,
    /// `ours / peer` of each repetition's pair.
    pub ratio: Summary,
}

/// Between two timed runs: long enough for the side that just ran to put its threads to sleep
/// (ONNX Runtime's spin a while waiting for more work, as rayon's do), which would otherwise
/// take the cores from the other side's run (the quickstart's 5 ms forward ran 1.5x ONNX
/// Runtime's time without the pause).
const PAUSE: std::time::Duration = std::time::Duration::from_millis(50);

/// `reps` repetitions of `ours` and `peer` (each returning its milliseconds) after one warm-up
/// of each, alternating which goes first so neither always runs on the other's heels, with a
/// pause before each run.
pub fn interleave(
    reps: usize,
    mut ours: impl FnMut() -> f64,
    mut peer: impl FnMut() -> Result<f64>,
) -> Result<Interleaved> {
    let mut ours = || {
        std::thread::sleep(PAUSE);
        ours()
    };
    let mut peer = || {
        std::thread::sleep(PAUSE);
        peer()
    };
    ours();
    peer()?;
    let mut pairs = Vec::with_capacity(reps);
    for rep in 0..reps {
        let pair = if rep % 2 == 0 {
            let a = ours();
            (a, peer()?)
        } else {
            let b = peer()?;
            (ours(), b)
        };
        pairs.push(pair);
    }
    Ok(summarise(&pairs))
}

fn summarise(pairs: &[(f64, f64)]) -> Interleaved {
    Interleaved {
        ours: Summary::of(pairs.iter().map(|p| p.0).collect::<Vec<_>>()),
        peer: Summary::of(pairs.iter().map(|p| p.1).collect::<Vec<_>>()),
        ratio: Summary::of(pairs.iter().map(|p| p.0 / p.1).collect::<Vec<_>>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pair_is_compared_within_itself() {
        // The machine halves its speed half way: each pair still reads 0.5.
        let pairs = [(10.0, 20.0), (11.0, 22.0), (20.0, 40.0), (22.0, 44.0)];
        let i = summarise(&pairs);
        assert_eq!((i.ratio.q1, i.ratio.median, i.ratio.q3), (0.5, 0.5, 0.5));
        assert_eq!(i.ours.median, 15.5);
        assert_eq!(i.peer.median, 31.0);
    }

    #[test]
    fn the_order_alternates_after_one_warm_up_each() {
        let log = std::cell::RefCell::new(Vec::new());
        let i = interleave(
            3,
            || {
                log.borrow_mut().push('o');
                1.0
            },
            || {
                log.borrow_mut().push('p');
                Ok(4.0)
            },
        )
        .unwrap();
        assert_eq!(log.into_inner().into_iter().collect::<String>(), "opoppoop");
        assert_eq!(i.ratio.median, 0.25);
    }
}
