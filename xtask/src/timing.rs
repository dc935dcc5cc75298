//! Timing helpers shared by the benchmarks.

use std::time::{Duration, Instant};

/// Median seconds of `f` over `reps` runs after one warm-up, and the last result.
pub fn time<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = f();
    let mut times = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t = Instant::now();
        out = f();
        times.push(t.elapsed().as_secs_f64());
    }
    (formats::stats::median(times), out)
}

/// Milliseconds of `f` over `reps` runs after one warm-up: median, quartiles, range.
pub fn time_ms(reps: usize, f: impl FnMut()) -> formats::stats::Summary {
    time_ms_apart(reps, Duration::ZERO, f)
}

/// `time_ms` with the machine left idle for `pause` before each run, as between a camera's
/// frames: what a caller sees on a machine whose cores sleep between calls, rather than in a
/// loop that keeps them busy.
pub fn time_ms_apart(reps: usize, pause: Duration, mut f: impl FnMut()) -> formats::stats::Summary {
    f();
    let times = (0..reps).map(|_| {
        if !pause.is_zero() {
            std::thread::sleep(pause);
        }
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64() * 1e3
    });
    formats::stats::Summary::of(times.collect::<Vec<_>>())
}

/// Seconds of a single run of `f` (no warm-up), and its result.
pub fn once<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let t = Instant::now();
    let out = f();
    (t.elapsed().as_secs_f64(), out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_apart_are_timed_without_their_pause() {
        let (pause, reps) = (Duration::from_millis(20), 4);
        let mut calls = 0;
        let start = Instant::now();
        let ms = time_ms_apart(reps, pause, || calls += 1);
        // One warm-up and `reps` timed runs, each after its pause, which is not in its time.
        assert_eq!(calls, reps + 1);
        assert!(start.elapsed() >= pause * reps as u32);
        assert!(ms.max < 20.0, "{}", ms.max);
        let mut back_to_back = 0;
        let start = Instant::now();
        time_ms(reps, || back_to_back += 1);
        assert_eq!(back_to_back, reps + 1);
        assert!(start.elapsed() < pause, "no pause without one asked for");
    }
}
