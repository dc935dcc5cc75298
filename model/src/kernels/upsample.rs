//! Bilinear upsample (`align_corners = true`) and concatenation in one pass on flex, or read row
//! by row by the convolution that follows them.
//!
//! Each decoder block upsamples its input and concatenates the skip behind it; through Burn
//! these were two passes over the largest tensors of the network (at 480x640, 300 ms in the
//! last block: 147 ms interpolating, 159 ms concatenating). Here the output is written once
//! (`upsample_concat`), or not at all (`upsample_concat_conv`).

use burn::nn::conv::Conv2d;
use burn::tensor::Tensor;
use rayon::prelude::*;

use super::conv::{flex_bias, gemm_padding};
use super::direct::Kernel;
use super::flex::{contiguous, flex_f32, flex_tensor, from_flex, slice};
use super::shared::{Activation, ConvShape, Epilogue, InputRows, RowScratch};
use super::winograd;

/// For each of `output` samples: the two input samples it blends and the weight of the second
/// (source position `i * (input - 1) / (output - 1)`, PyTorch's align-corners rule).
pub(crate) fn taps(output: usize, input: usize) -> Vec<(usize, usize, f32)> {
    (0..output)
        .map(|i| {
            let src = if output > 1 { i as f64 * (input - 1) as f64 / (output - 1) as f64 } else { 0.0 };
            let i0 = (src.floor() as usize).min(input - 1);
            (i0, (i0 + 1).min(input - 1), (src - i0 as f64) as f32)
        })
        .collect()
}

/// `cat([upsample(x, skip's size), skip], 1)` when both are f32 on flex outside autodiff.
pub(crate) fn upsample_concat(x: &Tensor<4>, skip: &Tensor<4>) -> Option<Tensor<4>> {
    let ([n, c1, h, w], [_, c2, oh, ow]) = (x.dims(), skip.dims());
    let (input, skip_flex) = (flex_f32(x)?, flex_f32(skip)?);
    let (x, skip) = (slice(&input), slice(&skip_flex));
    let (rows, cols) = (taps(oh, h), taps(ow, w));
    let mut out = vec![0.0f32; n * (c1 + c2) * oh * ow];
    out.par_chunks_mut(oh * ow).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / (c1 + c2), i % (c1 + c2));
        if ch >= c1 {
            dst.copy_from_slice(&skip[(b * c2 + ch - c1) * oh * ow..][..oh * ow]);
            return;
        }
        let plane = &x[(b * c1 + ch) * h * w..][..h * w];
        // Each input row interpolated along the width once, then rows blended.
        let mut wide = vec![0.0f32; h * ow];
        for (row, out) in plane.chunks_exact(w).zip(wide.chunks_exact_mut(ow)) {
            widen(row, &cols, out);
        }
        for (dst_row, &(i0, i1, f)) in dst.chunks_exact_mut(ow).zip(&rows) {
            blend(&wide[i0 * ow..][..ow], &wide[i1 * ow..][..ow], f, dst_row);
        }
    });
    Some(from_flex(flex_tensor(out, &[n, c1 + c2, oh, ow])))
}

/// `out[j]`: `row` at output column `j`, blended between its two taps.
#[inline(always)]
fn widen(row: &[f32], cols: &[(usize, usize, f32)], out: &mut [f32]) {
    for (o, &(j0, j1, f)) in out.iter_mut().zip(cols) {
        *o = row[j0] + (row[j1] - row[j0]) * f;
    }
}

/// `out = a + (b - a) * f`, value by value.
#[inline(always)]
fn blend(a: &[f32], b: &[f32], f: f32, out: &mut [f32]) {
    for ((d, a), b) in out.iter_mut().zip(a).zip(b) {
        *d = a + (b - a) * f;
    }
}

/// One image's `cat([upsample(x, skip's size), skip], 1)` read row by row: an upsampled row is
/// computed from its two input rows when read, a skip row read in place.
struct UpsampledConcat<'a> {
    /// [channels, h, w].
    x: &'a [f32],
    /// [skip channels, out_h, out_w].
    skip: &'a [f32],
    channels: usize,
    hw: [usize; 2],
    out_hw: [usize; 2],
    rows: &'a [(usize, usize, f32)],
    cols: &'a [(usize, usize, f32)],
}

impl InputRows for UpsampledConcat<'_> {
    #[inline(always)]
    fn row<'a>(&'a self, channel: usize, y: usize, scratch: &'a mut RowScratch) -> &'a [f32] {
        let ([h, w], [oh, ow]) = (self.hw, self.out_hw);
        if channel >= self.channels {
            return &self.skip[((channel - self.channels) * oh + y) * ow..][..ow];
        }
        // Two widened source rows kept in the scratch's first two parts, keyed by (channel,
        // source row): consecutive output rows share them, so each is widened once a task.
        let RowScratch { values, keys } = scratch;
        values.resize(3 * ow, 0.0);
        let (i0, i1, f) = self.rows[y];
        let plane = &self.x[channel * h * w..][..h * w];
        let mut part = |source: usize, other: usize| {
            let key = Some((channel, source));
            if let Some(at) = keys.iter().position(|k| *k == key) {
                return at;
            }
            // Overwrite the part the other source row does not need.
            let at = if keys[0] == Some((channel, other)) { 1 } else { 0 };
            widen(&plane[source * w..][..w], self.cols, &mut values[at * ow..][..ow]);
            keys[at] = key;
            at
        };
        let top = part(i0, i1);
        let bottom = part(i1, i0);
        let (parts, row) = values.split_at_mut(2 * ow);
        blend(&parts[top * ow..][..ow], &parts[bottom * ow..][..ow], f, row);
        row
    }
}

/// `conv(cat([upsample(x, skip's size), skip], 1))` with the convolution's bias and `activation`,
/// when both are f32 on flex outside autodiff and the convolution is 3x3, stride 1, padding 1
/// (Winograd's): the concatenation is computed row by row as the convolution reads it and never
/// written whole (DenseNet-161's last decoder block's is 72 MB at 480x640, freshly mapped on
/// every forward). The same values as `upsample_concat` then the convolution, bit for bit.
pub(crate) fn upsample_concat_conv(
    x: &Tensor<4>,
    skip: &Tensor<4>,
    conv: &Conv2d,
    activation: Activation,
) -> Option<Tensor<4>> {
    let ([n, c1, h, w], [n2, c2, oh, ow]) = (x.dims(), skip.dims());
    let [o, c, k, _] = conv.weight.dims();
    if n != n2 || c != c1 + c2 || k != 3 || gemm_padding(conv, skip)? != (1, 1) {
        return None;
    }
    let (input, skip_flex) = (contiguous(flex_f32(x)?), contiguous(flex_f32(skip)?));
    let (weight, bias) = (contiguous(flex_f32(&conv.weight.val())?), flex_bias(conv)?.map(contiguous));
    let s = ConvShape {
        batch: 1,
        channels_in: c,
        channels_out: o,
        height: oh,
        width: ow,
        kernel: 3,
        padding: 1,
        stride: 1,
    };
    let u = winograd::weight_for(&s, slice(&weight), true)?;
    let (x, skip) = (slice(&input), slice(&skip_flex));
    let (rows, cols) = (taps(oh, h), taps(ow, w));
    let epilogue = Epilogue::bias(bias.as_ref().map(slice), activation);
    let mut out = vec![0.0f32; n * o * oh * ow];
    out.par_chunks_mut(o * oh * ow).enumerate().for_each(|(b, dst)| {
        let input = UpsampledConcat {
            x: &x[b * c1 * h * w..][..c1 * h * w],
            skip: &skip[b * c2 * oh * ow..][..c2 * oh * ow],
            channels: c1,
            hw: [h, w],
            out_hw: [oh, ow],
            rows: &rows,
            cols: &cols,
        };
        winograd::forward_rows(Kernel::detect(), &input, &u, &s, None, &epilogue, dst);
    });
    Some(from_flex(flex_tensor(out, &[n, o, oh, ow])))
}
