//! Strided convolutions (the stem's 7x7 stride-2 one) computed directly from the input dealt
//! into phases, with no gathered copy.
//!
//! With the zero-padded input split into `stride x stride` phase planes (rows `i * stride + py`,
//! columns `j * stride + px` of the padded image in plane `(py, px)`), the input under tap
//! `(ky, kx)` for a run of output positions along a row is a contiguous run of one plane, at an
//! offset fixed by the tap. So a block of output channels times output positions is held in
//! registers and each tap adds one broadcast weight times one loaded run: the input is read in
//! place and nothing is copied. The gathered product (`conv_forward`) first wrote every tap's
//! values for every position (294 rows of 4096 values for the quickstart's stem), a third of
//! the stem's time (BENCHMARKS.md). The prologue is applied once per input value as the planes
//! are dealt, the epilogue on each finished band of rows.

use std::ops::Range;

use rayon::prelude::*;

use super::shared::{ConvShape, Epilogue, Prologue, SharedMut, column_chunks};

/// The input dealt into phase planes, each `(plane_rows + 1) x plane_width` (a spare row, and
/// spare values at the end, for the runs of the last positions, whose extra lanes are never
/// stored).
struct PhasePlanes {
    values: Vec<f32>,
    plane_width: usize,
    plane_len: usize,
}

impl PhasePlanes {
    fn of(image: &[f32], s: &ConvShape, prologue: Option<Prologue>, spare: usize) -> Self {
        let (st, p, c, (h, w)) = (s.stride, s.padding, s.channels_in, (s.height, s.width));
        let (plane_rows, plane_width) = ((h + 2 * p).div_ceil(st), (w + 2 * p).div_ceil(st));
        let plane_len = (plane_rows + 1) * plane_width;
        let mut values = vec![0.0f32; st * st * c * plane_len + spare];
        for ic in 0..c {
            let (scale, shift) = prologue.map_or((1.0, 0.0), |q| (q.scale[ic], q.shift[ic]));
            for (y, src) in image[ic * h * w..][..h * w].chunks_exact(w).enumerate() {
                let (py, i) = ((y + p) % st, (y + p) / st);
                for px in 0..st {
                    // Padded columns j * st + px, input columns j * st + px - p.
                    let first = (p.saturating_sub(px)).div_ceil(st);
                    let Some(x0) = (first * st + px).checked_sub(p).filter(|x0| *x0 < w) else { continue };
                    let at = ((py * st + px) * c + ic) * plane_len + i * plane_width + first;
                    let dst = &mut values[at..][..plane_width - first];
                    let src = src[x0..].iter().step_by(st);
                    match prologue {
                        None => dst.iter_mut().zip(src).for_each(|(d, v)| *d = *v),
                        Some(_) => dst.iter_mut().zip(src).for_each(|(d, v)| *d = (v * scale + shift).max(0.0)),
                    }
                }
            }
        }
        PhasePlanes { values, plane_width, plane_len }
    }
}

/// What every task reads.
struct Problem<'a> {
    planes: &'a PhasePlanes,
    /// Per tap in the weight's order (`ic * k * k + ky * k + kx`): where its run starts for
    /// output position (0, 0).
    offsets: Vec<usize>,
    /// The weight transposed to [taps, channels_out padded to the block], zeros in the padding.
    weight: Vec<f32>,
    channels_out: usize,
    out_width: usize,
    positions: usize,
}

/// Output channels x positions held in registers: 8 x 32 (16 vectors of 16) with AVX-512,
/// 4 x 16 (8 vectors of 8) with AVX2, leaving registers for the loaded run and the weight.
#[cfg(target_arch = "x86_64")]
const AVX512_BLOCK: (usize, usize) = (8, 32);
#[cfg(target_arch = "x86_64")]
const AVX2_BLOCK: (usize, usize) = (4, 16);

/// The kernel this CPU runs. Only `detect` makes one, after asking the CPU: the `unsafe` calls
/// into the `#[target_feature]` functions in `rows` rely on that alone.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(crate) enum Kernel {
    #[cfg(target_arch = "x86_64")]
    Avx512,
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Kernel {
    /// This CPU's kernel, if it has one with fused multiply-add: the widest. Asked once per
    /// process, not on every convolution.
    pub(crate) fn detect() -> Option<Kernel> {
        static DETECTED: std::sync::OnceLock<Option<Kernel>> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| Kernel::each_detected().into_iter().next())
    }

    /// Every kernel this CPU can run, widest first (the tests run each).
    pub(crate) fn each_detected() -> Vec<Kernel> {
        let mut kernels = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            // AVX-512 code may also use AVX2 and FMA (`winograd`'s twins enable all three), so
            // its kernel asks for every one of them.
            let (fma, avx2) = (is_x86_feature_detected!("fma"), is_x86_feature_detected!("avx2"));
            if fma && avx2 && is_x86_feature_detected!("avx512f") {
                kernels.push(Kernel::Avx512);
            }
            if fma && avx2 {
                kernels.push(Kernel::Avx2);
            }
        }
        kernels
    }

    /// Output channels and positions of one register block.
    fn block(self) -> (usize, usize) {
        match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => AVX512_BLOCK,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => AVX2_BLOCK,
        }
    }

    fn rows(self, problem: &Problem, rows: Range<usize>, out: SharedMut) {
        match self {
            // SAFETY: `detect` found the features these functions are compiled for.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => unsafe { rows_avx512(problem, rows, out) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => unsafe { rows_avx2(problem, rows, out) },
        }
    }
}

/// Output rows through one kernel: each register block (`$block`: output channels, positions in
/// two vectors of `$lanes`) summed over the taps in registers, through `std::arch` (written as
/// plain loops over arrays, the block stayed on the stack and was added one value at a time: 30x
/// slower).
macro_rules! rows_kernel {
    ($name:ident, $features:literal, $block:expr, $vector:ty, $lanes:literal, $zero:ident, $load:ident, $splat:ident, $fma:ident, $store:ident) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $name(problem: &Problem, rows: Range<usize>, out: SharedMut) {
            use std::arch::x86_64::*;
            const OB: usize = $block.0;
            const N: usize = 2;
            const L: usize = $block.1;
            const _: () = assert!(L == N * $lanes, "a block is two vectors wide");
            let (o, wo, width) = (problem.channels_out, problem.out_width, problem.planes.plane_width);
            let blocks = o.div_ceil(OB) * OB;
            let (values, weight) = (&problem.planes.values, &problem.weight);
            let Some(last) = rows.end.checked_sub(1) else { return };
            // Every run this task loads lies inside the planes, every weight block inside the
            // weight.
            let reach = problem.offsets.iter().max().map_or(0, |m| m + last * width + (wo - 1) + L);
            assert!(reach <= values.len(), "the phase planes' spare values cover the last runs");
            assert_eq!(weight.len(), problem.offsets.len() * blocks, "the weight's blocks");
            for oy in rows {
                for ox0 in (0..wo).step_by(L) {
                    let lanes = (wo - ox0).min(L);
                    let start = oy * width + ox0;
                    for oc0 in (0..blocks).step_by(OB) {
                        let mut acc: [[$vector; N]; OB] = [[$zero(); N]; OB];
                        for (tap, &offset) in problem.offsets.iter().enumerate() {
                            // SAFETY: `offset + start + L <= reach <= values.len()` (asserted
                            // above) and `tap * blocks + oc0 + OB <= weight.len()`.
                            let (x, w) = unsafe {
                                let at = values.as_ptr().add(offset + start);
                                ([$load(at), $load(at.add($lanes))], weight.as_ptr().add(tap * blocks + oc0))
                            };
                            for (r, acc) in acc.iter_mut().enumerate() {
                                // SAFETY: as above.
                                let w = $splat(unsafe { *w.add(r) });
                                for (a, x) in acc.iter_mut().zip(x) {
                                    *a = $fma(w, x, *a);
                                }
                            }
                        }
                        for (r, acc) in acc.iter().enumerate().take(o.saturating_sub(oc0)) {
                            let mut row = [0.0f32; L];
                            for (i, a) in acc.iter().enumerate() {
                                // SAFETY: `row` holds N vectors.
                                unsafe { $store(row.as_mut_ptr().add(i * $lanes), *a) };
                            }
                            let at = (oc0 + r) * problem.positions + oy * wo + ox0;
                            // SAFETY: output row `oy` of channel `oc0 + r` belongs to this task
                            // alone, and holds `lanes` values from `ox0` on.
                            let dst = unsafe { std::slice::from_raw_parts_mut(out.at(at), lanes) };
                            dst.copy_from_slice(&row[..lanes]);
                        }
                    }
                }
            }
        }
    };
}

rows_kernel!(
    rows_avx512,
    "avx512f,fma",
    AVX512_BLOCK,
    __m512,
    16,
    _mm512_setzero_ps,
    _mm512_loadu_ps,
    _mm512_set1_ps,
    _mm512_fmadd_ps,
    _mm512_storeu_ps
);
rows_kernel!(
    rows_avx2,
    "avx2,fma",
    AVX2_BLOCK,
    __m256,
    8,
    _mm256_setzero_ps,
    _mm256_loadu_ps,
    _mm256_set1_ps,
    _mm256_fmadd_ps,
    _mm256_storeu_ps
);

/// The convolutions this path computes: strided, not 1x1, with some input.
fn takes(s: &ConvShape) -> bool {
    s.stride >= 2 && s.kernel > 1 && s.channels_in > 0
}

/// The kernel that computes the convolution `s` on this CPU, if this path does: one it
/// [`takes`], on a CPU with one of the kernels.
pub(crate) fn kernel_for(s: &ConvShape) -> Option<Kernel> {
    takes(s).then(Kernel::detect).flatten()
}

/// The convolution of one image ([channels_in, height, width]) into `out` ([channels_out,
/// out_height * out_width]) through `kernel`, with the prologue and epilogue.
#[allow(clippy::too_many_arguments)]
pub(crate) fn forward_image(
    kernel: Kernel,
    image: &[f32],
    weight: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    assert!(takes(s), "a strided convolution: {s:?}");
    let (c, o, k, st) = (s.channels_in, s.channels_out, s.kernel, s.stride);
    let (ho, wo) = (s.out_height(), s.out_width());
    assert_eq!(image.len(), c * s.height * s.width, "conv input size");
    assert_eq!(weight.len(), o * c * k * k, "conv weight size");
    assert_eq!(out.len(), o * ho * wo, "conv output size");
    let (channel_block, lanes) = kernel.block();
    let planes = PhasePlanes::of(image, s, prologue, lanes);
    let (width, plane_len) = (planes.plane_width, planes.plane_len);
    let offsets = (0..c * k * k)
        .map(|tap| {
            let (ic, ky, kx) = (tap / (k * k), (tap / k) % k, tap % k);
            ((ky % st) * st + kx % st) * c * plane_len + ic * plane_len + (ky / st) * width + kx / st
        })
        .collect();
    let blocks = o.div_ceil(channel_block) * channel_block;
    let mut transposed = vec![0.0f32; c * k * k * blocks];
    for (oc, filter) in weight.chunks_exact(c * k * k).enumerate() {
        for (tap, w) in filter.iter().enumerate() {
            transposed[tap * blocks + oc] = *w;
        }
    }
    let problem =
        Problem { planes: &planes, offsets, weight: transposed, channels_out: o, out_width: wo, positions: ho * wo };
    let dst = SharedMut(out.as_mut_ptr());
    let min_rows = 256usize.div_ceil(wo).max(1);
    column_chunks(ho, min_rows, ho.max(1)).into_par_iter().for_each(|rows| {
        kernel.rows(&problem, rows.clone(), dst);
        if !epilogue.is_identity() {
            for oc in 0..o {
                // SAFETY: rows `rows` of channel `oc`, written by this task alone.
                let band =
                    unsafe { std::slice::from_raw_parts_mut(dst.at(oc * ho * wo + rows.start * wo), rows.len() * wo) };
                epilogue.apply(oc, band);
            }
        }
    });
}
