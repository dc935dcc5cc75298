//! Run-time CPU feature detection as a value. Code compiled for AVX2 is reachable only through
//! an [`Avx2`] token, and only [`Avx2::detect`] makes one, after asking the CPU: so a caller
//! cannot reach AVX2 instructions on a CPU without them, and the `unsafe` calls into
//! `#[target_feature]` functions rely on the token's existence alone.

/// Proof that the CPU running this process has AVX2.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx2 {
    _detected: (),
}

impl Avx2 {
    /// The token, if this CPU has AVX2 (never on other architectures).
    pub(crate) fn detect() -> Option<Avx2> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Some(Avx2 { _detected: () });
        }
        None
    }
}

/// Runs `f`, compiled for AVX2 where this CPU has it: `f` is inlined into a function built
/// with AVX2 enabled, so its loops vectorise eight lanes wide instead of the baseline's four.
/// `f` must be `#[inline(always)]` (as must what it calls, for that code to be rebuilt too).
/// Rust never contracts into FMA, so both builds compute the same bits.
#[inline(always)]
pub(crate) fn avx2_where_present<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if Avx2::detect().is_some() {
        #[target_feature(enable = "avx2")]
        fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        // SAFETY: detection just found AVX2 on this CPU.
        return unsafe { with_avx2(f) };
    }
    f()
}
