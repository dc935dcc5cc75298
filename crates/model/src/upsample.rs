//! Bilinear upsampling with `align_corners = true`, as DenseDepth's decoder does it.
//!
//! Burn 0.22's `interpolate` has a backward pass only on flex; on wgpu and cuda it panics. The
//! trainable path writes the same interpolation as two small matrices applied with `matmul`
//! (rows, then columns), which every backend differentiates.

use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Tensor, TensorData};

/// How to upsample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Upsample {
    /// Burn's `interpolate`: fastest; differentiable on flex only.
    Native,
    /// Separable interpolation matrices and `matmul`: differentiable everywhere.
    Matmul,
}

/// Row `i` holds the weights of output sample `i` over the `input` samples
/// (source position `i * (input - 1) / (output - 1)`, PyTorch's align-corners rule).
pub fn interpolation_matrix(output: usize, input: usize) -> Vec<f32> {
    let mut m = vec![0.0f32; output * input];
    for i in 0..output {
        let src = if output > 1 { i as f64 * (input - 1) as f64 / (output - 1) as f64 } else { 0.0 };
        let i0 = (src.floor() as usize).min(input - 1);
        let i1 = (i0 + 1).min(input - 1);
        let frac = (src - i0 as f64) as f32;
        m[i * input + i0] += 1.0 - frac;
        m[i * input + i1] += frac;
    }
    m
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
