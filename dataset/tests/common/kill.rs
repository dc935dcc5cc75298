//! "Kill anywhere, edit nothing, resume = uninterrupted", the property every resumable command
//! holds: a run killed -9 at any moment (starting up, claiming its folder, mid-item, writing its
//! summary) and run again, as often as it takes, ends with the files an uninterrupted run
//! writes. Shared by the dataset and training tests (`#[path]`).

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What the kills hit.
#[derive(Debug)]
pub struct Kills {
    /// Moments after their run's start at which the kills landed (ms).
    pub at_ms: Vec<u64>,
    /// How many found their run still running (the others had finished by then).
    pub mid_run: usize,
}

/// Runs `first`, then `again` (the command line that resumes), each run killed -9 at a moment
/// drawn (seeded by `seed`) in `0..2 * span / kills`, `kills` times; then runs `again` to the
/// end, which must succeed. `span` is how long an uninterrupted run took: the kills fall, on
/// average, `span / kills` of progress apart, so that together they reach across the whole run.
/// A run that ends before its kill must have succeeded. `DENSETACT_KILL_SEED` overrides the
/// seed, to explore other moments (`for s in $(seq 100); do DENSETACT_KILL_SEED=$s cargo test ...`).
pub fn kill_anywhere(bin: &str, first: &[String], again: &[String], kills: usize, span: Duration, seed: u64) -> Kills {
    let seed = std::env::var("DENSETACT_KILL_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(seed);
    let mut rng = formats::SplitMix64::new(seed);
    let mut result = Kills { at_ms: Vec::new(), mid_run: 0 };
    // Each run's messages go to a file (a pipe nobody reads could stall the run), shown when the
    // run fails.
    let log = tempfile::NamedTempFile::new().unwrap();
    for k in 0..kills {
        let args = if k == 0 { first } else { again };
        let at = span.mul_f64(2.0 * rng.unit() / kills as f64);
        let start = Instant::now();
        let stderr = Stdio::from(log.reopen().unwrap());
        log.as_file().set_len(0).unwrap();
        let mut child = Command::new(bin).args(args).stdout(Stdio::null()).stderr(stderr).spawn().unwrap();
        std::thread::sleep(at.saturating_sub(start.elapsed()));
        match child.try_wait().unwrap() {
            None => {
                child.kill().unwrap();
                child.wait().unwrap();
                result.mid_run += 1;
            }
            Some(status) => assert!(
                status.success(),
                "run {k} ({args:?}) failed before its kill at {at:?}, after {:?} (kills so far {result:?}): {}",
                start.elapsed(),
                std::fs::read_to_string(log.path()).unwrap_or_default()
            ),
        }
        result.at_ms.push(at.as_millis() as u64);
    }
    let last = Command::new(bin).args(again).output().unwrap();
    assert!(
        last.status.success(),
        "the run after {kills} kills ({result:?}) failed: {}",
        String::from_utf8_lossy(&last.stderr)
    );
    result
}

/// Runs `args` to the end and returns how long it took.
pub fn timed_run(bin: &str, args: &[String]) -> Duration {
    let start = Instant::now();
    let r = Command::new(bin).args(args).output().unwrap();
    assert!(r.status.success(), "{args:?}: {}", String::from_utf8_lossy(&r.stderr));
    start.elapsed()
}

/// `args` as owned strings.
pub fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}
