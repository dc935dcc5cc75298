//! The flex CPU kernels, and the one interface the network calls them through.
//!
//! Each function below runs this crate's kernel where its tensors are f32 on flex (outside
//! autodiff, or with the handwritten backward passes under autodiff on flex), and Burn's own
//! operation everywhere else (other backends, dtypes, layer shapes), so the network's results
//! agree on every backend within float rounding. Nothing else of these modules is visible to
//! the network.
//!
//! - convolutions as large matrix products, forward (`conv_forward`) and backward
//!   (`gemm_conv`, through a Burn backend extension in `conv`), 3x3 "same" ones by Winograd's
//!   F(2x2, 3x3) or, on large images, F(4x4, 3x3) (`winograd`, `winograd4`; the transformed
//!   weights kept between calls in `weight_cache`), strided ones directly from the input dealt into phases (`direct`);
//! - a dense block's eval-mode forward in one preallocated stack (`dense_block`);
//! - eval-mode and training-mode batch norm + ReLU in one pass (`norm_relu`, `batch_norm_train`);
//! - the loss's separable window, forward and backward (`blur`);
//! - the stem's max pool and a transition's batch norm + ReLU + average pool (`pool`), and the
//!   decoder's upsample + concatenation (`upsample`), written once or read row by row by the
//!   convolution after it.

use burn::nn::BatchNorm;
use burn::nn::conv::Conv2d;
use burn::tensor::Tensor;

/// Whether `device` runs this crate's inference kernels: plain flex, outside autodiff.
pub(crate) fn plain_flex(device: &burn::tensor::Device) -> bool {
    flex::flex_kind(device) == Some(false)
}

// The backward passes (and the helpers only they call) serve training alone: a build without
// `autodiff`, such as the `infer` binary's, compiles them but never calls them.
#[cfg_attr(not(feature = "autodiff"), allow(dead_code))]
mod batch_norm_train;
// The loss's separable window; its gradient serves training alone.
#[cfg_attr(not(feature = "autodiff"), allow(dead_code))]
mod blur;
#[cfg_attr(not(feature = "autodiff"), allow(dead_code))]
mod conv;
// Matrix products through raw pointers into disjoint parts of one buffer.
#[allow(unsafe_code)]
#[cfg_attr(not(feature = "autodiff"), allow(dead_code))]
mod conv_forward;
// A row dealt into column phases in SSE or AVX-512 registers.
#[allow(unsafe_code)]
mod deal;
mod dense_block;
// Output rows written through a shared pointer; kernels compiled for the CPU's vector features.
#[allow(unsafe_code)]
mod direct;
mod flex;
// The shared leaf: the matrix product and the pointer for disjoint writes.
#[allow(unsafe_code)]
#[cfg_attr(not(feature = "autodiff"), allow(dead_code))]
mod gemm_conv;
mod norm_relu;
mod pool;
#[allow(unsafe_code)]
mod shared;
mod upsample;
mod weight_cache;
// Matrix products through raw pointers into per-thread buffers and disjoint output rows.
#[allow(unsafe_code)]
mod winograd;
mod winograd4;

pub(crate) use batch_norm_train::norm_relu;
pub(crate) use blur::separable as separable_blur;
pub(crate) use conv::conv2d_act;
pub(crate) use norm_relu::inference_affine;
pub(crate) use pool::{max_pool2d, norm_relu_avg_pool2};
pub use shared::Activation;
pub(crate) use upsample::{taps as bilinear_taps, upsample_concat, upsample_concat_conv};

/// What the dense-block kernel needs of one dense layer: BN-ReLU-Conv1x1-BN-ReLU-Conv, where the
/// second batch norm may already be folded into the first convolution (`norm2` is `None`).
#[derive(Clone, Copy)]
pub(crate) struct DenseLayerParams<'a> {
    pub(crate) norm1: &'a BatchNorm,
    pub(crate) conv1: &'a Conv2d,
    pub(crate) norm2: Option<&'a BatchNorm>,
    pub(crate) conv2: &'a Conv2d,
}

/// A dense block's output (its input with every layer's new channels stacked behind it), when
/// `x` is f32 on flex outside autodiff and every layer has the shapes the kernel handles;
/// `None` otherwise, and the network runs its layers through Burn's operations.
pub(crate) fn dense_block(layers: &[DenseLayerParams], x: &Tensor<4>) -> Option<Tensor<4>> {
    dense_block::forward(layers, x)
}
