//! 3x3 stride-1 "same" convolutions by Winograd's minimal filtering F(2x2, 3x3).
//!
//! Each 2x2 block of outputs comes from a 4x4 tile of the input through 16 element-wise
//! products instead of 36 multiply-adds: with the input and the weight moved into the
//! transformed domain (`V = Bt d B`, `U = G g Gt`), the convolution over channels becomes 16
//! matrix products `M[xi] = U[xi] * V[xi]` of 2.25x fewer flops than the gathered (im2col)
//! product, and the output is `At M A`. DenseDepth's decoder is mostly such convolutions. The
//! transforms run over rows of tiles: input rows split into even and odd columns make each of a
//! tile's four columns a contiguous run, so the transforms vectorise across tiles. The prologue
//! (eval-mode batch norm + ReLU of the input) and epilogue (bias / folded batch norm, then the
//! activation) are the gathered path's, so the two are interchangeable.

use rayon::prelude::*;

use super::shared::{ConvShape, Epilogue, Prologue, SharedMut, column_chunks, matmul};

/// Transformed input held per thread (16 x channels x tiles, f32): the channel block is cut so
/// the block stays about 1 MB.
const TRANSFORMED_BUDGET: usize = 256 * 1024;
/// Tiles per task: enough columns for the products to run at speed.
const MIN_TILES: usize = 32;
const MAX_TILES: usize = 256;

thread_local! {
    /// Each worker's transformed input and products, kept between calls.
    static BUFFERS: std::cell::RefCell<(Vec<f32>, Vec<f32>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// Whether this path computes the convolution `s`: 3x3, stride 1, padding 1.
pub(crate) fn applies(s: &ConvShape) -> bool {
    s.kernel == 3 && s.stride == 1 && s.padding == 1 && s.height > 0 && s.width > 0
}

/// The transformed weight when this path computes the convolution `s` (kept between calls for
/// small weights, `weight_cache`); `None` when the gathered product must (the one place that
/// decides between them).
pub(crate) fn weight_for(s: &ConvShape, weight: &[f32]) -> Option<std::sync::Arc<[f32]>> {
    applies(s)
        .then(|| super::weight_cache::transformed(weight, || transform_weight(weight, s.channels_out, s.channels_in)))
}

/// `U = G g Gt` for every (output, input) channel pair, as 16 matrices [channels_out,
/// channels_in]: `u[xi * o * c + oc * c + ic]` with `xi = 4 * row + column`.
fn transform_weight(weight: &[f32], channels_out: usize, channels_in: usize) -> Vec<f32> {
    let (o, c) = (channels_out, channels_in);
    assert_eq!(weight.len(), o * c * 9, "3x3 weight size");
    let mut u = vec![0.0f32; 16 * o * c];
    let dst = SharedMut(u.as_mut_ptr());
    (0..o).into_par_iter().for_each(|oc| {
        let mut runs = vec![0.0f32; 16 * c];
        for (ic, g) in weight[oc * c * 9..][..c * 9].chunks_exact(9).enumerate() {
            // G g: 4 rows of 3.
            let mut gg = [[0.0f32; 3]; 4];
            for col in 0..3 {
                let (a, b, d) = (g[col], g[3 + col], g[6 + col]);
                gg[0][col] = a;
                gg[1][col] = 0.5 * (a + b + d);
                gg[2][col] = 0.5 * (a - b + d);
                gg[3][col] = d;
            }
            // (G g) Gt: 4 x 4.
            for (row, r) in gg.iter().enumerate() {
                let xi = 4 * row;
                runs[xi * c + ic] = r[0];
                runs[(xi + 1) * c + ic] = 0.5 * (r[0] + r[1] + r[2]);
                runs[(xi + 2) * c + ic] = 0.5 * (r[0] - r[1] + r[2]);
                runs[(xi + 3) * c + ic] = r[2];
            }
        }
        for (xi, run) in runs.chunks_exact(c.max(1)).enumerate() {
            // SAFETY: row `oc` of matrix `xi` of `u`, written by this task alone.
            unsafe { std::ptr::copy_nonoverlapping(run.as_ptr(), dst.at(xi * o * c + oc * c), c) };
        }
    });
    u
}

/// One input row split into the values a row of tiles reads: `odd[t] = x[2t - 1]` and
/// `even[t] = x[2t]` for tiles `t` in `0..=tiles` (zero outside the row, or for a padding row),
/// through the prologue.
fn split_row(row: Option<&[f32]>, prologue: Option<(f32, f32)>, even: &mut [f32], odd: &mut [f32]) {
    let Some(row) = row else {
        even.fill(0.0);
        odd.fill(0.0);
        return;
    };
    let value = |v: f32| prologue.map_or(v, |(scale, shift)| (v * scale + shift).max(0.0));
    let pairs = row.chunks_exact(2);
    let (n, last) = (row.len() / 2, pairs.remainder().first().copied());
    for ((e, o), pair) in even[..n].iter_mut().zip(&mut odd[1..=n]).zip(pairs) {
        *e = value(pair[0]);
        *o = value(pair[1]);
    }
    odd[0] = 0.0;
    odd[n + 1..].fill(0.0);
    even[n..].fill(0.0);
    if let Some(v) = last {
        even[n] = value(v);
    }
}

/// Four disjoint runs of `n` values, `stride` apart, from `first` on.
fn four_runs(v: &mut [f32], first: usize, stride: usize, n: usize) -> [&mut [f32]; 4] {
    let (a, rest) = v[first..].split_at_mut(stride);
    let (b, rest) = rest.split_at_mut(stride);
    let (c, d) = rest.split_at_mut(stride);
    [&mut a[..n], &mut b[..n], &mut c[..n], &mut d[..n]]
}

/// `V = Bt d B` for the `n` tiles of one tile row of one channel, from the row's four input
/// rows split by `split_row` (`[even, odd]` each): writes `v[xi * stride + t]` for tile `t`.
fn transform_input(rows: &[[&[f32]; 2]; 4], n: usize, v: &mut [f32], stride: usize) {
    // Columns 0..4 of tile t are x = 2t - 1, 2t, 2t + 1, 2t + 2.
    let d: [[&[f32]; 4]; 4] = std::array::from_fn(|r| {
        let [even, odd] = rows[r];
        [&odd[..n], &even[..n], &odd[1..=n], &even[1..=n]]
    });
    // Row r of Bt d is input row p plus or minus input row q.
    for (r, (p, q, sign)) in [(0, 2, -1.0f32), (1, 2, 1.0), (2, 1, -1.0), (1, 3, -1.0)].into_iter().enumerate() {
        let [v0, v1, v2, v3] = four_runs(v, 4 * r * stride, stride, n);
        let ([a0, a1, a2, a3], [b0, b1, b2, b3]) = (d[p], d[q]);
        for t in 0..n {
            let (c0, c1, c2, c3) =
                (a0[t] + sign * b0[t], a1[t] + sign * b1[t], a2[t] + sign * b2[t], a3[t] + sign * b3[t]);
            v0[t] = c0 - c2;
            v1[t] = c1 + c2;
            v2[t] = c2 - c1;
            v3[t] = c1 - c3;
        }
    }
}

/// `Y = At M A` for the `n` tiles of one tile row of one output channel, `m[xi * stride + t]`,
/// into the output rows under it (`rows[1]` is `None` past the bottom; a last tile of an odd
/// width writes its left column only).
fn transform_output(m: &[f32], stride: usize, n: usize, rows: [Option<&mut [f32]>; 2]) {
    let run = |xi: usize| &m[xi * stride..][..n];
    let s: [[&[f32]; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|col| run(4 * r + col)));
    for (a, row) in rows.into_iter().enumerate() {
        let Some(row) = row else { continue };
        // Row a of At M: rows 0 + 1 + 2, or 1 - 2 - 3.
        let combine = |col: usize, t: usize| {
            if a == 0 { s[0][col][t] + s[1][col][t] + s[2][col][t] } else { s[1][col][t] - s[2][col][t] - s[3][col][t] }
        };
        let pairs = row.len() / 2;
        let (whole, last) = row.split_at_mut(2 * pairs);
        for (t, out) in whole.chunks_exact_mut(2).enumerate() {
            let (e0, e1, e2, e3) = (combine(0, t), combine(1, t), combine(2, t), combine(3, t));
            out[0] = e0 + e1 + e2;
            out[1] = e1 - e2 - e3;
        }
        if let [out] = last {
            let t = pairs;
            *out = combine(0, t) + combine(1, t) + combine(2, t);
        }
    }
}

/// The convolution of one image ([channels_in, height, width]) with `u` from
/// `weight_for` into `out` ([channels_out, height * width]), with the prologue and
/// epilogue. Requires `applies(s)`.
pub(crate) fn forward_image(
    image: &[f32],
    u: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    assert!(applies(s), "Winograd F(2x2, 3x3) takes 3x3 stride-1 padding-1 convolutions");
    let (c, o, (h, w)) = (s.channels_in, s.channels_out, (s.height, s.width));
    assert_eq!(image.len(), c * h * w, "conv input size");
    assert_eq!(u.len(), 16 * o * c, "transformed weight size");
    assert_eq!(out.len(), o * h * w, "conv output size");
    let (tile_rows, tw) = (h.div_ceil(2), w.div_ceil(2));
    let min_rows = MIN_TILES.div_ceil(tw).max(1);
    let dst = SharedMut(out.as_mut_ptr());
    column_chunks(tile_rows, min_rows, (MAX_TILES / tw).max(min_rows)).into_par_iter().for_each(|rows| {
        let nt = rows.len() * tw;
        let block = (TRANSFORMED_BUDGET / (16 * nt)).clamp(1, c.max(1));
        BUFFERS.with_borrow_mut(|(v, m)| {
            v.resize(v.len().max(16 * block * nt), 0.0);
            m.resize(m.len().max(16 * o * nt), 0.0);
            if c == 0 {
                // No products to write them: a convolution of nothing is zero.
                m[..16 * o * nt].fill(0.0);
            }
            // The task's input rows 2 * rows.start - 1 ..= 2 * rows.end, each split once.
            let mut split = vec![0.0f32; (2 * rows.len() + 2) * 2 * (tw + 1)];
            for c0 in (0..c).step_by(block) {
                let channels = c0..(c0 + block).min(c);
                let stride = channels.len() * nt;
                for (cl, ic) in channels.clone().enumerate() {
                    let plane = &image[ic * h * w..][..h * w];
                    let affine = prologue.map(|q| (q.scale[ic], q.shift[ic]));
                    for (r, halves) in split.chunks_exact_mut(2 * (tw + 1)).enumerate() {
                        let y = (2 * rows.start + r).checked_sub(1).filter(|y| *y < h);
                        let (even, odd) = halves.split_at_mut(tw + 1);
                        split_row(y.map(|y| &plane[y * w..][..w]), affine, even, odd);
                    }
                    let halves = |r: usize| {
                        let row = &split[2 * r * (tw + 1)..][..2 * (tw + 1)];
                        [&row[..tw + 1], &row[tw + 1..]]
                    };
                    for ri in 0..rows.len() {
                        let input = [halves(2 * ri), halves(2 * ri + 1), halves(2 * ri + 2), halves(2 * ri + 3)];
                        transform_input(&input, tw, &mut v[cl * nt + ri * tw..], stride);
                    }
                }
                for xi in 0..16 {
                    // SAFETY: `m` holds 16 [o, nt] products, `v` 16 [channels, nt] blocks and
                    // `u` 16 [o, c] matrices whose columns `c0..` this block reads.
                    unsafe {
                        matmul(
                            [o, nt, channels.len()],
                            m.as_mut_ptr().add(xi * o * nt),
                            [1, nt],
                            c0 > 0,
                            u.as_ptr().add(xi * o * c + c0),
                            [1, c],
                            v.as_ptr().add(xi * stride),
                            [1, nt],
                        );
                    }
                }
            }
            let (y0, y1) = (2 * rows.start, (2 * rows.end).min(h));
            for oc in 0..o {
                // SAFETY: rows `y0..y1` of output channel `oc` belong to this task alone.
                let band = unsafe { std::slice::from_raw_parts_mut(dst.at(oc * h * w + y0 * w), (y1 - y0) * w) };
                for (ri, pair) in band.chunks_mut(2 * w).enumerate() {
                    let (top, bottom) = pair.split_at_mut(w.min(pair.len()));
                    let bottom = (!bottom.is_empty()).then_some(bottom);
                    transform_output(&m[oc * nt + ri * tw..], o * nt, tw, [Some(top), bottom]);
                }
                if !epilogue.is_identity() {
                    epilogue.apply(oc, band);
                }
            }
        });
    });
}
