//! 3x3 stride-1 "same" convolutions by Winograd's minimal filtering, F(2x2, 3x3) here and
//! F(4x4, 3x3) for large images (`winograd4`), through one driver.
//!
//! Each 2x2 block of outputs comes from a 4x4 tile of the input through 16 element-wise
//! products instead of 36 multiply-adds: with the input and the weight moved into the
//! transformed domain (`V = Bt d B`, `U = G g Gt`), the convolution over channels becomes 16
//! matrix products `M[xi] = U[xi] * V[xi]` of 2.25x fewer flops than the gathered (im2col)
//! product, and the output is `At M A`. DenseDepth's decoder is mostly such convolutions. The
//! transforms run over all of a task's tiles in one loop: input rows split into even and odd
//! columns and grouped by row parity make each of a tile's sixteen values one contiguous run
//! across tiles (with a spare tile at the end of each tile row), so they vectorise across tiles
//! however few a row holds. The prologue
//! (eval-mode batch norm + ReLU of the input) and epilogue (bias / folded batch norm, then the
//! activation) are the gathered path's, so the two are interchangeable.

use rayon::prelude::*;

use super::direct::Kernel;
use super::shared::{
    ConvShape, Epilogue, InputRows, Planes, Prologue, RowScratch, SharedMut, aligned, balanced_chunks, column_chunks,
    matmul,
};
use super::winograd4;

/// Transformed input held per thread (products x channels x tiles, f32): the channel block is cut so
/// the block stays about 1 MB.
const TRANSFORMED_BUDGET: usize = 256 * 1024;
/// The same for F(4x4, 3x3), 16 MB: enough for every channel of DenseNet-161's convolutions in
/// one block, so each of the 36 products is one matrix product over all input channels, its
/// output written once. Cut at 1 MB, the products of a large task (up to 2.5 MB in the decoder's
/// last block) were read and written again for every block of 28 channels, from beyond the
/// core's cache: the decoder's blocks took 1.2-1.6x their time now (BENCHMARKS.md, "Products
/// over every channel at once"). F(2x2, 3x3), whose products are smaller, keeps the small
/// block, and with it the quickstart's figures to the last bit.
const TRANSFORMED_BUDGET_FOUR: usize = 4 * 1024 * 1024;
/// The products' columns (tiles) are padded to a multiple of this, the vector width of the
/// widest product kernel: at any other count the `gemm` crate packs a copy of the transformed
/// input into a buffer it allocates on every call.
const PRODUCT_COLUMNS: usize = 16;
/// Tiles per task: enough columns for the products to run at speed.
const MIN_TILES: usize = 32;
const MAX_TILES: usize = 256;
/// The same for F(4x4, 3x3), whose tiles hold four times the outputs: its products (36 x
/// channels_out x tiles) and transformed input stay nearer the core's cache, and an image
/// splits into more tasks to balance (BENCHMARKS.md, "F(4x4, 3x3)'s rows dealt in vector
/// registers, its tasks balanced").
const MAX_TILES_FOUR: usize = 128;

/// One worker's scratch, kept between calls so that a task allocates nothing.
#[derive(Default)]
struct Buffers {
    /// The transformed input, 16 x channels x tiles.
    v: Vec<f32>,
    /// The products, 16 x channels_out x tiles.
    m: Vec<f32>,
    /// The task's input rows split by `split_row`.
    split: Vec<f32>,
    /// One output channel's rows of `At M`, two columns per tile (`transform_output`).
    columns: Vec<f32>,
    /// F(4x4, 3x3)'s input tiles after their first transform (`winograd4::transform_input`).
    rows: Vec<f32>,
}

thread_local! {
    static BUFFERS: std::cell::RefCell<Buffers> = std::cell::RefCell::new(Buffers::default());
}

/// The side of the output block one tile gives: F(2x2, 3x3) or F(4x4, 3x3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Tile {
    Two,
    Four,
}

/// F(4x4, 3x3) takes a convolution whose image holds at least this many of its tiles (two
/// tasks' worth: fewer, and the larger tile leaves a thread idle) and whose weight holds at least
/// this many (output, input) channel pairs (fewer, and its larger transforms cost more than the
/// products it saves): BENCHMARKS.md, "F(4x4, 3x3)".
const FOUR_MIN_TILES: usize = 2 * MIN_TILES;
const FOUR_MIN_PAIRS: usize = 1024;

impl Tile {
    /// The tile for the convolution `s` (which `applies`).
    pub(crate) fn for_shape(s: &ConvShape) -> Tile {
        let tiles = s.height.div_ceil(4) * s.width.div_ceil(4);
        if tiles >= FOUR_MIN_TILES && s.channels_in * s.channels_out >= FOUR_MIN_PAIRS { Tile::Four } else { Tile::Two }
    }

    /// Outputs along each side of a tile.
    fn outputs(self) -> usize {
        match self {
            Tile::Two => 2,
            Tile::Four => 4,
        }
    }

    /// Element-wise products per tile: the tile's input side squared.
    fn products(self) -> usize {
        (self.outputs() + 2).pow(2)
    }
}

/// A 3x3 weight in the transformed domain of its tile.
pub(crate) struct Transformed {
    tile: Tile,
    u: std::sync::Arc<[f32]>,
}

/// Whether this path computes the convolution `s`: 3x3, stride 1, padding 1.
pub(crate) fn applies(s: &ConvShape) -> bool {
    s.kernel == 3 && s.stride == 1 && s.padding == 1 && s.height > 0 && s.width > 0
}

/// The transformed weight when this path computes the convolution `s`; `None` when the
/// gathered product must (the one place that decides between them). `keep`: kept between calls
/// (`weight_cache`), for a network's weights; a training step's, which change every step, and
/// a gradient's flipped copy are transformed and dropped, through F(2x2, 3x3) alone: F(4x4,
/// 3x3)'s transform, 2.25 times larger, made DenseNet-161's training step slower when it ran
/// on every call (BENCHMARKS.md, "F(4x4, 3x3)").
pub(crate) fn weight_for(s: &ConvShape, weight: &[f32], keep: bool) -> Option<Transformed> {
    let tile = if keep { Tile::for_shape(s) } else { Tile::Two };
    applies(s).then(|| weight_with(s, weight, tile, keep))
}

/// `weight_for` through a given tile.
pub(crate) fn weight_with(s: &ConvShape, weight: &[f32], tile: Tile, keep: bool) -> Transformed {
    let (o, c) = (s.channels_out, s.channels_in);
    let transform = || match tile {
        Tile::Two => transform_weight(weight, o, c),
        Tile::Four => winograd4::transform_weight(weight, o, c),
    };
    let u = if keep { super::weight_cache::transformed(weight, tile.outputs(), transform) } else { transform().into() };
    Transformed { tile, u }
}

/// `U = G g Gt` for every (output, input) channel pair, as 16 matrices [channels_out,
/// channels_in]: `u[xi * o * c + oc * c + ic]` with `xi = 4 * row + column`.
fn transform_weight(weight: &[f32], channels_out: usize, channels_in: usize) -> Vec<f32> {
    let (o, c) = (channels_out, channels_in);
    assert_eq!(weight.len(), o * c * 9, "3x3 weight size");
    super::shared::transform_rows(o, c, 16, |oc, runs| {
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
    })
}

/// One input row split into the values a row of tiles reads: `odd[t] = x[2t - 1]` and
/// `even[t] = x[2t]` for tiles `t` in `0..=tiles` (zero outside the row, or for a padding row),
/// through the prologue.
#[inline(always)]
fn split_row(row: Option<&[f32]>, prologue: Option<(f32, f32)>, even: &mut [f32], odd: &mut [f32]) {
    let Some(row) = row else {
        even.fill(0.0);
        odd.fill(0.0);
        return;
    };
    let value = |v: f32| prologue.map_or(v, |(scale, shift)| (v * scale + shift).max(0.0));
    let pairs = row.chunks_exact(2);
    let (n, last) = (row.len() / 2, pairs.remainder().first().copied());
    // The prologue decided outside the loop, so that each arm is one vectorised loop.
    let (even_run, odd_run) = (&mut even[..n], &mut odd[1..=n]);
    match prologue {
        None => deal(row, even_run, odd_run, |v| v),
        Some((scale, shift)) => deal(row, even_run, odd_run, |v| (v * scale + shift).max(0.0)),
    }
    odd[0] = 0.0;
    odd[n + 1..].fill(0.0);
    even[n..].fill(0.0);
    if let Some(v) = last {
        even[n] = value(v);
    }
}

/// `even[t] = f(row[2t])`, `odd[t] = f(row[2t + 1])` for the row's whole pairs.
#[inline(always)]
fn deal(row: &[f32], even: &mut [f32], odd: &mut [f32], f: impl Fn(f32) -> f32) {
    let n = even.len();
    let (row, odd) = (&row[..2 * n], &mut odd[..n]);
    for t in 0..n {
        even[t] = f(row[2 * t]);
        odd[t] = f(row[2 * t + 1]);
    }
}

/// Four disjoint runs of `n` values, `stride` apart, from the start of `v`.
#[inline(always)]
fn four_runs(v: &mut [f32], stride: usize, n: usize) -> [&mut [f32]; 4] {
    let (a, rest) = v.split_at_mut(stride);
    let (b, rest) = rest.split_at_mut(stride);
    let (c, d) = rest.split_at_mut(stride);
    [&mut a[..n], &mut b[..n], &mut c[..n], &mut d[..n]]
}

/// `V = Bt d B` for `n` tiles of one channel, from its input rows split by `split_row` and
/// grouped by parity (`rows[p] = [even, odd]`: the split rows `p, p + 2, ...` one after another,
/// `row_len` values each). Tile `f` starts at split row `2 * (f / row_len)`, column `f % row_len`
/// (the last column of every row is a spare tile, which the caller ignores), so every tile of the
/// task is one run of one loop instead of a call per tile row: at 8x8 a tile row holds 4 tiles,
/// and the per-call setup was most of the time. Writes `v[xi * stride + f]`.
#[inline(always)]
fn transform_input<'a>(rows: [[&'a [f32]; 2]; 2], row_len: usize, n: usize, v: &mut [f32], stride: usize) {
    // Columns 0..4 of a tile are x = 2t - 1, 2t, 2t + 1, 2t + 2; input row j is split row
    // 2 * (tile row) + j, row j / 2 of parity j % 2.
    // (Arrays built by hand: `array::from_fn` and `map` were not inlined, a fifth of a small
    // convolution's time.)
    let [[even0, odd0], [even1, odd1]] = rows;
    let columns = |even: &'a [f32], odd: &'a [f32], at: usize| {
        [&odd[at..][..n], &even[at..][..n], &odd[at + 1..][..n], &even[at + 1..][..n]]
    };
    let d = [
        columns(even0, odd0, 0),
        columns(even1, odd1, 0),
        columns(even0, odd0, row_len),
        columns(even1, odd1, row_len),
    ];
    let (r0, r1, r2, r3) = ((d[0], d[2]), (d[1], d[2]), (d[2], d[1]), (d[1], d[3]));
    let (v0, rest) = v.split_at_mut(4 * stride);
    let (v1, rest) = rest.split_at_mut(4 * stride);
    let (v2, v3) = rest.split_at_mut(4 * stride);
    input_row(r0, |a, b| a - b, four_runs(v0, stride, n));
    input_row(r1, |a, b| a + b, four_runs(v1, stride, n));
    input_row(r2, |a, b| a - b, four_runs(v2, stride, n));
    input_row(r3, |a, b| a - b, four_runs(v3, stride, n));
}

/// One row of `V = Bt d B`: `(Bt d)` row `combine(p, q)` of two input rows' four column runs,
/// times `B`. The runs are cut to one length here, where the loop can see it, so that it has no
/// bounds checks and runs over tiles in vector registers (`transform_input`, `transform_output`
/// and `split_row` took 40 % of a small 3x3 convolution as scalar loops, BENCHMARKS.md).
#[inline(always)]
fn input_row(
    ([p0, p1, p2, p3], [q0, q1, q2, q3]): ([&[f32]; 4], [&[f32]; 4]),
    combine: impl Fn(f32, f32) -> f32,
    [v0, v1, v2, v3]: [&mut [f32]; 4],
) {
    let n = v0.len();
    let (p0, p1, p2, p3) = (&p0[..n], &p1[..n], &p2[..n], &p3[..n]);
    let (q0, q1, q2, q3) = (&q0[..n], &q1[..n], &q2[..n], &q3[..n]);
    let (v1, v2, v3) = (&mut v1[..n], &mut v2[..n], &mut v3[..n]);
    for t in 0..n {
        let (c0, c1, c2, c3) =
            (combine(p0[t], q0[t]), combine(p1[t], q1[t]), combine(p2[t], q2[t]), combine(p3[t], q3[t]));
        v0[t] = c0 - c2;
        v1[t] = c1 + c2;
        v2[t] = c2 - c1;
        v3[t] = c1 - c3;
    }
}

/// `Y = At M A` for the tiles of one output channel, `m[xi * stride + f]` with tile `f` as in
/// `transform_input`, into the output rows `band` ([rows, width], from an even row on): each
/// tile row's two output rows (one at the bottom of an odd height), and a last tile of an odd
/// width writes its left column only. `columns` holds each output row's two columns per tile,
/// reused between calls.
#[inline(always)]
fn transform_output(m: &[f32], stride: usize, row_len: usize, band: &mut [f32], width: usize, columns: &mut Vec<f32>) {
    let tile_rows = band.len().div_ceil(2 * width);
    let n = tile_rows * row_len;
    let run = |xi: usize| &m[xi * stride..][..n];
    columns.resize(4 * n, 0.0);
    let (top, bottom) = columns.split_at_mut(2 * n);
    for (a, halves) in [top, bottom].into_iter().enumerate() {
        // Row a of At M: rows 0 + 1 + 2, or 1 - 2 - 3; then its two columns, for every tile.
        let (ra, rb, rc) = if a == 0 { (0, 1, 2) } else { (1, 2, 3) };
        let sign = if a == 0 { 1.0f32 } else { -1.0 };
        let col = |c: usize| (run(4 * ra + c), run(4 * rb + c), run(4 * rc + c));
        let (left, right) = halves.split_at_mut(n);
        output_columns([col(0), col(1), col(2), col(3)], sign, left, right);
    }
    let pairs = width / 2;
    for (y, row) in band.chunks_exact_mut(width).enumerate() {
        let (ri, half) = (y / 2, if y % 2 == 0 { &columns[..2 * n] } else { &columns[2 * n..] });
        let (left, right) = (&half[ri * row_len..][..row_len], &half[n + ri * row_len..][..row_len]);
        let (whole, last) = row.split_at_mut(2 * pairs);
        for ((out, l), r) in whole.chunks_exact_mut(2).zip(&left[..pairs]).zip(&right[..pairs]) {
            out[0] = *l;
            out[1] = *r;
        }
        if let [out] = last {
            *out = left[pairs];
        }
    }
}

/// The two output columns of every tile of one output row: with `e[c] = s0 + sign s1 + sign s2`
/// for tile column `c` (the rows of `At M`), `left = e0 + e1 + e2` and `right = e1 - e2 - e3`,
/// each added left to right as the tile-row version did, so the outputs are the same bits.
#[inline(always)]
fn output_columns<'a>(e: [(&'a [f32], &'a [f32], &'a [f32]); 4], sign: f32, left: &mut [f32], right: &mut [f32]) {
    let n = left.len();
    let right = &mut right[..n];
    let cut = |(a, b, c): (&'a [f32], &'a [f32], &'a [f32])| (&a[..n], &b[..n], &c[..n]);
    let ((a0, b0, c0), (a1, b1, c1), (a2, b2, c2), (a3, b3, c3)) = (cut(e[0]), cut(e[1]), cut(e[2]), cut(e[3]));
    for t in 0..n {
        let e0 = (a0[t] + sign * b0[t]) + sign * c0[t];
        let e1 = (a1[t] + sign * b1[t]) + sign * c1[t];
        let e2 = (a2[t] + sign * b2[t]) + sign * c2[t];
        let e3 = (a3[t] + sign * b3[t]) + sign * c3[t];
        left[t] = e0 + e1 + e2;
        right[t] = e1 - e2 - e3;
    }
}

/// The convolution of one image ([channels_in, height, width]) with `t` from
/// `weight_for` into `out` ([channels_out, height * width]), with the prologue and
/// epilogue. Requires `applies(s)`.
pub(crate) fn forward_image(
    image: &[f32],
    t: &Transformed,
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    assert_eq!(image.len(), s.channels_in * s.height * s.width, "conv input size");
    let planes = Planes { image, height: s.height, width: s.width };
    forward_rows(Kernel::detect(), &planes, t, s, prologue, epilogue, out);
}

/// `forward_image` with its input's rows read through `input` ([channels_in, height, width]),
/// each task compiled for `kernel`'s vector features (`None`: the baseline's): the same
/// arithmetic in the same order through wider vectors. The network passes the widest this CPU
/// has (`Kernel::detect`); the tests run each.
pub(crate) fn forward_rows<I: InputRows>(
    kernel: Option<Kernel>,
    input: &I,
    t: &Transformed,
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    assert!(applies(s), "Winograd's F(2x2, 3x3) and F(4x4, 3x3) take 3x3 stride-1 padding-1 convolutions");
    assert_eq!(t.u.len(), t.tile.products() * s.channels_out * s.channels_in, "transformed weight size");
    match t.tile {
        Tile::Two => forward_tiles::<2, I>(kernel, input, &t.u, s, prologue, epilogue, out),
        Tile::Four => forward_tiles::<4, I>(kernel, input, &t.u, s, prologue, epilogue, out),
    }
}

/// `forward_rows` through tiles of `SIDE` outputs a side: one copy of the driver for each, so
/// that each inlines its own transforms (one driver for both ran the quickstart's network,
/// which takes F(2x2, 3x3) alone, 3-7 % slower).
fn forward_tiles<const SIDE: usize, I: InputRows>(
    kernel: Option<Kernel>,
    input: &I,
    u: &[f32],
    s: &ConvShape,
    prologue: Option<Prologue>,
    epilogue: &Epilogue,
    out: &mut [f32],
) {
    assert_eq!(out.len(), s.channels_out * s.height * s.width, "conv output size");
    let (tile_rows, tw) = (s.height.div_ceil(SIDE), s.width.div_ceil(SIDE));
    let min_rows = MIN_TILES.div_ceil(tw).max(1);
    let dst = SharedMut(out.as_mut_ptr());
    let task = Task { input, u, s, prologue, epilogue, dst, kernel };
    let chunks = if SIDE == 2 {
        column_chunks(tile_rows, min_rows, (MAX_TILES / tw).max(min_rows))
    } else {
        // Five tasks on two threads left one idle for a fifth of a dense layer's 3x3 convolution
        // at 120x160: as many tasks as a multiple of the threads.
        balanced_chunks(tile_rows, min_rows, (MAX_TILES_FOUR / tw).max(1))
    };
    chunks.into_par_iter().for_each(|rows| {
        let task = &task;
        match kernel {
            // SAFETY: `Kernel::detect` (or `each_detected`) found these features on this CPU.
            #[cfg(target_arch = "x86_64")]
            Some(Kernel::Avx512) => unsafe { tiles_avx512::<SIDE, I>(task, rows) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Some(Kernel::Avx2) => unsafe { tiles_avx2::<SIDE, I>(task, rows) },
            None => tiles::<SIDE, I>(task, rows),
        }
    });
}

/// What every task of one convolution reads, and where it writes.
struct Task<'a, I> {
    input: &'a I,
    u: &'a [f32],
    s: &'a ConvShape,
    prologue: Option<Prologue<'a>>,
    epilogue: &'a Epilogue<'a>,
    dst: SharedMut,
    /// The vector kernel the task runs under (for `deal::quads`).
    kernel: Option<Kernel>,
}

/// `tiles` compiled for wider vectors: its transforms (all inlined into it) vectorise over 8 or
/// 16 tiles at once instead of the baseline's 4.
macro_rules! tiles_for {
    ($name:ident, $features:literal) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $name<const SIDE: usize, I: InputRows>(task: &Task<'_, I>, rows: std::ops::Range<usize>) {
            tiles::<SIDE, I>(task, rows)
        }
    };
}
tiles_for!(tiles_avx512, "avx512f,avx2,fma");
tiles_for!(tiles_avx2, "avx2,fma");

/// One task: the tile rows `rows`, from the input's rows through the transforms and products
/// to the output's rows.
#[inline(always)]
fn tiles<const SIDE: usize, I: InputRows>(task: &Task<'_, I>, rows: std::ops::Range<usize>) {
    let Task { input, u, s, prologue, epilogue, dst, kernel } = *task;
    let (c, o, (h, w)) = (s.channels_in, s.channels_out, (s.height, s.width));
    let (side, products) = (SIDE, (SIDE + 2) * (SIDE + 2));
    let tw = w.div_ceil(side);
    // Each tile row has a spare tile at its end (see `transform_input`).
    let row_len = tw + 1;
    let nt = (rows.len() * row_len).next_multiple_of(PRODUCT_COLUMNS);
    let budget = if SIDE == 2 { TRANSFORMED_BUDGET } else { TRANSFORMED_BUDGET_FOUR };
    let block = (budget / (products * nt)).clamp(1, c.max(1));
    // Out of the thread-local and back after, rather than in a closure: a closure would be
    // compiled apart from this function's vector features.
    let mut buffers = BUFFERS.take();
    let Buffers { v, m, split, columns, rows: scratch } = &mut buffers;
    // The rows an input computes when read (`InputRows::row`), in a scratch of the task's own:
    // what it keeps between rows must never outlive the input it was computed from.
    let line = &mut RowScratch::default();
    // Both from a cache line on: `nt` is a multiple of sixteen, so every run of them starts on one.
    let v = aligned(v, products * block * nt);
    let m = aligned(m, products * o * nt);
    if c == 0 {
        // No products to write them: a convolution of nothing is zero.
        m[..products * o * nt].fill(0.0);
    }
    // The task's input rows side * rows.start - 1 ..= side * rows.end, each split once
    // into its column phases and grouped by row phase: run (row phase q, column phase
    // k) at `(side * q + k) * len`, then zeros, which the spare tiles up to `nt` read
    // (their products are computed and never read; zeros keep them finite whatever the
    // buffer held before). F(2x2, 3x3)'s two phases are [even, odd] columns.
    let (rows_len, len) = ((rows.len() + 1) * row_len, row_len + 1 + nt);
    let runs = side * side;
    split.resize(split.len().max(runs * len), 0.0);
    split[..runs * len].chunks_exact_mut(len).for_each(|run| run[rows_len..].fill(0.0));
    for c0 in (0..c).step_by(block) {
        let channels = c0..(c0 + block).min(c);
        let stride = channels.len() * nt;
        for (cl, ic) in channels.clone().enumerate() {
            let affine = prologue.map(|q| (q.scale[ic], q.shift[ic]));
            for r in 0..side * rows.len() + 2 {
                let y = (side * rows.start + r).checked_sub(1).filter(|y| *y < h);
                // A `match`, not `Option::map`: the closure was compiled apart from this
                // function's vector features, and the upsampled rows it computes with them.
                #[allow(clippy::manual_map)]
                let row = match y {
                    Some(y) => Some(input.row(ic, y, line)),
                    None => None,
                };
                let (group, at) = (&mut split[(r % side) * side * len..], (r / side) * row_len);
                if SIDE == 2 {
                    let (even, odd) = group.split_at_mut(len);
                    split_row(row, affine, &mut even[at..][..row_len], &mut odd[at..][..row_len]);
                } else {
                    winograd4::split_row(row, affine, group, len, at, row_len, kernel);
                }
            }
            let v = &mut v[cl * nt..];
            if SIDE == 2 {
                let parity = |p: usize| {
                    let (even, odd) = split[2 * p * len..][..2 * len].split_at(len);
                    [even, odd]
                };
                transform_input([parity(0), parity(1)], row_len, nt, v, stride);
            } else {
                winograd4::transform_input(split, len, row_len, nt, v, stride, scratch);
            }
        }
        for xi in 0..products {
            // SAFETY: `m` holds `products` [o, nt] products, `v` as many [channels, nt]
            // blocks and `u` as many [o, c] matrices whose columns `c0..` this block reads.
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
    let (y0, y1) = (side * rows.start, (side * rows.end).min(h));
    for oc in 0..o {
        // SAFETY: rows `y0..y1` of output channel `oc` belong to this task alone.
        let band = unsafe { std::slice::from_raw_parts_mut(dst.at(oc * h * w + y0 * w), (y1 - y0) * w) };
        if SIDE == 2 {
            transform_output(&m[oc * nt..], o * nt, row_len, band, w, columns);
        } else {
            winograd4::transform_output(&m[oc * nt..], o * nt, row_len, band, w, columns);
        }
        if !epilogue.is_identity() {
            epilogue.apply(oc, band);
        }
    }
    BUFFERS.set(buffers);
}
