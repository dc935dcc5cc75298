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

/// Milliseconds of CPU time this process has used, all its threads together: what polling
/// workers cost between calls, which wall time does not show.
#[allow(unsafe_code)]
pub fn process_cpu_ms() -> f64 {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: libc's promise: `clock_gettime` writes one `timespec` through the pointer, which
    // points at a live local of that type; the clock id is one POSIX defines.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_PROCESS_CPUTIME_ID) failed");
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
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

    #[test]
    fn process_cpu_time_counts_work_on_other_threads() {
        // Other tests run in this process meanwhile, so only a lower bound holds: the main
        // thread's own clock would see none of this.
        let before = process_cpu_ms();
        let busy = std::thread::spawn(|| {
            let t = Instant::now();
            while t.elapsed() < Duration::from_millis(40) {
                std::hint::spin_loop();
            }
        });
        busy.join().unwrap();
        let worked = process_cpu_ms() - before;
        // The other thread's 40 ms busy, less what a loaded machine took from it.
        assert!(worked > 10.0, "a thread's 40 ms busy loop counted {worked} ms");
    }
}
