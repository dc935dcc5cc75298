//! The convolution's forward pass as matrix products over gathered input, on plain `f32` slices.
//!
//! Each task takes a range of output positions of one image. A 1x1 convolution multiplies the
//! image itself; any other kernel first gathers (im2col) a block of channels times taps for
//! those positions into a per-thread buffer, so that one product runs over `channels * k * k`
//! at once instead of `k * k` thin products each re-reading the output. Padding is never
//! materialised: the gather writes zeros where a tap falls outside the image. What the network
//! does right before and after a convolution rides along while the data is in cache: an input
//! `Prologue` (eval-mode batch norm + ReLU) applied as values are gathered, and an output
//! `Epilogue` (bias or folded batch norm, then ReLU or LeakyReLU).

use std::ops::Range;

use rayon::prelude::*;

use super::shared::{Activation, ConvShape, Epilogue, Prologue, SharedMut, balanced_chunks, matmul};
use super::{direct, winograd};

/// Output positions per task when the input is gathered, and the most gathered rows (channel
/// and tap pairs) at a time: together about 2 MB per thread, which the product reads from cache.
pub(crate) const GATHER_COLUMNS: usize = 512;
pub(crate) const GATHER_ROWS: usize = 1152;
/// The fewest output positions a task is cut to for the threads' sake: narrower products each
/// pack the whole weight again for little work (`balanced_chunks`).
const GATHER_MIN_COLUMNS: usize = 128;
/// Output positions per task for a 1x1 convolution read in place.
const POINTWISE_COLUMNS: usize = 2048;

thread_local! {
    /// Each worker's gathered block, kept between calls so it is allocated once.
    static GATHERED: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Output indices `i` whose input index `i * stride + tap - padding` lies in `0..input`.
fn valid_span(output: usize, input: usize, tap: usize, padding: usize, stride: usize) -> Range<usize> {
    let lo = padding.saturating_sub(tap).div_ceil(stride);
    let hi = if input + padding > tap { ((input + padding - tap - 1) / stride + 1).min(output) } else { 0 };
    lo.min(hi)..hi
}

/// Where the CPU has no direct kernel (`direct`): a strided convolution's input with each row's
/// columns dealt into `stride` phases (the columns `q, q + stride, q + 2 stride, ...` side by
/// side for each `q`, `phase_len` each), so that a tap's values along a row are contiguous: the
/// gather then copies runs instead of reading every `stride`-th value (the stem's 7x7 stride-2
/// convolution: 0.36 -> 0.32 ms on the quickstart's network, BENCHMARKS.md).
struct Phases {
    values: Vec<f32>,
    phase_len: usize,
}

impl Phases {
    fn of(image: &[f32], s: &ConvShape) -> Self {
        let (st, w) = (s.stride, s.width.max(1));
        let phase_len = w.div_ceil(st);
        let mut values = vec![0.0; image.len() / w * st * phase_len];
        for (src, dst) in image.chunks_exact(w).zip(values.chunks_exact_mut(st * phase_len)) {
            for (q, phase) in dst.chunks_exact_mut(phase_len).enumerate() {
                phase.iter_mut().zip(src[q.min(w)..].iter().step_by(st)).for_each(|(d, v)| *d = *v);
            }
        }
        Phases { values, phase_len }
    }

    /// The values of row `row` (of all channels' rows) at columns `start, start + stride, ...`.
    fn run(&self, row: usize, start: usize, len: usize, stride: usize) -> &[f32] {
        let base = row * stride * self.phase_len + (start % stride) * self.phase_len + start / stride;
        &self.values[base..base + len]
    }
}

/// One image's input under each tap of a strided or unstrided convolution, gathered for any
/// output positions without a prologue: what a convolution's weight gradient multiplies its
/// output gradient by when the stride keeps the taps from being windows of one padded image
/// (`gemm_conv::weight_grad`).
pub(crate) struct Taps<'a> {
    image: &'a [f32],
    phases: Option<Phases>,
    shape: ConvShape,
}

impl<'a> Taps<'a> {
    pub(crate) fn new(image: &'a [f32], s: &ConvShape) -> Self {
        assert_eq!(image.len(), s.channels_in * s.height * s.width, "conv input size");
        Taps { image, phases: (s.stride > 1).then(|| Phases::of(image, s)), shape: *s }
    }

    /// Rows `channels` x taps for the output positions `cols` into `into`, as `gather` lays
    /// them out (row `(ic - channels.start) * k * k + tap`, one column per position).
    pub(crate) fn gather(&self, into: &mut [f32], channels: Range<usize>, cols: Range<usize>) {
        gather(into, self.image, self.phases.as_ref(), &self.shape, None, channels, cols);
    }
}

/// Rows `channels` x taps of the gathered input for output positions `cols`: row
/// `(ic - channels.start) * k * k + tap`, column `j` holds the value under `tap` for output
/// position `cols.start + j` (zero in the padding), through the prologue if there is one.
/// `phases`: the image dealt into phases, which a strided convolution reads instead of `image`.
fn gather(
    into: &mut [f32],
    image: &[f32],
    phases: Option<&Phases>,
    s: &ConvShape,
    prologue: Option<Prologue>,
    channels: Range<usize>,
    cols: Range<usize>,
) {
    let (k, st, p, wo) = (s.kernel, s.stride, s.padding, s.out_width());
    let (ho, plane) = (s.out_height(), s.height * s.width);
    let n = cols.len();
    if s.is_pointwise() {
        // A 1x1 convolution's positions are its input's: one run per channel (a dense layer's
        // bottleneck with its batch norm + ReLU as the prologue).
        for (i, ic) in channels.enumerate() {
            let (src, dst) = (&image[ic * plane + cols.start..][..n], &mut into[i * n..][..n]);
            match prologue {
                None => dst.copy_from_slice(src),
                Some(q) => {
                    let (scale, shift) = (q.scale[ic], q.shift[ic]);
                    dst.iter_mut().zip(src).for_each(|(d, v)| *d = (v * scale + shift).max(0.0));
                }
            }
        }
        return;
    }
    for (i, ic) in channels.enumerate() {
        let input = &image[ic * plane..][..plane];
        let (scale, shift) = prologue.map_or((1.0, 0.0), |q| (q.scale[ic], q.shift[ic]));
        let normalise = |d: &mut f32, v: &f32| *d = (v * scale + shift).max(0.0);
        for tap in 0..k * k {
            let row = &mut into[(i * k * k + tap) * n..][..n];
            let (ky, kx) = (tap / k, tap % k);
            let (rows, xs) = (valid_span(ho, s.height, ky, p, st), valid_span(wo, s.width, kx, p, st));
            let mut pos = cols.start;
            while pos < cols.end {
                let (y, x0) = (pos / wo, pos % wo);
                let x1 = wo.min(x0 + cols.end - pos);
                let dst = &mut row[pos - cols.start..][..x1 - x0];
                let (lo, hi) = (xs.start.clamp(x0, x1), xs.end.clamp(x0, x1));
                if !rows.contains(&y) || lo >= hi {
                    dst.fill(0.0);
                } else {
                    dst[..lo - x0].fill(0.0);
                    dst[hi - x0..].fill(0.0);
                    let row = y * st + ky - p;
                    let start = lo * st + kx - p;
                    let dst = &mut dst[lo - x0..hi - x0];
                    let src = match phases {
                        Some(phases) => phases.run(ic * s.height + row, start, dst.len(), st),
                        None => {
                            debug_assert_eq!(st, 1, "a strided gather reads the phases");
                            &input[row * s.width + start..][..dst.len()]
                        }
                    };
                    match prologue {
                        None => dst.copy_from_slice(src),
                        Some(_) => dst.iter_mut().zip(src).for_each(|(d, v)| normalise(d, v)),
                    }
                }
                pos += x1 - x0;
            }
        }
    }
}

/// The convolution of one image `image` ([channels_in, height, width]) with `weight`
/// ([channels_out, channels_in, kernel, kernel]) into `out` ([channels_out, out_height *
/// out_width]), with the prologue and epilogue. `s.batch` is ignored. 3x3 "same"
/// convolutions go through Winograd's F(2x2, 3x3), the rest through the gathered input.
pub(crate) fn forward_image(
    image: &[f32],
    weight: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    let u = winograd::weight_for(s, weight, true);
    forward_image_with(image, weight, u.as_ref(), s, prologue, epilogue, out);
}

/// `forward_image` with the Winograd-transformed weight `u` when there is one; a strided
/// convolution directly from its input where the CPU has the kernel (`direct`); through the
/// gathered input otherwise.
pub(crate) fn forward_image_with(
    image: &[f32],
    weight: &[f32],
    u: Option<&winograd::Transformed>,
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    if let Some(u) = u {
        return winograd::forward_image(image, u, s, prologue, epilogue, out);
    }
    if let Some(kernel) = direct::kernel_for(s) {
        return direct::forward_image(kernel, image, weight, s, prologue, epilogue, out);
    }
    gathered(image, weight, s, prologue, epilogue, out);
}

/// The convolution through the gathered input: any kernel, stride and padding.
fn gathered(
    image: &[f32],
    weight: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    let (c, o, kk) = (s.channels_in, s.channels_out, s.kernel * s.kernel);
    let positions = s.out_height() * s.out_width();
    assert_eq!(image.len(), c * s.height * s.width, "conv input size");
    assert_eq!(weight.len(), o * c * kk, "conv weight size");
    assert_eq!(out.len(), o * positions, "conv output size");
    let in_place = s.is_pointwise() && prologue.is_none();
    let block = (GATHER_ROWS / kk).clamp(1, c.max(1));
    let dst = SharedMut(out.as_mut_ptr());
    let max = if in_place { POINTWISE_COLUMNS } else { GATHER_COLUMNS };
    let phases = (!in_place && s.stride > 1).then(|| Phases::of(image, s));
    balanced_chunks(positions, GATHER_MIN_COLUMNS, max).into_par_iter().for_each(|cols| {
        let n = cols.len();
        if in_place {
            // SAFETY: tasks write disjoint columns of the [o, positions] output.
            unsafe {
                matmul(
                    [o, n, c],
                    dst.at(cols.start),
                    [1, positions],
                    false,
                    weight.as_ptr(),
                    [1, c],
                    image.as_ptr().add(cols.start),
                    [1, positions],
                );
            }
        } else {
            GATHERED.with_borrow_mut(|buf| {
                if buf.len() < block * kk * n {
                    buf.resize(block * kk * n, 0.0);
                }
                for c0 in (0..c).step_by(block) {
                    let channels = c0..(c0 + block).min(c);
                    let rows = channels.len() * kk;
                    gather(&mut buf[..rows * n], image, phases.as_ref(), s, prologue, channels, cols.clone());
                    // SAFETY: as above; the weight's columns `c0 * kk ..` of row stride `c * kk`.
                    unsafe {
                        matmul(
                            [o, n, rows],
                            dst.at(cols.start),
                            [1, positions],
                            c0 > 0,
                            weight.as_ptr().add(c0 * kk),
                            [1, c * kk],
                            buf.as_ptr(),
                            [1, n],
                        );
                    }
                }
            });
        }
        if !epilogue.is_identity() {
            for oc in 0..o {
                // SAFETY: row `oc` of this task's columns, inside `out`.
                epilogue.apply(oc, unsafe { std::slice::from_raw_parts_mut(dst.at(oc * positions + cols.start), n) });
            }
        }
    });
}

/// The convolution of `x` ([batch, channels_in, height, width]) with `weight` plus `bias`:
/// [batch, channels_out, out_height, out_width].
/// The weight is transformed for this call alone (a gradient's flipped copy).
pub(crate) fn forward(x: &[f32], weight: &[f32], bias: Option<&[f32]>, s: &ConvShape) -> Vec<f32> {
    forward_with(x, weight, s, None, &Epilogue::bias(bias, Activation::Identity), false)
}

/// `forward` with a prologue and an epilogue; `keep`: the weight's transform kept between calls
/// (`winograd::weight_for`).
pub(crate) fn forward_with(
    x: &[f32],
    weight: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    keep: bool,
) -> Vec<f32> {
    let (image_len, out_len) = (s.channels_in * s.height * s.width, s.channels_out * s.out_height() * s.out_width());
    assert_eq!(x.len(), s.batch * image_len, "conv input size");
    let mut out = vec![0.0f32; s.batch * out_len];
    if image_len > 0 && out_len > 0 {
        // The Winograd weight transform once for the batch. The images side by side as well as
        // within: a small image is one task, which alone would leave the other threads idle.
        let u = winograd::weight_for(s, weight, keep);
        out.par_chunks_mut(out_len).zip(x.par_chunks(image_len)).for_each(|(dst, image)| {
            forward_image_with(image, weight, u.as_ref(), s, prologue, epilogue, dst);
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::shared::Planes;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| ((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32 / (1 << 24) as f32 - 0.5)
            .collect()
    }

    /// Winograd's F(2x2, 3x3) and F(4x4, 3x3) against the gathered product on the same image,
    /// prologue and epilogue: sides of every remainder by 2 and 4, a single pixel, a single
    /// column, and more channels than one transformed block holds (so products accumulate over
    /// channel blocks), and none. F(4x4, 3x3)'s larger constants round ten times more.
    #[test]
    fn winograd_equals_the_gathered_product() {
        for (tile, tolerance) in [(winograd::Tile::Two, 2e-6), (winograd::Tile::Four, 1e-5)] {
            for (channels_in, channels_out, height, width) in [
                (3, 2, 4, 4),
                (5, 7, 7, 9),
                (2, 3, 1, 1),
                (4, 3, 6, 1),
                (300, 5, 5, 6),
                (16, 33, 33, 18),
                (3, 4, 13, 22),
                (7, 5, 19, 35),
                (0, 2, 3, 3),
            ] {
                let s =
                    ConvShape { batch: 1, channels_in, channels_out, height, width, kernel: 3, padding: 1, stride: 1 };
                assert!(winograd::applies(&s));
                let image = values(channels_in * height * width, 7);
                let weight = values(channels_out * channels_in * 9, 8);
                let (scale_in, shift_in) = (values(channels_in, 9), values(channels_in, 10));
                let shift_out = values(channels_out, 11);
                let u = winograd::weight_with(&s, &weight, tile, false);
                for prologue in [None, Some(Prologue { scale: &scale_in, shift: &shift_in })] {
                    let epilogue = Epilogue::bias(Some(&shift_out), Activation::Leaky(0.2));
                    // Zeros, as `forward_with` hands it (the gathered path writes nothing without
                    // input channels); NaN where Winograd must write everything.
                    let mut want = vec![0.0; channels_out * height * width];
                    forward_image_with(&image, &weight, None, &s, prologue, &epilogue, &mut want);
                    let mut got = vec![f32::NAN; want.len()];
                    forward_image_with(&image, &weight, Some(&u), &s, prologue, &epilogue, &mut got);
                    let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                        let prologue = prologue.is_some();
                        assert!(
                            (g - w).abs() <= tolerance * scale,
                            "{tile:?} {s:?} prologue {prologue} [{i}]: {g} vs {w}"
                        );
                    }
                }
            }
        }
    }

    /// Each vector width this CPU has gives the baseline's bits, through both tiles, with and
    /// without the prologue, over images of several tasks and of a remainder in both directions,
    /// and rows wide enough for the wide kernels' blocks of dealt values (`deal`).
    #[test]
    fn every_vector_width_gives_the_same_bits() {
        let kernels = direct::Kernel::each_detected();
        if kernels.is_empty() {
            eprintln!("no vector kernel on this CPU: nothing to compare");
        }
        for tile in [winograd::Tile::Two, winograd::Tile::Four] {
            for (channels_in, channels_out, height, width) in [(40, 33, 61, 50), (5, 3, 9, 7), (6, 5, 10, 137)] {
                let s =
                    ConvShape { batch: 1, channels_in, channels_out, height, width, kernel: 3, padding: 1, stride: 1 };
                let image = values(channels_in * height * width, 21);
                let weight = values(channels_out * channels_in * 9, 22);
                let (scale_in, shift_in) = (values(channels_in, 23), values(channels_in, 24));
                let shift_out = values(channels_out, 25);
                let u = winograd::weight_with(&s, &weight, tile, false);
                let planes = Planes { image: &image, height, width };
                for prologue in [None, Some(Prologue { scale: &scale_in, shift: &shift_in })] {
                    let epilogue = Epilogue::bias(Some(&shift_out), Activation::Leaky(0.2));
                    let mut want = vec![f32::NAN; channels_out * height * width];
                    winograd::forward_rows(None, &planes, &u, &s, prologue, &epilogue, &mut want);
                    assert!(want.iter().all(|v| v.is_finite()));
                    for &kernel in &kernels {
                        let mut got = vec![f32::NAN; want.len()];
                        winograd::forward_rows(Some(kernel), &planes, &u, &s, prologue, &epilogue, &mut got);
                        let same = got.iter().zip(&want).all(|(g, w)| g.to_bits() == w.to_bits());
                        assert!(same, "{kernel:?} {tile:?} {s:?} prologue {}", prologue.is_some());
                    }
                }
            }
        }
    }

    /// F(4x4, 3x3) for images of two tasks' tiles or more with many channel pairs (DenseNet-161's
    /// dense layers at 30x40 and up, its decoder); F(2x2, 3x3) for smaller images or few pairs
    /// (the dense layers at 15x20, every layer of the quickstart's network).
    #[test]
    fn large_convolutions_take_the_larger_tile() {
        let tile = |channels_in, channels_out, height, width| {
            let s = ConvShape { batch: 1, channels_in, channels_out, height, width, kernel: 3, padding: 1, stride: 1 };
            winograd::Tile::for_shape(&s)
        };
        assert_eq!(tile(192, 48, 30, 40), winograd::Tile::Four);
        assert_eq!(tile(1488, 552, 30, 40), winograd::Tile::Four);
        assert_eq!(tile(69, 69, 240, 320), winograd::Tile::Four);
        assert_eq!(tile(192, 48, 15, 20), winograd::Tile::Two);
        assert_eq!(tile(48, 12, 128, 128), winograd::Tile::Two);
        assert_eq!(tile(3, 1, 128, 128), winograd::Tile::Two);
    }

    /// A non-finite input value reaches only the Winograd tiles whose input window holds it
    /// (4x4 for F(2x2, 3x3), 6x6 for F(4x4, 3x3)): every other output equals the gathered
    /// product. The transforms run over all of a task's tiles at once with a spare tile at the
    /// end of each tile row, which reads the next row's first values; its products must never
    /// reach the output. Each position in turn, on sizes with one task and with several.
    #[test]
    fn winograd_keeps_a_non_finite_input_in_its_tiles() {
        let cases = [
            (winograd::Tile::Two, 6, 7, vec![]),
            (winograd::Tile::Two, 40, 9, vec![0, 1, 12, 13, 14, 15, 19, 20, 21, 27, 28, 29, 39]),
            (winograd::Tile::Four, 9, 11, vec![]),
            (winograd::Tile::Four, 100, 9, vec![0, 1, 3, 4, 43, 44, 45, 47, 48, 87, 88, 89, 91, 92, 99]),
        ];
        for (tile, height, width, edge_rows) in cases {
            let side = if tile == winograd::Tile::Two { 2 } else { 4 };
            let s = ConvShape {
                batch: 1,
                channels_in: 2,
                channels_out: 3,
                height,
                width,
                kernel: 3,
                padding: 1,
                stride: 1,
            };
            let weight = values(3 * 2 * 9, 12);
            let u = winograd::weight_with(&s, &weight, tile, false);
            let epilogue = Epilogue::bias(None, Activation::Identity);
            let positions: Vec<(usize, usize)> = if edge_rows.is_empty() {
                (0..height).flat_map(|y| (0..width).map(move |x| (y, x))).collect()
            } else {
                // Rows next to the tasks' edges and the first and last columns.
                edge_rows.iter().flat_map(|&y| [0, 1, width - 1].map(|x| (y, x))).collect()
            };
            for (y, x) in positions {
                let mut image = values(2 * height * width, 13);
                image[height * width + y * width + x] = f32::INFINITY;
                let mut want = vec![0.0; 3 * height * width];
                forward_image_with(&image, &weight, None, &s, None, &epilogue, &mut want);
                let mut got = vec![f32::NAN; want.len()];
                forward_image_with(&image, &weight, Some(&u), &s, None, &epilogue, &mut got);
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    let (oy, ox) = ((i / width) % height, i % width);
                    // The input window of the tile holding (oy, ox): side + 2 values from one before it.
                    let (ty, tx) = (side * (oy / side), side * (ox / side));
                    let in_window = y + 1 >= ty && y <= ty + side && x + 1 >= tx && x <= tx + side;
                    if !in_window {
                        assert!(
                            (g - w).abs() <= 1e-5,
                            "{tile:?} {height}x{width}, inf at ({y}, {x}): [{i}] {g} vs {w}"
                        );
                    }
                }
            }
        }
    }

    /// The direct strided kernel (each this CPU has) against the gathered product: the stem's
    /// shape with fewer rows, stride 3 over sides it does not divide, output channels that fill no register
    /// block and rows narrower than one, with and without the prologue and epilogue.
    #[test]
    fn direct_equals_the_gathered_product() {
        let shapes = [
            ConvShape {
                batch: 1,
                channels_in: 6,
                channels_out: 32,
                height: 22,
                width: 70,
                kernel: 7,
                padding: 3,
                stride: 2,
            },
            ConvShape {
                batch: 1,
                channels_in: 3,
                channels_out: 5,
                height: 11,
                width: 13,
                kernel: 3,
                padding: 1,
                stride: 3,
            },
            ConvShape {
                batch: 1,
                channels_in: 2,
                channels_out: 9,
                height: 9,
                width: 9,
                kernel: 5,
                padding: 0,
                stride: 2,
            },
            ConvShape {
                batch: 1,
                channels_in: 4,
                channels_out: 3,
                height: 40,
                width: 5,
                kernel: 4,
                padding: 2,
                stride: 2,
            },
        ];
        for s in shapes {
            let kernels = direct::Kernel::each_detected();
            if kernels.is_empty() {
                eprintln!("no direct kernel on this CPU; {s:?} not compared");
            }
            let image = values(s.channels_in * s.height * s.width, 14);
            let weight = values(s.channels_out * s.channels_in * s.kernel * s.kernel, 15);
            let (scale_in, shift_in) = (values(s.channels_in, 16), values(s.channels_in, 17));
            let (scale_out, shift_out) = (values(s.channels_out, 18), values(s.channels_out, 19));
            for prologue in [None, Some(Prologue { scale: &scale_in, shift: &shift_in })] {
                for epilogue in [
                    Epilogue::bias(None, Activation::Identity),
                    Epilogue { scale: Some(&scale_out), shift: Some(&shift_out), activation: Activation::Relu },
                ] {
                    let len = s.channels_out * s.out_height() * s.out_width();
                    let mut want = vec![0.0; len];
                    gathered(&image, &weight, &s, prologue, &epilogue, &mut want);
                    for &kernel in &kernels {
                        let mut got = vec![f32::NAN; len];
                        direct::forward_image(kernel, &image, &weight, &s, prologue, &epilogue, &mut got);
                        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                            let pro = prologue.is_some();
                            assert!((g - w).abs() <= 1e-5, "{kernel:?} {s:?} prologue {pro} [{i}]: {g} vs {w}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn valid_span_is_where_the_tap_lands_inside() {
        for (output, input, padding, stride, kernel) in
            [(5, 5, 1, 1, 3), (4, 8, 3, 2, 7), (3, 9, 0, 3, 3), (1, 1, 2, 1, 5)]
        {
            for tap in 0..kernel {
                let span = valid_span(output, input, tap, padding, stride);
                for i in 0..output {
                    let at = (i * stride + tap) as isize - padding as isize;
                    assert_eq!(
                        span.contains(&i),
                        at >= 0 && at < input as isize,
                        "{output} {input} {padding} {stride} {tap} {i}"
                    );
                }
            }
        }
    }

    /// The prologue equals normalising and clamping the input first (padding stays zero), and
    /// the epilogue equals scaling, shifting and activating the output afterwards.
    #[test]
    fn prologue_and_epilogue_equal_separate_passes() {
        for (kernel, padding, stride) in [(1, 0, 1), (3, 1, 1), (3, 1, 2)] {
            let s =
                ConvShape { batch: 2, channels_in: 4, channels_out: 3, height: 6, width: 7, kernel, padding, stride };
            let plane = s.height * s.width;
            let x = values(s.batch * 4 * plane, 1);
            let weight = values(3 * 4 * kernel * kernel, 2);
            let (scale_in, shift_in) = (values(4, 3), values(4, 4));
            let (scale_out, shift_out) = (values(3, 5), values(3, 6));
            let normalised: Vec<f32> = x
                .iter()
                .enumerate()
                .map(|(i, v)| (v * scale_in[(i / plane) % 4] + shift_in[(i / plane) % 4]).max(0.0))
                .collect();
            let plain = forward(&normalised, &weight, None, &s);
            let out_plane = s.out_height() * s.out_width();
            for activation in [Activation::Identity, Activation::Relu, Activation::Leaky(0.2)] {
                let epilogue = Epilogue { scale: Some(&scale_out), shift: Some(&shift_out), activation };
                let prologue = Prologue { scale: &scale_in, shift: &shift_in };
                let fused = forward_with(&x, &weight, &s, Some(prologue), &epilogue, false);
                for (i, (f, p)) in fused.iter().zip(&plain).enumerate() {
                    let o = (i / out_plane) % 3;
                    let y = p * scale_out[o] + shift_out[o];
                    let want = match activation {
                        Activation::Identity => y,
                        Activation::Relu => y.max(0.0),
                        Activation::Leaky(slope) => {
                            if y >= 0.0 {
                                y
                            } else {
                                y * slope as f32
                            }
                        }
                    };
                    assert!((f - want).abs() <= 1e-5, "{s:?} {activation:?} [{i}]: {f} vs {want}");
                }
            }
        }
    }
}
