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
