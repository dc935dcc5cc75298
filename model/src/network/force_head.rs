//! The force head: the contact's total force as three numbers, read from the encoder's last
//! features (and, in heads trained since, the features at a sixteenth of the input as well).
//! The pressure channel beside depth gives force only through its resultant, from the
//! decoder's last few channels; this head pools features that see the whole image, and its
//! training term reaches the encoder (BENCHMARKS.md, "The force head").

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::{Activation, LEAKY_SLOPE, conv2d_act};

/// relu(norm5) through a 1x1 convolution and LeakyReLU(0.2), averaged over the image; where the
/// head has `skip`, relu(transition2) through its own 1x1 convolution and LeakyReLU, averaged,
/// added; then a linear map to the force (x, y, z; sensor frame) in
/// [`crate::FORCE_N_PER_LOSS_UNIT`]s.
#[derive(Module, Debug)]
pub struct ForceHead {
    pub conv: Conv2d,
    /// On transition2's output (1/16 of the input: 8x8 cells at 128x128 where norm5 has 4x4).
    pub skip: Option<Conv2d>,
    pub linear: Linear,
}

impl ForceHead {
    /// The width the recipes train: of 64 and 256 measured, the better (BENCHMARKS.md).
    pub const DEFAULT_HIDDEN: usize = 256;

    /// `features`: norm5's channels; `skip`: transition2's, where the head reads it too.
    pub(crate) fn new(features: usize, skip: Option<usize>, hidden: usize, device: &Device) -> Self {
        let conv1x1 = |c: usize| Conv2dConfig::new([c, hidden], [1, 1]).init(device);
        ForceHead {
            conv: conv1x1(features),
            skip: skip.map(conv1x1),
            linear: LinearConfig::new(hidden, 3).init(device),
        }
    }

    /// `features`: relu(norm5), `[N, C, h, w]`; `transition2`: that block's output (before any
    /// ReLU), read where the head has `skip`. The force, `[N, 3]`, in loss units.
    pub fn forward(&self, features: Tensor<4>, transition2: Tensor<4>) -> Tensor<2> {
        let mut pooled = pooled_1x1(&self.conv, features);
        if let Some(skip) = &self.skip {
            pooled = pooled + pooled_1x1(skip, relu(transition2));
        }
        self.linear.forward(pooled)
    }
}

/// A 1x1 convolution with LeakyReLU, averaged over the image: `[N, C_out]`.
fn pooled_1x1(conv: &Conv2d, x: Tensor<4>) -> Tensor<2> {
    let x = conv2d_act(conv, x, Activation::Leaky(LEAKY_SLOPE));
    let [n, c, _, _] = x.dims();
    x.mean_dim(3).mean_dim(2).reshape([n, c])
}
