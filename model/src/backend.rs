//! Which Burn backend runs where.
//!
//! On the CPU the default is burn-flex, built with its `x86-v4` feature (AVX-512 matrix kernels
//! chosen at run time, with a fallback on older CPUs): DenseDepth-161 forward at 480x640 took
//! 1.63 s with it, 3.5 s without, and 20.4 s on the deprecated burn-ndarray (field notes).

use burn::tensor::{Device, Tensor};

/// The default device: flex on the CPU.
pub fn default_device() -> Device {
    Device::flex()
}

/// Makes Burn's own default device the CPU (flex) unless `BURN_DEVICE` says otherwise. Burn
/// picks a GPU backend first when one is compiled in, and places some state there without being
/// asked (an optimiser record loaded on resume), which starts the Vulkan loader, and its
/// complaints, on runs that asked for the CPU. Call first thing in `main`; our code names its
/// devices, so only Burn's implicit choice changes. Whether it set it: it does only while the
/// process runs one thread (checked, not assumed: the environment is not thread-safe), so called
/// later it does nothing.
#[allow(unsafe_code)]
pub fn cpu_unless_asked() -> bool {
    if std::env::var_os("BURN_DEVICE").is_some() || !single_threaded() {
        return false;
    }
    // SAFETY: `set_var` races only with other threads reading or writing the environment; the
    // process has one thread (just counted), and only this one could start another.
    unsafe { std::env::set_var("BURN_DEVICE", "flex") };
    true
}

/// Whether the process runs a single thread (Linux: one entry in `/proc/self/task`); false where
/// that cannot be told.
fn single_threaded() -> bool {
    std::fs::read_dir("/proc/self/task").map(|tasks| tasks.count() == 1).unwrap_or(false)
}

/// Runs `f` on one of rayon's workers (at once if this thread is one). The flex kernels scatter
/// each layer's work over rayon's pool; called from a thread outside it, every layer's scatter
/// is injected into the pool and waited for through a lock, which costs a good part of the
/// layers' time at the quickstart's 128x128: the compact network's inference forward, alternated
/// in one process, 1.14-1.34x faster inside the pool (BENCHMARKS.md,
/// `cargo xtask bench model --recipe quickstart --pool-hop-ab`), with the same output to the bit.
/// `DenseDepth::forward` runs inference (plain flex, no autodiff) through it; `train`'s fit runs
/// its whole epoch loop through it, on one worker, so that batch norm's running statistics
/// (Burn keeps them per thread) are all written from one thread, as they were from outside.
pub fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() || !POOL_HOP.load(std::sync::atomic::Ordering::Relaxed) {
        f()
    } else {
        let call = InFlight::enter();
        rayon::scope(|_| {
            let r = f();
            drop(call);
            keep_warm();
            r
        })
    }
}

/// How many [`in_pool`] calls are running their work now.
static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// One [`in_pool`] call counted in [`CALLS`] until dropped (also when its work panics).
struct InFlight;

impl InFlight {
    fn enter() -> InFlight {
        CALLS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        InFlight
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        CALLS.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

/// How long (ns) rayon's workers keep polling for work after an [`in_pool`] call; 0: not at all.
static SPIN_NS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
/// Until when (ns on [`clock_ns`]) the polling tasks poll.
static SPIN_UNTIL_NS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
/// How many polling tasks are in rayon's pool now.
static SPINNERS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Keeps all but one of rayon's workers (at least one) polling for work for `window` after each
/// [`in_pool`] call, process-wide; zero, the default, turns it off. For frames that come at a
/// camera's rate: a worker that has slept through the gap between two frames is woken late (on
/// a 2-vCPU VM, a job scattered at a forward's start began on the second worker 2.2 ms later),
/// so the quickstart's 128x128 forward took 5.8 ms 50 ms after the last one and 3.7 ms back to
/// back; polling through the gap it takes 3.9-4.6 ms, for the price of a core kept busy
/// (BENCHMARKS.md, "Each side's workers polling between frames"). ONNX Runtime does this by
/// default: its workers spin about 60 ms after each run.
pub fn set_spin(window: std::time::Duration) {
    let ns = u64::try_from(window.as_nanos()).unwrap_or(u64::MAX);
    SPIN_NS.store(ns, std::sync::atomic::Ordering::SeqCst);
    if ns == 0 {
        // Off means now: the polling tasks leave at their next look at the deadline.
        SPIN_UNTIL_NS.store(0, std::sync::atomic::Ordering::SeqCst);
    }
}

/// The polling window [`set_spin`] set (zero: off), for reports to say what their latencies
/// were measured with.
pub fn spin() -> std::time::Duration {
    std::time::Duration::from_nanos(SPIN_NS.load(std::sync::atomic::Ordering::SeqCst))
}

/// Nanoseconds since the first call: the polling tasks' clock.
fn clock_ns() -> u64 {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    u64::try_from(START.get_or_init(std::time::Instant::now).elapsed().as_nanos()).unwrap_or(u64::MAX)
}

/// How many polling tasks [`set_spin`] keeps: all workers but the one the caller's next call
/// will wake by itself, and at least one.
fn spinners_wanted() -> usize {
    rayon::current_num_threads().saturating_sub(1).max(1)
}

/// Takes one polling task's place if fewer than wanted hold one.
fn take_spinner_place() -> bool {
    use std::sync::atomic::Ordering::SeqCst;
    let wanted = spinners_wanted();
    SPINNERS.fetch_update(SeqCst, SeqCst, |n| (n < wanted).then_some(n + 1)).is_ok()
}

/// After an [`in_pool`] call: moves the polling deadline on and starts the polling tasks that
/// are missing.
fn keep_warm() {
    use std::sync::atomic::Ordering::SeqCst;
    let window = SPIN_NS.load(SeqCst);
    if window == 0 {
        return;
    }
    SPIN_UNTIL_NS.fetch_max(clock_ns().saturating_add(window), SeqCst);
    while take_spinner_place() {
        rayon::spawn(poll_until_deadline);
    }
}

/// One polling task: runs whatever work the pool has (a forward's scatter, the next call's
/// hop) until the deadline, then leaves, unless a call moved the deadline on meanwhile.
///
/// It is a job like any other, so a worker waiting inside another call's work (for a task
/// another worker took) may take it up, and would then hold that call until the deadline (a
/// test saw a call beside others take the whole 60 s window). So it polls only if it starts
/// while no call is running, which is the case between frames; a task started inside a call's
/// work leaves at once and the next call's end starts another. Rayon work that does not come
/// through `in_pool` is not counted: a worker waiting inside it could still take up a polling
/// task in the moment between its spawning and its start, and wait out the window.
fn poll_until_deadline() {
    use std::sync::atomic::Ordering::SeqCst;
    loop {
        if CALLS.load(SeqCst) == 0 {
            while clock_ns() < SPIN_UNTIL_NS.load(SeqCst) {
                if rayon::yield_now() != Some(rayon::Yield::Executed) {
                    std::hint::spin_loop();
                }
            }
        }
        SPINNERS.fetch_sub(1, SeqCst);
        // A call that ended before the count's decrement saw this task counted and started
        // none: stay for it.
        if CALLS.load(SeqCst) > 0 || clock_ns() >= SPIN_UNTIL_NS.load(SeqCst) || !take_spinner_place() {
            return;
        }
    }
}

/// How many polling tasks are running (for the tests).
#[cfg(test)]
pub(crate) fn spinners() -> usize {
    SPINNERS.load(std::sync::atomic::Ordering::SeqCst)
}

static POOL_HOP: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(true);

/// Turns [`in_pool`]'s hop off (`false`) or back on, process-wide: for the benchmark that
/// measures both sides alternately in one run (`cargo xtask bench model --pool-hop-ab`).
/// Inference results are the same either way (that benchmark checks it).
pub fn set_pool_hop(on: bool) {
    POOL_HOP.store(on, std::sync::atomic::Ordering::Relaxed);
}

/// The default wgpu adapter (a discrete GPU when there is one; Mesa's lavapipe on a CPU-only
/// machine with `mesa-vulkan-drivers`).
#[cfg(feature = "wgpu")]
pub fn wgpu_device() -> Device {
    Device::wgpu(burn::tensor::DeviceKind::DefaultDevice)
}

/// A device by its command-line name: `flex` (or `cpu`); `wgpu` (the default adapter) and
/// `wgpu:N` (the N-th discrete GPU) in builds with the `wgpu` feature; `cuda` and `cuda:N` in
/// builds with the `cuda` feature.
pub fn device(name: &str) -> Result<Device, DeviceError> {
    let (kind, index) = match name.split_once(':') {
        Some((kind, index)) => {
            let i = index.trim().parse::<usize>().map_err(|_| DeviceError::Index(name.to_string()))?;
            (kind.trim(), Some(i))
        }
        None => (name.trim(), None),
    };
    match (kind, index) {
        ("flex" | "cpu", None) => Ok(default_device()),
        #[cfg(feature = "wgpu")]
        ("wgpu", None) => Ok(wgpu_device()),
        #[cfg(feature = "wgpu")]
        ("wgpu", Some(i)) => Ok(Device::wgpu(burn::tensor::DeviceKind::DiscreteGpu(i))),
        #[cfg(feature = "cuda")]
        ("cuda", i) => Ok(Device::cuda(i.unwrap_or(0))),
        _ => Err(DeviceError::Unknown(name.to_string())),
    }
}

/// Whether `device` works: a GPU runtime that cannot start (no driver, no adapter) panics at its
/// first operation, which here becomes an error naming the device.
pub fn check(device: &Device) -> Result<(), DeviceError> {
    let probe = || Tensor::<1>::from_floats([1.0, 2.0], device).sum().into_scalar::<f32>();
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(probe)) {
        Ok(3.0) => Ok(()),
        Ok(v) => Err(DeviceError::Wrong { device: format!("{device:?}"), sum: v }),
        Err(p) => Err(DeviceError::CannotStart { device: format!("{device:?}"), message: panic_message(p.as_ref()) }),
    }
}

/// Why a device named on the command line cannot be used.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DeviceError {
    #[error("{0:?}: the device index must be a number")]
    Index(String),
    #[error(
        "unknown or unavailable device {0:?}: this build knows flex{wgpu}{cuda}",
        wgpu = if cfg!(feature = "wgpu") { ", wgpu, wgpu:N" } else { " (wgpu needs a build with --features model/wgpu)" },
        cuda = if cfg!(feature = "cuda") { ", cuda, cuda:N" } else { " (cuda needs a build with --features model/cuda)" }
    )]
    Unknown(String),
    #[error("device {device} computed 1 + 2 = {sum}")]
    Wrong { device: String, sum: f32 },
    #[error("device {device} cannot start: {message}")]
    CannotStart { device: String, message: String },
    #[error("{0:?}: name at least one device")]
    NoneNamed(String),
    #[error("{list:?}: {name} is named twice; each device takes one share of a batch")]
    Twice { list: String, name: String },
}

/// The message a caught panic carried (GPU runtimes report failures by panicking).
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "the device's runtime panicked".into())
}

/// The index of the first device in `devices` that an earlier one already names.
pub fn first_repeat(devices: &[Device]) -> Option<usize> {
    (1..devices.len()).find(|&i| devices[..i].contains(&devices[i]))
}

/// [`device`] and [`check`] together: the device named, known to work.
pub fn working_device(name: &str) -> Result<Device, DeviceError> {
    let d = device(name)?;
    check(&d)?;
    Ok(d)
}

/// Devices from a comma-separated list (`cuda:0,cuda:1`), each named once.
pub fn devices(list: &str) -> Result<Vec<Device>, DeviceError> {
    let names: Vec<&str> = list.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
    if names.is_empty() {
        return Err(DeviceError::NoneNamed(list.to_string()));
    }
    let out = names.iter().map(|name| working_device(name)).collect::<Result<Vec<_>, _>>()?;
    match first_repeat(&out) {
        Some(i) => Err(DeviceError::Twice { list: list.to_string(), name: names[i].to_string() }),
        None => Ok(out),
    }
}

/// burn-ndarray, deprecated in Burn 0.22 and about 12x slower than flex here; built only with
/// the `ndarray` feature, for comparisons.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
pub fn ndarray_device() -> Device {
    Device::ndarray()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_environment_is_left_alone_once_threads_run() {
        // A test runs beside the harness's threads; one more is kept alive to be sure.
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let other = std::thread::spawn(move || rx.recv());
        assert!(!single_threaded());
        let before = std::env::var_os("BURN_DEVICE");
        assert!(!cpu_unless_asked());
        assert_eq!(std::env::var_os("BURN_DEVICE"), before);
        drop(tx);
        let _ = other.join();
    }

    #[test]
    fn device_names_parse_and_bad_ones_are_refused() {
        assert_eq!(device("flex").unwrap(), default_device());
        assert_eq!(device("cpu").unwrap(), default_device());
        assert_eq!(devices(" flex ").unwrap(), vec![default_device()]);
        assert!(check(&default_device()).is_ok());
        for bad in ["flex:1", "gpu", "cuda:x", "wgpu:-1", ""] {
            assert!(device(bad).is_err(), "{bad:?} must be refused");
        }
        let twice = devices("flex,cpu").unwrap_err().to_string();
        assert!(twice.contains("twice"), "{twice}");
        assert!(devices(",").unwrap_err().to_string().contains("at least one"));
        if !cfg!(feature = "cuda") {
            let e = device("cuda:0").unwrap_err().to_string();
            assert!(e.contains("--features model/cuda"), "{e}");
        }
    }

    /// The polling tests turn it on and off for the whole process: one at a time.
    static SPIN_TESTS: std::sync::Mutex<()> = std::sync::Mutex::new(());

    #[test]
    fn polling_workers_run_the_next_calls_and_leave_when_turned_off() {
        use rayon::prelude::*;
        let _serial = SPIN_TESTS.lock().unwrap_or_else(|e| e.into_inner());
        let work = || (0..200_000u64).into_par_iter().map(|i| i * i % 7).sum::<u64>();
        let want: u64 = (0..200_000u64).map(|i| i * i % 7).sum();
        set_spin(std::time::Duration::from_secs(60));
        assert_eq!(spin(), std::time::Duration::from_secs(60));
        // A polling task that started while a call ran leaves and hands its place on: the count
        // may be off for a moment.
        let settles_at = |count: usize| {
            let waited = std::time::Instant::now();
            while spinners() != count && waited.elapsed() < std::time::Duration::from_secs(30) {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            spinners() == count
        };
        for _ in 0..20 {
            // Each call after the first hops onto a pool whose workers are polling.
            assert_eq!(in_pool(work), want);
            assert!(settles_at(spinners_wanted()), "{} polling tasks, {} wanted", spinners(), spinners_wanted());
        }
        set_spin(std::time::Duration::ZERO);
        assert_eq!(spin(), std::time::Duration::ZERO);
        assert!(settles_at(0), "the polling tasks must leave once turned off");
        // And calls without them give the same.
        assert_eq!(in_pool(work), want);
        assert_eq!(spinners(), 0);
    }

    /// A polling task is a job like any other: one that a worker took up while waiting inside
    /// another call's work would hold that call until the deadline.
    #[test]
    fn polling_never_holds_up_a_call_that_runs_beside_others() {
        use rayon::prelude::*;
        let _serial = SPIN_TESTS.lock().unwrap_or_else(|e| e.into_inner());
        set_spin(std::time::Duration::from_secs(60));
        let started = std::time::Instant::now();
        let long = std::thread::spawn(|| {
            in_pool(|| {
                (0..64u64)
                    .into_par_iter()
                    .map(|i| {
                        std::thread::sleep(std::time::Duration::from_millis(5));
                        i
                    })
                    .sum::<u64>()
            })
        });
        let short = std::thread::spawn(|| {
            for _ in 0..200 {
                in_pool(|| (0..1000u64).into_par_iter().sum::<u64>());
            }
        });
        assert_eq!(long.join().unwrap(), 64 * 63 / 2);
        short.join().unwrap();
        set_spin(std::time::Duration::ZERO);
        let took = started.elapsed();
        assert!(took < std::time::Duration::from_secs(20), "the calls took {took:?}");
    }

    #[test]
    fn flex_computes_a_matrix_product() {
        let device = default_device();
        let a = Tensor::<2>::from_floats([[1.0, 2.0], [3.0, 4.0]], &device);
        let b = Tensor::<2>::from_floats([[5.0, 6.0], [7.0, 8.0]], &device);
        let c: Vec<f32> = a.matmul(b).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(c, vec![19.0, 22.0, 43.0, 50.0]);
    }
}
