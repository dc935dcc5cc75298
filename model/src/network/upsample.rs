//! Bilinear upsampling with `align_corners = true`, as DenseDepth's decoder does it.
//!
//! Burn 0.22's `interpolate` has a backward pass only on flex; on wgpu and cuda the backward of
//! bilinear interpolation is not implemented and panics (upstream: tracel-ai/burn#3863,
//! "Support bilinear and bicubic interpolation backward operations", and the leftover list of
//! tracel-ai/burn#1393). So the trainable path writes the same interpolation as two small
//! matrices applied with `matmul` (rows, then columns), which every backend differentiates.

use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor, TensorData};

use crate::kernels;

/// How to upsample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Upsample {
    /// Burn's `interpolate`: fastest; differentiable on flex only.
    Native,
    /// Separable interpolation matrices and `matmul`: differentiable everywhere.
    Matmul,
}

/// Native upsampling except where autodiff meets a backend without its backward pass
/// (everything but flex in Burn 0.22).
pub fn upsample_mode_for(device: &Device) -> Upsample {
    if device.is_autodiff() && !format!("{device:?}").contains("Flex") { Upsample::Matmul } else { Upsample::Native }
}

/// Row `i` holds the weights of output sample `i` over the `input` samples.
pub fn interpolation_matrix(output: usize, input: usize) -> Vec<f32> {
    let mut m = vec![0.0f32; output * input];
    for (i, (i0, i1, frac)) in kernels::bilinear_taps(output, input).into_iter().enumerate() {
        m[i * input + i0] += 1.0 - frac;
        m[i * input + i1] += frac;
    }
    m
}

/// `cat([upsample_bilinear(x, skip's size, mode), skip], 1)`: what each decoder block does
/// first. One pass on flex outside autodiff.
pub(crate) fn upsample_concat(x: Tensor<4>, skip: Tensor<4>, mode: Upsample) -> Tensor<4> {
    if mode == Upsample::Native
        && let Some(out) = kernels::upsample_concat(&x, &skip)
    {
        return out;
    }
    let [_, _, oh, ow] = skip.dims();
    Tensor::cat(vec![upsample_bilinear(x, [oh, ow], mode), skip], 1)
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

    #[test]
    fn flex_keeps_the_native_upsample_even_when_training() {
        let flex = crate::backend::default_device();
        assert_eq!(upsample_mode_for(&flex), Upsample::Native);
        assert_eq!(upsample_mode_for(&flex.autodiff()), Upsample::Native);
    }

    /// The one-pass kernel against Burn's interpolate and cat: upsampling 2x (the decoder's
    /// case), to an uneven size, and the identity size; batch 2 with different channel counts.
    #[test]
    fn one_pass_equals_interpolate_then_cat() {
        let device = crate::backend::default_device();
        for ([h, w], [oh, ow]) in [([3, 4], [6, 8]), ([5, 3], [9, 11]), ([4, 4], [4, 4]), ([1, 2], [3, 4])] {
            let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
            let skip = Tensor::<4>::random([2, 2, oh, ow], Distribution::Normal(0.0, 1.0), &device);
            let expected = Tensor::cat(vec![upsample_bilinear(x.clone(), [oh, ow], Upsample::Native), skip.clone()], 1);
            let fused = kernels::upsample_concat(&x, &skip).expect("flex takes the kernel");
            fused.into_data().assert_approx_eq::<f32>(&expected.into_data(), Tolerance::rel_abs(1e-5, 1e-6));
        }
    }

    /// The convolution reading the upsampled concatenation row by row gives the bits of the
    /// concatenation written whole and then convolved: through F(2x2, 3x3) (few channels) and
    /// F(4x4, 3x3) (48 -> 24 channels at 33x35), 2x and uneven scales, batch 2; one upsampled
    /// channel over several tasks three times, so that an input that read rows of an earlier
    /// one (kept between rows, `RowScratch`) would show. A convolution that is not Winograd's is
    /// left to the two steps.
    #[test]
    fn the_convolution_reads_the_concatenation_as_written() {
        use burn::nn::PaddingConfig2d;
        use burn::nn::conv::Conv2dConfig;
        let device = crate::backend::default_device();
        let leaky = kernels::Activation::Leaky(0.2);
        for (n, [c1, c2, o], [h, w], [oh, ow]) in [
            (2, [3, 2, 4], [5, 6], [9, 11]),
            (1, [4, 3, 5], [4, 4], [8, 8]),
            (2, [24, 24, 24], [17, 18], [33, 35]),
            (2, [1, 2, 3], [17, 18], [33, 35]),
            (2, [1, 2, 3], [17, 18], [33, 35]),
            (2, [1, 2, 3], [17, 18], [33, 35]),
        ] {
            let x = Tensor::<4>::random([n, c1, h, w], Distribution::Normal(0.0, 1.0), &device);
            let skip = Tensor::<4>::random([n, c2, oh, ow], Distribution::Normal(0.0, 1.0), &device);
            let conv = Conv2dConfig::new([c1 + c2, o], [3, 3])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(&device);
            let concatenated = kernels::upsample_concat(&x, &skip).expect("flex takes the kernel");
            let want = kernels::conv2d_act(&conv, concatenated, leaky).into_data();
            let got = kernels::upsample_concat_conv(&x, &skip, &conv, leaky).expect("a Winograd convolution");
            assert_eq!(got.into_data(), want, "{n}x{c1}+{c2} -> {o}, {h}x{w} -> {oh}x{ow}");
        }
        let x = Tensor::<4>::random([1, 2, 3, 3], Distribution::Normal(0.0, 1.0), &device);
        let skip = Tensor::<4>::random([1, 2, 6, 6], Distribution::Normal(0.0, 1.0), &device);
        let pointwise = Conv2dConfig::new([4, 3], [1, 1]).init(&device);
        assert!(kernels::upsample_concat_conv(&x, &skip, &pointwise, leaky).is_none());
    }
}
