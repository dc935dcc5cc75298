//! The network: a torchvision-compatible DenseNet encoder and DenseDepth's skip-connection
//! decoder, as Burn modules. Its layers call the CPU kernels through `crate::kernels` only.

mod config;
mod decoder;
mod densedepth;
mod densenet;
mod force_head;
mod upsample;

pub use config::{ConfigError, DenseDepthConfig, DenseNetConfig, Preset};
pub use decoder::{Decoder, Heads, UpBlock};
pub use densedepth::DenseDepth;
pub use densenet::{DenseBlock, DenseLayer, DenseNetEncoder, Skips, Transition, fold_batch_norm};
pub use force_head::ForceHead;
pub use upsample::{Upsample, interpolation_matrix, upsample_bilinear, upsample_mode_for};

pub use crate::kernels::Activation;

/// DenseDepth's LeakyReLU slope, the decoder's and the force head's.
pub(crate) const LEAKY_SLOPE: f64 = 0.2;

/// `activation(conv.forward(x))`.
pub(crate) fn conv2d_act(
    conv: &burn::nn::conv::Conv2d,
    x: burn::tensor::Tensor<4>,
    activation: Activation,
) -> burn::tensor::Tensor<4> {
    crate::kernels::conv2d_act(conv, x, activation)
}

/// `conv.forward(x)`.
pub(crate) fn conv2d(conv: &burn::nn::conv::Conv2d, x: burn::tensor::Tensor<4>) -> burn::tensor::Tensor<4> {
    conv2d_act(conv, x, Activation::Identity)
}
