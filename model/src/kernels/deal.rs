//! A row's values dealt into four column phases, `phases[k][t] = row[4t + k]`: how Winograd's
//! F(4x4, 3x3) lays out its input so that each of a tile's 36 values is one contiguous run
//! (`winograd4::split_row`).
//!
//! As a plain loop this is a scalar load and store per value, which the compiler does not
//! vectorise (a stride-4 gather): a third of the transforms' time in a dense layer's 3x3
//! convolution at 120x160 (BENCHMARKS.md). Here blocks of four quads are transposed in SSE
//! registers (x86-64's baseline, so every x86 CPU runs it), or blocks of sixteen quads by two
//! permutes and a lane shuffle each in AVX-512 registers where the caller's kernel has them.
//! It moves values and computes nothing, so every path gives the same bits (tested).

use super::direct::Kernel;

/// `phases[k][t] = row[4t + k]` for `t < n`, `n` the phases' common length (`row` holds at least
/// `4n` values). `kernel`: the vector kernel the caller runs under (`Kernel::detect`), which
/// alone allows the AVX-512 path.
#[inline(always)]
pub(crate) fn quads(row: &[f32], phases: [&mut [f32]; 4], kernel: Option<Kernel>) {
    let n = phases[0].len();
    assert!(phases.iter().all(|p| p.len() == n) && row.len() >= 4 * n, "dealt phases' lengths");
    let [p0, p1, p2, p3] = phases;
    #[allow(unused_mut)]
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    {
        if kernel == Some(Kernel::Avx512) {
            // SAFETY: `Kernel::Avx512` is only made after the CPU reported AVX-512F
            // (`Kernel::detect`, `Kernel::each_detected`); the lengths were checked above.
            done = unsafe { x86::sixteen_quads(row, [&mut *p0, &mut *p1, &mut *p2, &mut *p3], done) };
        }
        // SAFETY: SSE and SSE2 are part of every x86-64 CPU; the lengths were checked above.
        done = unsafe { x86::four_quads(row, [&mut *p0, &mut *p1, &mut *p2, &mut *p3], done) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = kernel;
    for t in done..n {
        p0[t] = row[4 * t];
        p1[t] = row[4 * t + 1];
        p2[t] = row[4 * t + 2];
        p3[t] = row[4 * t + 3];
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// Quads `from..` in blocks of four, each block transposed as a 4x4 matrix in SSE registers;
    /// returns how many quads are dealt. Requires every phase `n` long and `row` `4n`.
    #[inline(always)]
    pub(super) unsafe fn four_quads(row: &[f32], phases: [&mut [f32]; 4], from: usize) -> usize {
        let n = phases[0].len();
        let [p0, p1, p2, p3] = phases;
        let mut t = from;
        while t + 4 <= n {
            // SAFETY: values 4t..4t + 16 of `row` and 4 values from t of each phase lie inside
            // (the caller checked the lengths); SSE2 is in every x86-64 CPU.
            unsafe {
                let x = row.as_ptr().add(4 * t);
                let (r0, r1, r2, r3) =
                    (_mm_loadu_ps(x), _mm_loadu_ps(x.add(4)), _mm_loadu_ps(x.add(8)), _mm_loadu_ps(x.add(12)));
                let (lo01, lo23) = (_mm_unpacklo_ps(r0, r1), _mm_unpacklo_ps(r2, r3));
                let (hi01, hi23) = (_mm_unpackhi_ps(r0, r1), _mm_unpackhi_ps(r2, r3));
                _mm_storeu_ps(p0.as_mut_ptr().add(t), _mm_movelh_ps(lo01, lo23));
                _mm_storeu_ps(p1.as_mut_ptr().add(t), _mm_movehl_ps(lo23, lo01));
                _mm_storeu_ps(p2.as_mut_ptr().add(t), _mm_movelh_ps(hi01, hi23));
                _mm_storeu_ps(p3.as_mut_ptr().add(t), _mm_movehl_ps(hi23, hi01));
            }
            t += 4;
        }
        t
    }

    /// The permutes' lanes for each phase `k`: lanes 0-3 take phase k of the first register's
    /// four quads, lanes 4-7 the second's; lanes 8-15 repeat them (the shuffle keeps lanes 0-7
    /// only). Fixed at compile time: `sixteen_quads` runs once per input row.
    const PHASE_LANES: [[i32; 16]; 4] = {
        let mut lanes = [[0i32; 16]; 4];
        let mut k = 0;
        while k < 4 {
            let mut l = 0;
            while l < 16 {
                let m = (l % 8) as i32;
                lanes[k][l] = if m < 4 { k as i32 + 4 * m } else { 16 + k as i32 + 4 * (m - 4) };
                l += 1;
            }
            k += 1;
        }
        lanes
    };

    /// Quads `from..` in blocks of sixteen: for each phase, two permutes gather its values of
    /// quads 0-7 and 8-15 of the block, and a lane shuffle joins the halves. Returns how many
    /// quads are dealt. Requires every phase `n` long and `row` `4n`.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn sixteen_quads(row: &[f32], mut phases: [&mut [f32]; 4], from: usize) -> usize {
        let n = phases[0].len();
        // SAFETY: each row of `PHASE_LANES` holds 16 values; the caller's CPU has AVX-512F.
        let indices = unsafe {
            [
                _mm512_loadu_epi32(PHASE_LANES[0].as_ptr()),
                _mm512_loadu_epi32(PHASE_LANES[1].as_ptr()),
                _mm512_loadu_epi32(PHASE_LANES[2].as_ptr()),
                _mm512_loadu_epi32(PHASE_LANES[3].as_ptr()),
            ]
        };
        let mut t = from;
        while t + 16 <= n {
            // SAFETY: values 4t..4t + 64 of `row` and 16 values from t of each phase lie inside
            // (the caller checked the lengths); the caller's CPU has AVX-512F.
            unsafe {
                let x = row.as_ptr().add(4 * t);
                let a = [
                    _mm512_loadu_ps(x),
                    _mm512_loadu_ps(x.add(16)),
                    _mm512_loadu_ps(x.add(32)),
                    _mm512_loadu_ps(x.add(48)),
                ];
                for (phase, index) in phases.iter_mut().zip(&indices) {
                    let lo = _mm512_permutex2var_ps(a[0], *index, a[1]);
                    let hi = _mm512_permutex2var_ps(a[2], *index, a[3]);
                    let joined = _mm512_shuffle_f32x4::<0b01_00_01_00>(lo, hi);
                    _mm512_storeu_ps(phase.as_mut_ptr().add(t), joined);
                }
            }
            t += 16;
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every path against the plain definition, on lengths around both block sizes and with
    /// values whose bits would show a mix-up (distinct, signs and a NaN payload).
    #[test]
    fn every_path_deals_each_value_to_its_phase() {
        let mut kernels = vec![None];
        kernels.extend(Kernel::each_detected().into_iter().map(Some));
        for n in [0usize, 1, 3, 4, 5, 15, 16, 17, 31, 33, 40, 81] {
            let row: Vec<f32> = (0..4 * n + 3)
                .map(|i| {
                    if i == 7 {
                        f32::from_bits(0x7fc0_1234)
                    } else {
                        (i as f32 + 0.25) * if i % 3 == 0 { -1.0 } else { 1.0 }
                    }
                })
                .collect();
            for &kernel in &kernels {
                let mut out = vec![vec![f32::INFINITY; n]; 4];
                let [a, b, c, d] = &mut out[..] else { unreachable!() };
                quads(&row, [a, b, c, d], kernel);
                for (k, phase) in out.iter().enumerate() {
                    for (t, v) in phase.iter().enumerate() {
                        assert_eq!(v.to_bits(), row[4 * t + k].to_bits(), "n {n}, phase {k}, t {t}, {kernel:?}");
                    }
                }
            }
        }
    }
}
