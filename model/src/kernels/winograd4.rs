//! The transforms of Winograd's F(4x4, 3x3), for `winograd`'s driver.
//!
//! Each 4x4 block of outputs comes from a 6x6 input tile through 36 element-wise products: 2.25
//! products per output against F(2x2, 3x3)'s 4 and the direct convolution's 9, so the matrix
//! products that are most of a large 3x3 convolution's time shrink by 44 %. The points are 0, +-1,
//! +-2 and infinity (Lavin and Gray's matrices); their larger constants cost accuracy, about
//! ten times F(2x2, 3x3)'s rounding error, which is why `winograd::Tile::for_shape` keeps this
//! for large images only. The layout follows `winograd`'s: input rows dealt into four phases by
//! column (`phase k [t] = x[4t + k - 1]`) and grouped by row phase, so each of a tile's 36 input
//! values is one contiguous run across every tile of a task (a spare tile at the end of each
//! tile row).

use super::direct::Kernel;
use super::shared::aligned;

/// The input transform `Bt x` of six runs, into six runs.
#[inline(always)]
fn bt(x: [&[f32]; 6], y: [&mut [f32]; 6]) {
    let n = y[0].len();
    let [x0, x1, x2, x3, x4, x5] = x;
    let (x0, x1, x2, x3, x4, x5) = (&x0[..n], &x1[..n], &x2[..n], &x3[..n], &x4[..n], &x5[..n]);
    let [y0, y1, y2, y3, y4, y5] = y;
    let (y0, y1, y2, y3, y4, y5) = (&mut y0[..n], &mut y1[..n], &mut y2[..n], &mut y3[..n], &mut y4[..n], &mut y5[..n]);
    for t in 0..n {
        let (a, b, c, d, e, f) = (x0[t], x1[t], x2[t], x3[t], x4[t], x5[t]);
        y0[t] = 4.0 * a - 5.0 * c + e;
        y1[t] = (d + e) - 4.0 * (b + c);
        y2[t] = (e - d) + 4.0 * (b - c);
        y3[t] = (e - c) + 2.0 * (d - b);
        y4[t] = (e - c) - 2.0 * (d - b);
        y5[t] = 4.0 * b - 5.0 * d + f;
    }
}

/// The output transform `At x` of six runs, into four runs.
#[inline(always)]
fn at(x: [&[f32]; 6], y: [&mut [f32]; 4]) {
    let n = y[0].len();
    let [x0, x1, x2, x3, x4, x5] = x;
    let (x0, x1, x2, x3, x4, x5) = (&x0[..n], &x1[..n], &x2[..n], &x3[..n], &x4[..n], &x5[..n]);
    let [y0, y1, y2, y3] = y;
    let (y0, y1, y2, y3) = (&mut y0[..n], &mut y1[..n], &mut y2[..n], &mut y3[..n]);
    for t in 0..n {
        let (a, b, c, d, e, f) = (x0[t], x1[t], x2[t], x3[t], x4[t], x5[t]);
        let (sum1, diff1, sum2, diff2) = (b + c, b - c, d + e, d - e);
        y0[t] = a + sum1 + sum2;
        y1[t] = diff1 + 2.0 * diff2;
        y2[t] = sum1 + 4.0 * sum2;
        y3[t] = diff1 + 8.0 * diff2 + f;
    }
}

/// `K` disjoint runs of `n` values, `stride` apart, from `offset` in `v`.
#[inline(always)]
fn runs_mut<const K: usize>(v: &mut [f32], offset: usize, stride: usize, n: usize) -> [&mut [f32]; K] {
    let mut rest = &mut v[offset..];
    let mut out: [&mut [f32]; K] = std::array::from_fn(|_| Default::default());
    for (k, slot) in out.iter_mut().enumerate() {
        let take = if k + 1 < K { stride } else { n };
        let (run, tail) = std::mem::take(&mut rest).split_at_mut(take);
        *slot = &mut run[..n];
        rest = tail;
    }
    out
}

/// `G x` for one column `(a, b, d)` of a 3x3 weight: its six values in the transformed domain.
#[inline(always)]
fn g(a: f32, b: f32, d: f32) -> [f32; 6] {
    const SIXTH: f32 = 1.0 / 6.0;
    const TWELFTH: f32 = 1.0 / 12.0;
    let (ends, quarter) = (a + d, a * 0.25 + d);
    [
        a * 0.25,
        -(ends + b) * SIXTH,
        -(ends - b) * SIXTH,
        quarter * SIXTH + b * TWELFTH,
        quarter * SIXTH - b * TWELFTH,
        d,
    ]
}

/// Input channels transformed together: one vector of each of the 36 values.
const LANES: usize = 16;

/// `U = G g Gt` for every (output, input) channel pair, as 36 matrices [channels_out,
/// channels_in]: `u[xi * o * c + oc * c + ic]` with `xi = 6 * row + column`. Sixteen input
/// channels at a time, so that the loop over them vectorises: one pair at a time, in f64, it
/// took longer than DenseNet-161's largest convolution itself (the transform runs once for a
/// kept weight, but on every load and for each new input size).
pub(super) fn transform_weight(weight: &[f32], channels_out: usize, channels_in: usize) -> Vec<f32> {
    let (o, c) = (channels_out, channels_in);
    assert_eq!(weight.len(), o * c * 9, "3x3 weight size");
    super::shared::transform_rows(o, c, 36, |oc, runs| {
        let w = &weight[oc * c * 9..][..c * 9];
        for ic0 in (0..c).step_by(LANES) {
            let k = LANES.min(c - ic0);
            let mut taps = [[0.0f32; LANES]; 9];
            for (lane, tap) in w[ic0 * 9..][..k * 9].chunks_exact(9).enumerate() {
                for (j, v) in tap.iter().enumerate() {
                    taps[j][lane] = *v;
                }
            }
            let mut out = [[0.0f32; LANES]; 36];
            for lane in 0..LANES {
                // G g, column by column; then each of its rows times Gt.
                let columns = [0, 1, 2].map(|col| g(taps[col][lane], taps[3 + col][lane], taps[6 + col][lane]));
                for row in 0..6 {
                    let r = g(columns[0][row], columns[1][row], columns[2][row]);
                    for (col, value) in r.into_iter().enumerate() {
                        out[6 * row + col][lane] = value;
                    }
                }
            }
            for (xi, values) in out.iter().enumerate() {
                runs[xi * c + ic0..][..k].copy_from_slice(&values[..k]);
            }
        }
    })
}

/// One input row dealt into the four column phases a row of tiles reads, `phases[k][t] = x[4t +
/// k - 1]` for tiles `t` in `0..row_len` (zero outside the row, or for a padding row), through
/// the prologue. `group` holds the four phases `len` apart; this row's values start at `at`.
/// `kernel`: the caller's vector kernel, for `deal::quads`.
#[inline(always)]
pub(super) fn split_row(
    row: Option<&[f32]>,
    prologue: Option<(f32, f32)>,
    group: &mut [f32],
    len: usize,
    at: usize,
    row_len: usize,
    kernel: Option<Kernel>,
) {
    let [p0, p1, p2, p3] = runs_mut::<4>(group, at, len, row_len);
    for p in [&mut *p0, &mut *p1, &mut *p2, &mut *p3] {
        p.fill(0.0);
    }
    let Some(row) = row else { return };
    let quads = row.len() / 4;
    let value = |v: f32| prologue.map_or(v, |(scale, shift)| (v * scale + shift).max(0.0));
    // x[4t + 3] is phase 0's value of tile t + 1.
    let [w0, w1, w2, w3] = [&mut p1[..quads], &mut p2[..quads], &mut p3[..quads], &mut p0[1..=quads]];
    super::deal::quads(row, [&mut *w0, &mut *w1, &mut *w2, &mut *w3], kernel);
    // The prologue afterwards, over runs now in cache: one vectorised loop each.
    if let Some((scale, shift)) = prologue {
        for run in [w0, w1, w2, w3] {
            run.iter_mut().for_each(|v| *v = (*v * scale + shift).max(0.0));
        }
    }
    for (i, &v) in row.iter().enumerate().skip(4 * quads) {
        let (phase, t) = ((i + 1) % 4, (i + 1) / 4);
        [&mut *p0, &mut *p1, &mut *p2, &mut *p3][phase][t] = value(v);
    }
}

/// `V = Bt d B` for `n` tiles of one channel from its dealt rows: run `(q, k)` (row phase q,
/// column phase k) at `split[(4q + k) * len ..]`, tile row `r` of it at `r * row_len`. Input
/// value (j, i) of tile `f` is run `(j % 4, i % 4)` at `f + (j / 4) * row_len + i / 4`. Writes
/// `v[xi * stride + f]`; `rows` is scratch for 36 runs of `n`.
#[inline(always)]
pub(super) fn transform_input(
    split: &[f32],
    len: usize,
    row_len: usize,
    n: usize,
    v: &mut [f32],
    stride: usize,
    rows: &mut Vec<f32>,
) {
    let rows = aligned(rows, 36 * n);
    let value = |j: usize, i: usize| &split[(4 * (j % 4) + i % 4) * len + (j / 4) * row_len + i / 4..][..n];
    // d B, row by row: rows[(6j + k) * n + f].
    for j in 0..6 {
        let x = [value(j, 0), value(j, 1), value(j, 2), value(j, 3), value(j, 4), value(j, 5)];
        bt(x, runs_mut::<6>(rows, 6 * j * n, n, n));
    }
    // Bt (d B), column by column.
    for k in 0..6 {
        let x: [&[f32]; 6] = std::array::from_fn(|j| &rows[(6 * j + k) * n..][..n]);
        let [y0, y1, y2, y3, y4, y5] = runs_mut::<6>(v, k * stride, 6 * stride, n);
        bt(x, [y0, y1, y2, y3, y4, y5]);
    }
}

/// `Y = At M A` for the tiles of one output channel, `m[xi * stride + f]` with tile `f` as in
/// `transform_input`, into the output rows `band` ([rows, width], from a multiple of four on):
/// a last tile row or column past the image writes only the rows and columns inside it.
/// `scratch` holds `At M` and then `Y` as runs of tiles, reused between calls.
#[inline(always)]
pub(super) fn transform_output(
    m: &[f32],
    stride: usize,
    row_len: usize,
    band: &mut [f32],
    width: usize,
    scratch: &mut Vec<f32>,
) {
    let tile_rows = band.len().div_ceil(4 * width);
    let n = tile_rows * row_len;
    let (half, y) = aligned(scratch, 40 * n).split_at_mut(24 * n);
    // At M, column by column: half[(6r + k) * n + f].
    for k in 0..6 {
        let x: [&[f32]; 6] = std::array::from_fn(|j| &m[(6 * j + k) * stride..][..n]);
        at(x, runs_mut::<4>(half, k * n, 6 * n, n));
    }
    // (At M) A, row by row: y[(4r + c) * n + f].
    for r in 0..4 {
        let x: [&[f32]; 6] = std::array::from_fn(|k| &half[(6 * r + k) * n..][..n]);
        at(x, runs_mut::<4>(y, 4 * r * n, n, n));
    }
    let quads = width / 4;
    for (row_index, row) in band.chunks_exact_mut(width).enumerate() {
        let (tile_row, r) = (row_index / 4, row_index % 4);
        let column = |c: usize| &y[(4 * r + c) * n + tile_row * row_len..][..row_len];
        let (c0, c1, c2, c3) = (column(0), column(1), column(2), column(3));
        let (whole, last) = row.split_at_mut(4 * quads);
        for (t, out) in whole.chunks_exact_mut(4).enumerate() {
            out[0] = c0[t];
            out[1] = c1[t];
            out[2] = c2[t];
            out[3] = c3[t];
        }
        for (c, out) in last.iter_mut().enumerate() {
            *out = [c0, c1, c2, c3][c][quads];
        }
    }
}
