//! Timing helpers shared by the benchmarks.

use std::time::Instant;

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
pub fn time_ms(reps: usize, mut f: impl FnMut()) -> formats::stats::Summary {
    f();
    let times = (0..reps).map(|_| {
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
