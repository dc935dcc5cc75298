//! Bilinear upsampling with `align_corners = true`, as DenseDepth's decoder does it.
//!
//! Burn 0.22's `interpolate` has a backward pass only on flex; on wgpu and cuda it panics. The
//! trainable path writes the same interpolation as two small matrices applied with `matmul`
//! (rows, then columns), which every backend differentiates.

use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

use crate::backend::{flex_f32, flex_tensor, from_flex, slice};

/// How to upsample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Upsample {
    /// Burn's `interpolate`: fastest; differentiable on flex only.
    Native,
    /// Separable interpolation matrices and `matmul`: differentiable everywhere.
    Matmul,
}

/// For each of `output` samples: the two input samples it blends and the weight of the second
/// (source position `i * (input - 1) / (output - 1)`, PyTorch's align-corners rule).
fn taps(output: usize, input: usize) -> Vec<(usize, usize, f32)> {
    (0..output)
        .map(|i| {
            let src = if output > 1 { i as f64 * (input - 1) as f64 / (output - 1) as f64 } else { 0.0 };
            let i0 = (src.floor() as usize).min(input - 1);
            (i0, (i0 + 1).min(input - 1), (src - i0 as f64) as f32)
        })
        .collect()
}

/// Row `i` holds the weights of output sample `i` over the `input` samples.
pub fn interpolation_matrix(output: usize, input: usize) -> Vec<f32> {
    let mut m = vec![0.0f32; output * input];
    for (i, (i0, i1, frac)) in taps(output, input).into_iter().enumerate() {
        m[i * input + i0] += 1.0 - frac;
        m[i * input + i1] += frac;
    }
    m
}

/// `cat([upsample_bilinear(x, skip's size, mode), skip], 1)`. Each decoder block upsamples its
/// input and concatenates the skip behind it; through Burn these were two passes over the
/// largest tensors of the network (at 480x640, 300 ms in the last block: 147 ms interpolating,
/// 159 ms concatenating). On flex outside autodiff it is one pass that writes the output once.
pub fn upsample_concat(x: Tensor<4>, skip: Tensor<4>, mode: Upsample) -> Tensor<4> {
    let ([n, c1, h, w], [_, c2, oh, ow]) = (x.dims(), skip.dims());
    let (Some(input), Some(skip_flex), Upsample::Native) = (flex_f32(&x), flex_f32(&skip), mode) else {
        return Tensor::cat(vec![upsample_bilinear(x, [oh, ow], mode), skip], 1);
    };
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
        let wide: Vec<f32> = plane
            .chunks_exact(w)
            .flat_map(|row| cols.iter().map(move |&(j0, j1, f)| row[j0] + (row[j1] - row[j0]) * f))
            .collect();
        for (dst_row, &(i0, i1, f)) in dst.chunks_exact_mut(ow).zip(&rows) {
            let (r0, r1) = (&wide[i0 * ow..][..ow], &wide[i1 * ow..][..ow]);
            for ((d, a), b) in dst_row.iter_mut().zip(r0).zip(r1) {
                *d = a + (b - a) * f;
            }
        }
    });
    from_flex(flex_tensor(out, &[n, c1 + c2, oh, ow]))
}

/// Upsamples `x` ([N, C, h, w]) to `size` = [H, W].
pub fn upsample_bilinear(x: Tensor<4>, size: [usize; 2], mode: Upsample) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    if [h, w] == size {
        return x;
    }
    match mode {
        Upsample::Native => interpolate(
            x,
            InterpolateOptions::new(InterpolateMode::Bilinear).with_align_corners(true).with_output_size(size),
        ),
        Upsample::Matmul => {
            let device = x.device();
            let [oh, ow] = size;
            let rows = Tensor::<2>::from_data(TensorData::new(interpolation_matrix(oh, h), [oh, h]), &device);
            let cols = Tensor::<2>::from_data(TensorData::new(interpolation_matrix(ow, w), [ow, w]), &device);
            // Columns: [N*C*h, w] x [w, W].
            let x = x.reshape([n * c * h, w]).matmul(cols.transpose());
            // Rows: [1, H, h] x [N*C, h, W], broadcast over the batch.
            let x = rows.unsqueeze::<3>().matmul(x.reshape([n * c, h, ow]));
            x.reshape([n, c, oh, ow])
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Distribution, Tolerance};

    /// The one-pass kernel against Burn's interpolate and cat: upsampling 2x (the decoder's
    /// case), to an uneven size, and the identity size; batch 2 with different channel counts.
    #[test]
    fn one_pass_equals_interpolate_then_cat() {
        let device = crate::backend::default_device();
        for ([h, w], [oh, ow]) in [([3, 4], [6, 8]), ([5, 3], [9, 11]), ([4, 4], [4, 4]), ([1, 2], [3, 4])] {
            let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
            let skip = Tensor::<4>::random([2, 2, oh, ow], Distribution::Normal(0.0, 1.0), &device);
            let expected = Tensor::cat(vec![upsample_bilinear(x.clone(), [oh, ow], Upsample::Native), skip.clone()], 1);
            upsample_concat(x, skip, Upsample::Native)
                .into_data()
                .assert_approx_eq::<f32>(&expected.into_data(), Tolerance::rel_abs(1e-5, 1e-6));
        }
    }
}
