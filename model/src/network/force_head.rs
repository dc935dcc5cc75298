//! The force head: the contact's total force as three numbers, read from the encoder's last
//! features. The pressure channel beside depth gives force only through its resultant, from the
//! decoder's last few channels; this head pools features that see the whole image, and its
//! training term reaches the encoder (BENCHMARKS.md, "The force head").

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::{Device, Tensor};

use super::{Activation, LEAKY_SLOPE, conv2d_act};

/// relu(norm5) through a 1x1 convolution and LeakyReLU(0.2), averaged over the image, then a
/// linear map to the force (x, y, z; sensor frame) in [`crate::FORCE_N_PER_LOSS_UNIT`]s.
#[derive(Module, Debug)]
pub struct ForceHead {
    pub conv: Conv2d,
    pub linear: Linear,
}

impl ForceHead {
    /// The width the recipes train: of 64 and 256 measured, the better (BENCHMARKS.md).
    pub const DEFAULT_HIDDEN: usize = 256;

    pub(crate) fn new(features: usize, hidden: usize, device: &Device) -> Self {
        ForceHead {
            conv: Conv2dConfig::new([features, hidden], [1, 1]).init(device),
            linear: LinearConfig::new(hidden, 3).init(device),
        }
    }

    /// `features`: relu(norm5), `[N, C, h, w]`; the force, `[N, 3]`, in loss units.
    pub fn forward(&self, features: Tensor<4>) -> Tensor<2> {
        let x = conv2d_act(&self.conv, features, Activation::Leaky(LEAKY_SLOPE));
        let [n, c, _, _] = x.dims();
        let pooled = x.mean_dim(3).mean_dim(2).reshape([n, c]);
        self.linear.forward(pooled)
    }
}
