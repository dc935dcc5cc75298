//! Eval-mode `relu(batch_norm(x))` in one pass on flex.
//!
//! Each dense layer normalises the whole concatenated feature stack before its 1x1 convolution;
//! Burn's inference batch norm is four element-wise passes over it (subtract, divide, multiply,
//! add) and the ReLU a fifth. With running statistics the pair is one per-channel scale and
//! shift followed by a clamp, which flex runs here as a single pass. Anywhere else (autodiff,
//! other backends or dtypes) it is Burn's `BatchNorm::forward` and `relu`.

use burn::nn::BatchNorm;
use burn::tensor::Tensor;
use burn_flex::FlexTensor;
use rayon::prelude::*;

use super::flex::{flex_tensor, slice};

/// The kernel: `x` holds planes of `plane` elements, channel after channel, image after image.
fn scale_shift_relu_slices(x: &[f32], plane: usize, scale: &[f32], shift: &[f32]) -> Vec<f32> {
    let channels = scale.len();
    let mut out = vec![0.0f32; x.len()];
    if plane == 0 || channels == 0 {
        return out;
    }
    out.par_chunks_mut(plane).zip(x.par_chunks(plane)).enumerate().for_each(|(i, (dst, src))| {
        let (s, t) = (scale[i % channels], shift[i % channels]);
        for (d, v) in dst.iter_mut().zip(src) {
            *d = (v * s + t).max(0.0);
        }
    });
    out
}

/// A batch norm with running statistics as `x * scale + shift` per channel:
/// `scale = gamma / sqrt(var + eps)`, `shift = beta - mean * scale`.
pub(crate) fn inference_affine(norm: &BatchNorm) -> (Tensor<1>, Tensor<1>) {
    let scale = norm.gamma.val() / norm.running_var.value().add_scalar(norm.epsilon).sqrt();
    let shift = norm.beta.val() - norm.running_mean.value() * scale.clone();
    (scale, shift)
}

/// `max(0, x * scale[c] + shift[c])` for a contiguous f32 flex `x` [batch, channels, ...].
pub(crate) fn scale_shift_relu_flex(x: &FlexTensor, scale: &[f32], shift: &[f32]) -> FlexTensor {
    let dims = x.layout().shape().to_vec();
    let plane = dims[2..].iter().product();
    flex_tensor(scale_shift_relu_slices(slice(x), plane, scale, shift), &dims)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kernels::norm_relu;
    use burn::nn::BatchNormConfig;
    use burn::tensor::activation::relu;
    use burn::tensor::{Distribution, Tolerance};

    /// A batch norm of `channels` with random running statistics and affine parameters away
    /// from their defaults, which the fused kernels are checked with.
    pub(crate) fn random_norm(channels: usize, device: &burn::tensor::Device) -> burn::nn::BatchNorm {
        let mut norm = BatchNormConfig::new(channels).init(device);
        let random = |low, high| Tensor::<1>::random([channels], Distribution::Uniform(low, high), device);
        norm.gamma = burn::module::Param::from_tensor(random(-2.0, 2.0));
        norm.beta = burn::module::Param::from_tensor(random(-1.0, 1.0));
        norm.running_mean = burn::module::RunningState::new(random(-1.0, 1.0));
        norm.running_var = burn::module::RunningState::new(random(0.1, 3.0));
        norm
    }

    /// Against Burn's inference batch norm and ReLU, with running statistics and affine
    /// parameters away from their defaults, on a 4-d and a 3-d input.
    #[test]
    fn one_pass_equals_burns_batch_norm_and_relu() {
        let device = crate::backend::default_device();
        let norm = random_norm(5, &device);
        let x = Tensor::<4>::random([2, 5, 3, 7], Distribution::Normal(0.0, 2.0), &device);
        let expected = relu(norm.forward(x.clone())).into_data();
        norm_relu(&norm, x.clone()).into_data().assert_approx_eq::<f32>(&expected, Tolerance::rel_abs(1e-5, 1e-6));
        let x3 = x.reshape([2, 5, 21]);
        let expected = relu(norm.forward(x3.clone())).into_data();
        norm_relu(&norm, x3).into_data().assert_approx_eq::<f32>(&expected, Tolerance::rel_abs(1e-5, 1e-6));
    }
}
