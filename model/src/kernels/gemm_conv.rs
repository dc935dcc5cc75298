//! Convolution gradients as matrix products over the zero-padded image, on plain `f32` slices
//! (the forward is `conv_forward`).
//!
//! With the image padded and flattened row by row (padded width `wp`), the input under kernel
//! tap `(ky, kx)` for every output position is one contiguous window of the flat image, shifted
//! by `ky * wp + kx`: a matrix with ordinary strides. So the weight gradient is `k * k` products
//! whose inner dimension runs over the whole image. flex lowers the weight gradient to a
//! convolution with the batch as channels, which becomes one thin matrix product per input
//! channel (about 4x slower for DenseNet's 3x3 layers here); this form keeps every product
//! large. Each output row carries `k - 1` padding columns, zero in the spread output gradient.
//! The input gradient is a forward convolution with the weight transposed and flipped. A
//! strided convolution (DenseNet's 7x7 stem) takes its taps from the forward's gathered input
//! instead, and its input gradient starts from the output gradient spread to stride 1.

use rayon::prelude::*;

use super::conv_forward::{GATHER_COLUMNS, GATHER_ROWS, Taps};
use super::shared::{ConvShape, column_chunks, matmul};

/// Columns per weight-gradient task, so that a task's window of the image stays in cache across
/// the `k * k` products that revisit it.
const MAX_COLUMNS: usize = 2048;

/// Copies `planes` ([planes, rows, width], dense) into `into` ([planes, plane_len]), each row
/// at `offset + row * stride` of its plane; the rest of `into` keeps its zeros.
fn spread_rows(
    into: &mut [f32],
    plane_len: usize,
    planes: &[f32],
    [rows, width]: [usize; 2],
    stride: usize,
    offset: usize,
) {
    into.par_chunks_mut(plane_len).zip(planes.par_chunks(rows * width)).for_each(|(dst, src)| {
        for (row, src_row) in src.chunks_exact(width).enumerate() {
            dst[offset + row * stride..][..width].copy_from_slice(src_row);
        }
    });
}

/// One image `[channels, height, width]` zero-padded into `[channels, padded_len]`.
fn pad_image(image: &[f32], s: &ConvShape, channels: usize) -> Vec<f32> {
    let (p, wp, len) = (s.padding, s.padded_width(), s.padded_len());
    let mut padded = vec![0.0f32; channels * len];
    spread_rows(&mut padded, len, image, [s.height, s.width], wp, p * wp + p);
    padded
}

/// The gradient of the input: `grad` ([batch, channels_out, out_height, out_width]), spread to
/// stride 1 where the convolution is strided, convolved with the weight transposed and flipped.
pub(crate) fn input_grad(grad: &[f32], weight: &[f32], s: &ConvShape) -> Vec<f32> {
    let (c, o, k) = (s.channels_in, s.channels_out, s.kernel);
    let t = s.transposed();
    assert_eq!(grad.len(), s.batch * o * s.out_height() * s.out_width(), "conv output gradient size");
    let spread;
    let grad = if s.stride == 1 {
        grad
    } else {
        // Output position (i, j) sits at (i * stride, j * stride) of a stride-1 output; the
        // rows and columns a stride skips, and any the last step did not reach, stay zero.
        let (wo, st) = (s.out_width(), s.stride);
        let mut dilated = vec![0.0f32; s.batch * o * t.height * t.width];
        dilated.par_chunks_mut(t.height * t.width).zip(grad.par_chunks(s.out_height() * wo)).for_each(|(dst, src)| {
            for (i, row) in src.chunks_exact(wo).enumerate() {
                let dst = &mut dst[i * st * t.width..][..t.width];
                dst.iter_mut().step_by(st).zip(row).for_each(|(d, v)| *d = *v);
            }
        });
        spread = dilated;
        &spread[..]
    };
    let mut flipped = vec![0.0f32; weight.len()];
    for oc in 0..o {
        for ic in 0..c {
            for tap in 0..k * k {
                flipped[(ic * o + oc) * k * k + (k * k - 1 - tap)] = weight[(oc * c + ic) * k * k + tap];
            }
        }
    }
    super::conv_forward::forward(grad, &flipped, None, &t)
}

/// The gradient of the weight: [channels_out, channels_in, kernel, kernel]. The inner dimension
/// (every output position of every image) is split across threads, each summing into its own
/// buffer, because the product's outer dimensions are too small to split well.
pub(crate) fn weight_grad(x: &[f32], grad: &[f32], s: &ConvShape) -> Vec<f32> {
    if s.stride > 1 {
        return strided_weight_grad(x, grad, s);
    }
    let (c, o, k) = (s.channels_in, s.channels_out, s.kernel);
    let (ho, wo, wp, n, len) = (s.out_height(), s.out_width(), s.padded_width(), s.columns(), s.padded_len());
    assert_eq!(x.len(), s.batch * c * s.height * s.width, "conv input size");
    assert_eq!(grad.len(), s.batch * o * ho * wo, "conv output gradient size");
    let size = o * c * k * k;
    let mut total = vec![0.0f32; size];
    for b in 0..s.batch {
        let image = &x[b * c * s.height * s.width..][..c * s.height * s.width];
        let image_grad = &grad[b * o * ho * wo..][..o * ho * wo];
        let (padded, wide);
        let (flat, g) = if s.is_pointwise() {
            (image, image_grad)
        } else {
            padded = pad_image(image, s, c);
            // The output gradient at the padded row stride, zero in the padding columns.
            let mut spread = vec![0.0f32; o * n];
            spread_rows(&mut spread, n, image_grad, [ho, wo], wp, 0);
            wide = spread;
            (&padded[..], &wide[..])
        };
        let chunks = column_chunks(n, 512, MAX_COLUMNS);
        add_in_groups(&mut total, &chunks, |group, part| {
            for cols in group {
                for tap in 0..k * k {
                    let shift = (tap / k) * wp + tap % k;
                    // SAFETY: `part` is [o, c, k, k] written at stride k*k from `tap`; the
                    // window of `flat` ends at most at `padded_len`.
                    unsafe {
                        matmul(
                            [o, c, cols.len()],
                            part.as_mut_ptr().add(tap),
                            [k * k, c * k * k],
                            true,
                            g.as_ptr().add(cols.start),
                            [1, n],
                            flat.as_ptr().add(shift + cols.start),
                            [len, 1],
                        );
                    }
                }
            }
        });
    }
    total
}

/// `weight_grad` of a strided convolution: its taps are no longer windows of one padded image,
/// so each task gathers its output positions' input under every tap (as the forward does) and
/// multiplies the output gradient by it, `[o, positions] x [positions, channels * k * k]`, one
/// product per block of channels. The positions are summed in fixed groups, as above.
fn strided_weight_grad(x: &[f32], grad: &[f32], s: &ConvShape) -> Vec<f32> {
    let (c, o, kk) = (s.channels_in, s.channels_out, s.kernel * s.kernel);
    let (plane, positions) = (s.height * s.width, s.out_height() * s.out_width());
    assert_eq!(x.len(), s.batch * c * plane, "conv input size");
    assert_eq!(grad.len(), s.batch * o * positions, "conv output gradient size");
    let block = (GATHER_ROWS / kk).clamp(1, c.max(1));
    let chunks = column_chunks(positions, 64, GATHER_COLUMNS);
    let mut total = vec![0.0f32; o * c * kk];
    for (image, image_grad) in x.chunks_exact(c * plane).zip(grad.chunks_exact(o * positions)) {
        let taps = Taps::new(image, s);
        add_in_groups(&mut total, &chunks, |group, part| {
            let mut gathered = vec![0.0f32; block * kk * GATHER_COLUMNS.min(positions)];
            for cols in group {
                let n = cols.len();
                for c0 in (0..c).step_by(block) {
                    let channels = c0..(c0 + block).min(c);
                    let rows = channels.len() * kk;
                    taps.gather(&mut gathered[..rows * n], channels, cols.clone());
                    // SAFETY: `part` is [o, c * kk], written in columns `c0 * kk ..` for `rows`
                    // columns; the gradient's row `oc` is read at `cols`, inside its
                    // `positions`; `gathered` holds `rows` rows of `n`.
                    unsafe {
                        matmul(
                            [o, rows, n],
                            part.as_mut_ptr().add(c0 * kk),
                            [1, c * kk],
                            true,
                            image_grad.as_ptr().add(cols.start),
                            [1, positions],
                            gathered.as_ptr(),
                            [n, 1],
                        );
                    }
                }
            }
        });
    }
    total
}

/// Adds to `total` what `task` sums over all of `chunks` (column ranges), computed in a fixed
/// number of contiguous groups of them, each summed into a buffer of its own on whichever thread
/// takes it; the buffers are then added in group order. Rayon's `fold` would make one buffer per
/// split, and its splits follow work stealing, so the sum's rounding (and a training run's
/// weights) would follow the schedule.
fn add_in_groups(
    total: &mut [f32],
    chunks: &[std::ops::Range<usize>],
    task: impl Fn(&[std::ops::Range<usize>], &mut [f32]) + Sync,
) {
    let size = total.len();
    let partials: Vec<Vec<f32>> = reduction_groups(chunks.len())
        .into_par_iter()
        .map(|group| {
            let mut part = vec![0.0f32; size];
            task(&chunks[group], &mut part);
            part
        })
        .collect();
    for part in &partials {
        total.iter_mut().zip(part).for_each(|(t, p)| *t += p);
    }
}

/// `chunks` chunk indices cut into at most one contiguous range per rayon thread: as many
/// partial sums as the pool can fill, in an order that does not depend on the schedule.
fn reduction_groups(chunks: usize) -> Vec<std::ops::Range<usize>> {
    let size = chunks.div_ceil(rayon::current_num_threads().max(1)).max(1);
    (0..chunks).step_by(size).map(|start| start..(start + size).min(chunks)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::conv_forward::forward;

    /// Direct convolution by its definition, for reference.
    fn naive(x: &[f32], weight: &[f32], s: &ConvShape) -> Vec<f32> {
        let (c, o, k, p, st) = (s.channels_in, s.channels_out, s.kernel, s.padding as isize, s.stride as isize);
        let (h, w, ho, wo) = (s.height, s.width, s.out_height(), s.out_width());
        let mut out = vec![0.0f32; s.batch * o * ho * wo];
        for b in 0..s.batch {
            for oc in 0..o {
                for i in 0..ho {
                    for j in 0..wo {
                        let mut acc = 0.0f64;
                        for ic in 0..c {
                            for ky in 0..k {
                                for kx in 0..k {
                                    let (y, xx) =
                                        (i as isize * st + ky as isize - p, j as isize * st + kx as isize - p);
                                    if y >= 0 && xx >= 0 && (y as usize) < h && (xx as usize) < w {
                                        acc += (x[((b * c + ic) * h + y as usize) * w + xx as usize]
                                            * weight[((oc * c + ic) * k + ky) * k + kx])
                                            as f64;
                                    }
                                }
                            }
                        }
                        out[((b * o + oc) * ho + i) * wo + j] = acc as f32;
                    }
                }
            }
        }
        out
    }

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| ((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32 / (1u32 << 24) as f32 - 0.5)
            .collect()
    }

    fn close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}: length");
        let scale = b.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!((x - y).abs() <= 1e-5 * scale.max(1.0), "{what}[{i}]: {x} vs {y}");
        }
    }

    const SHAPES: [ConvShape; 4] = [
        ConvShape { batch: 2, channels_in: 5, channels_out: 3, height: 7, width: 9, kernel: 3, padding: 1, stride: 1 },
        ConvShape { batch: 1, channels_in: 4, channels_out: 6, height: 5, width: 4, kernel: 1, padding: 0, stride: 1 },
        ConvShape { batch: 2, channels_in: 3, channels_out: 2, height: 6, width: 8, kernel: 3, padding: 0, stride: 1 },
        ConvShape { batch: 1, channels_in: 2, channels_out: 3, height: 6, width: 5, kernel: 5, padding: 2, stride: 1 },
    ];

    /// Strided shapes, like DenseNet's 7x7 stem, a stride that leaves the last rows and
    /// columns out, and one longer than the kernel.
    const STRIDED: [ConvShape; 3] = [
        ConvShape {
            batch: 2,
            channels_in: 3,
            channels_out: 5,
            height: 11,
            width: 10,
            kernel: 7,
            padding: 3,
            stride: 2,
        },
        ConvShape { batch: 1, channels_in: 2, channels_out: 3, height: 9, width: 9, kernel: 3, padding: 0, stride: 3 },
        // A stride longer than the kernel: inputs that no output reads get no gradient.
        ConvShape { batch: 2, channels_in: 3, channels_out: 2, height: 7, width: 6, kernel: 1, padding: 0, stride: 2 },
    ];

    #[test]
    fn forward_matches_the_definition() {
        for s in SHAPES.into_iter().chain(STRIDED) {
            let x = values(s.batch * s.channels_in * s.height * s.width, 1);
            let weight = values(s.channels_out * s.channels_in * s.kernel * s.kernel, 2);
            let bias = values(s.channels_out, 3);
            let mut expected = naive(&x, &weight, &s);
            let plane = s.out_height() * s.out_width();
            for (i, v) in expected.iter_mut().enumerate() {
                *v += bias[(i / plane) % s.channels_out];
            }
            close(&forward(&x, &weight, Some(&bias), &s), &expected, &format!("{s:?}"));
        }
    }

    /// The gradients against the definition: for the loss `sum(g * conv(x, w))`, the weight
    /// gradient's entry is the forward with a one-hot weight, and the input gradient's entry
    /// the forward with a one-hot input.
    #[test]
    fn gradients_match_one_hot_forwards() {
        for s in SHAPES.into_iter().chain(STRIDED) {
            let (nx, nw) =
                (s.batch * s.channels_in * s.height * s.width, s.channels_out * s.channels_in * s.kernel * s.kernel);
            let x = values(nx, 4);
            let weight = values(nw, 5);
            let grad = values(s.batch * s.channels_out * s.out_height() * s.out_width(), 6);
            // Entry i of the gradient: the loss with the i-th of `n` inputs one-hot.
            let one_hot = |n: usize, loss: &dyn Fn(&[f32]) -> Vec<f32>| -> Vec<f32> {
                (0..n)
                    .map(|i| {
                        let mut one = vec![0.0; n];
                        one[i] = 1.0;
                        loss(&one).iter().zip(&grad).map(|(p, q)| (p * q) as f64).sum::<f64>() as f32
                    })
                    .collect()
            };
            let expected_dw = one_hot(nw, &|one| naive(&x, one, &s));
            let expected_dx = one_hot(nx, &|one| naive(one, &weight, &s));
            close(&weight_grad(&x, &grad, &s), &expected_dw, &format!("weight grad {s:?}"));
            close(&input_grad(&grad, &weight, &s), &expected_dx, &format!("input grad {s:?}"));
        }
    }

    /// The weight gradient's sum does not follow the schedule: a training step gives the same
    /// weights whether it runs from inside rayon's pool or outside it, run after run. A shape
    /// with many column chunks, so that the pool has something to steal; strided (the stem's
    /// gathered path) and not.
    #[test]
    fn the_weight_gradient_is_the_same_whoever_runs_it() {
        let same = ConvShape {
            batch: 2,
            channels_in: 8,
            channels_out: 6,
            height: 96,
            width: 96,
            kernel: 3,
            padding: 1,
            stride: 1,
        };
        let stem = ConvShape { channels_in: 3, height: 160, width: 160, kernel: 7, padding: 3, stride: 2, ..same };
        for s in [same, stem] {
            let x = values(s.batch * s.channels_in * s.height * s.width, 7);
            let grad = values(s.batch * s.channels_out * s.out_height() * s.out_width(), 8);
            let outside = weight_grad(&x, &grad, &s);
            for round in 0..6 {
                let again = if round % 2 == 0 {
                    rayon::scope(|_| weight_grad(&x, &grad, &s))
                } else {
                    weight_grad(&x, &grad, &s)
                };
                assert!(again.iter().zip(&outside).all(|(a, b)| a.to_bits() == b.to_bits()), "{s:?} round {round}");
            }
        }
    }
}
