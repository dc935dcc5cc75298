//! A dense block's eval-mode forward on flex, in one preallocated feature stack.
//!
//! Through Burn's operations every dense layer copies the whole growing stack to append its
//! channels (quadratic copying over a block), writes the normalised stack to a new tensor, and
//! adds bias and ReLU in passes of their own: about 40 % of the block's time at 480x640. Here
//! the block's output is allocated once. Each layer reads the stack's first `c` channels (one
//! contiguous run per image) with its norm1 + ReLU as the 1x1 convolution's prologue, keeps
//! the bottleneck in one reused buffer with norm2 (folded or not) + ReLU as the epilogue, and
//! writes the 3x3 convolution's output straight into its own channels of the stack.

use burn::nn::conv::Conv2d;
use burn::tensor::Tensor;
use burn_flex::FlexTensor;
use rayon::prelude::*;

use super::DenseLayerParams;
use super::conv::{flex_bias, gemm_padding};
use super::conv_forward::{forward_image, forward_image_with};
use super::flex::{flex_f32, flex_tensor, from_flex, slice};
use super::norm_relu::inference_affine;
use super::shared::{Activation, ConvShape, Epilogue, Prologue};
use super::winograd;

/// One layer's parameters as flex tensors and plain values.
struct Layer {
    norm1: [FlexTensor; 2],
    conv1: FlexTensor,
    /// conv1's epilogue: scale and shift from its bias and norm2 (either may be absent).
    post1: (Option<Vec<f32>>, Option<Vec<f32>>),
    conv2: FlexTensor,
    bias2: Option<FlexTensor>,
    /// conv1's output channels, conv2's output channels, conv2's kernel.
    bottleneck: usize,
    growth: usize,
    kernel: usize,
}

/// The kernel of `conv` when the matrix-product path runs it on `x`'s images keeping their size
/// (stride 1, `(k - 1) / 2` padding): the shapes the block kernel handles.
fn same_size(conv: &Conv2d, x: &Tensor<4>) -> Option<usize> {
    let k = conv.kernel_size[0];
    match gemm_padding(conv, x)? {
        (padding, 1) if 2 * padding + 1 == k => Some(k),
        _ => None,
    }
}

impl Layer {
    fn new(layer: &DenseLayerParams, x: &Tensor<4>) -> Option<Layer> {
        if same_size(layer.conv1, x)? != 1 {
            return None;
        }
        let kernel = same_size(layer.conv2, x)?;
        let (scale1, shift1) = inference_affine(layer.norm1);
        let conv1 = flex_f32(&layer.conv1.weight.val())?;
        let bias1 = flex_bias(layer.conv1)?.map(|b| slice(&b).to_vec());
        let post1 = match layer.norm2 {
            None => (None, bias1),
            Some(norm) => {
                let (scale, shift) = inference_affine(norm);
                let (scale, shift) = (slice(&flex_f32(&scale)?).to_vec(), slice(&flex_f32(&shift)?).to_vec());
                // norm2(conv1 + b) = conv1 * scale + (b * scale + shift).
                let shift = match &bias1 {
                    Some(b) => b.iter().zip(&scale).zip(&shift).map(|((b, s), t)| b * s + t).collect(),
                    None => shift,
                };
                (Some(scale), Some(shift))
            }
        };
        let conv2 = flex_f32(&layer.conv2.weight.val())?;
        let bias2 = flex_bias(layer.conv2)?;
        let ([bottleneck, ..], [growth, ..]) = (layer.conv1.weight.dims(), layer.conv2.weight.dims());
        Some(Layer {
            norm1: [flex_f32(&scale1)?, flex_f32(&shift1)?],
            conv1,
            post1,
            conv2,
            bias2,
            bottleneck,
            growth,
            kernel,
        })
    }
}

/// The block's forward when `x` is on flex outside autodiff and every layer has the expected
/// shapes; `None` otherwise (the caller then runs Burn's operations).
pub(crate) fn forward(params: &[DenseLayerParams], x: &Tensor<4>) -> Option<Tensor<4>> {
    let input = flex_f32(x)?;
    let layers = params.iter().map(|layer| Layer::new(layer, x)).collect::<Option<Vec<_>>>()?;
    let [n, c0, h, w] = x.dims();
    let hw = h * w;
    // Each layer must read exactly the channels stacked before it.
    let mut total = c0;
    for (layer, dense) in layers.iter().zip(params) {
        if dense.conv1.weight.dims()[1] != total || dense.conv2.weight.dims()[1] != layer.bottleneck {
            return None;
        }
        total += layer.growth;
    }
    let mut stack = vec![0.0f32; n * total * hw];
    let widest = layers.iter().map(|l| l.bottleneck).max().unwrap_or(0);
    let shape = |channels_in, channels_out, kernel| ConvShape {
        batch: 1,
        channels_in,
        channels_out,
        height: h,
        width: w,
        kernel,
        padding: kernel / 2,
        stride: 1,
    };
    // The 3x3 weights' Winograd transforms looked up once for the batch, not once per image.
    let transformed: Vec<_> = layers
        .iter()
        .map(|l| winograd::weight_for(&shape(l.bottleneck, l.growth, l.kernel), slice(&l.conv2), true))
        .collect();
    // The images side by side as well as within each convolution: at 8x8 and 4x4 a convolution
    // is one task, and the images one after another left the other threads idle.
    stack.par_chunks_mut(total * hw).zip(slice(&input).par_chunks(c0 * hw)).for_each(|(image, x)| {
        let mut bottleneck = vec![0.0f32; widest * hw];
        image[..c0 * hw].copy_from_slice(x);
        let mut c = c0;
        for (layer, u) in layers.iter().zip(&transformed) {
            let (features, rest) = image.split_at_mut(c * hw);
            let (m, g, k) = (layer.bottleneck, layer.growth, layer.kernel);
            let prologue = Prologue { scale: slice(&layer.norm1[0]), shift: slice(&layer.norm1[1]) };
            let post1 = Epilogue {
                scale: layer.post1.0.as_deref(),
                shift: layer.post1.1.as_deref(),
                activation: Activation::Relu,
            };
            let mid = &mut bottleneck[..m * hw];
            forward_image(features, slice(&layer.conv1), &shape(c, m, 1), Some(prologue), &post1, mid);
            let post2 = Epilogue::bias(layer.bias2.as_ref().map(slice), Activation::Identity);
            let conv2 = slice(&layer.conv2);
            forward_image_with(mid, conv2, u.as_ref(), &shape(m, g, k), None, &post2, &mut rest[..g * hw]);
            c += g;
        }
    });
    Some(from_flex(flex_tensor(stack, &[n, total, h, w])))
}

#[cfg(test)]
mod tests {
    use burn::module::{Param, RunningState};
    use burn::nn::BatchNorm;
    use burn::tensor::activation::relu;
    use burn::tensor::{Device, Distribution, Tolerance};

    use crate::network::{DenseBlock, DenseNetConfig, DenseNetEncoder};

    use super::*;

    fn randomise(norm: &mut BatchNorm, device: &Device) {
        let [c] = norm.gamma.dims();
        let random = |low, high| Tensor::<1>::random([c], Distribution::Uniform(low, high), device);
        norm.gamma = Param::from_tensor(random(0.5, 1.5));
        norm.beta = Param::from_tensor(random(-0.5, 0.5));
        norm.running_mean = RunningState::new(random(-0.5, 0.5));
        norm.running_var = RunningState::new(random(0.5, 2.0));
    }

    /// The block through Burn's own operations only: batch norm, ReLU, convolution, cat.
    fn reference(block: &DenseBlock, x: Tensor<4>) -> Tensor<4> {
        let mut features = x;
        for layer in &block.layers {
            let mid = layer.conv1.forward(relu(layer.norm1.forward(features.clone())));
            let mid = relu(layer.norm2.as_ref().map_or(mid.clone(), |n| n.forward(mid)));
            features = Tensor::cat(vec![features, layer.conv2.forward(mid)], 1);
        }
        features
    }

    /// The one-stack kernel against Burn's operations, with norm2 separate and folded into
    /// conv1 (which then has a bias), on a batch of 2 with sides that are not a multiple of the
    /// task size.
    #[test]
    fn one_stack_equals_burns_layers() {
        let device = crate::backend::default_device();
        let mut encoder: DenseNetEncoder = DenseNetConfig::tiny().init(&device);
        for layer in &mut encoder.denseblock2.layers {
            randomise(&mut layer.norm1, &device);
            randomise(layer.norm2.as_mut().unwrap(), &device);
        }
        let block = encoder.denseblock2.clone();
        let [_, c0, _, _] = block.layers[0].conv1.weight.dims();
        let x = Tensor::<4>::random([2, c0, 9, 13], Distribution::Normal(0.0, 1.0), &device);
        let expected = reference(&block, x.clone()).into_data();
        let tol = Tolerance::rel_abs(1e-4, 1e-4);
        forward(&block.kernel_params(), &x)
            .expect("flex takes the kernel")
            .into_data()
            .assert_approx_eq::<f32>(&expected, tol);
        let folded = encoder.folded().denseblock2;
        assert!(folded.layers[0].norm2.is_none() && folded.layers[0].conv1.bias.is_some());
        forward(&folded.kernel_params(), &x)
            .expect("flex takes the kernel")
            .into_data()
            .assert_approx_eq::<f32>(&expected, tol);
    }

    #[test]
    #[cfg(feature = "autodiff")]
    fn autodiff_keeps_burns_layers() {
        let device = crate::backend::default_device().autodiff();
        let encoder: DenseNetEncoder = DenseNetConfig::tiny().init(&device);
        let [_, c0, _, _] = encoder.denseblock1.layers[0].conv1.weight.dims();
        assert!(forward(&encoder.denseblock1.kernel_params(), &Tensor::zeros([1, c0, 4, 4], &device)).is_none());
    }
}
