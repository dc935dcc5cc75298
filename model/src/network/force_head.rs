//! The force head: the contact's total force as three numbers, read from the encoder's last
//! features (and, in heads trained since, the features at a sixteenth of the input as well).
//! The pressure channel beside depth gives force only through its resultant, from the
//! decoder's last few channels; this head pools features that see the whole image, and its
//! training term reaches the encoder (BENCHMARKS.md, "The force head").

use burn::module::{Module, Param};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};

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
        self.linear.forward(self.pooled(features, transition2))
    }

    /// What the linear map reads (`[N, hidden]`): the pooled activations of
    /// [`forward`](Self::forward)'s 1x1 convolutions, summed.
    pub fn pooled(&self, features: Tensor<4>, transition2: Tensor<4>) -> Tensor<2> {
        let mut pooled = pooled_1x1(&self.conv, features);
        if let Some(skip) = &self.skip {
            pooled = pooled + pooled_1x1(skip, relu(transition2));
        }
        pooled
    }

    /// The hidden width: the linear map's inputs.
    pub fn hidden(&self) -> usize {
        self.linear.weight.dims()[0]
    }

    /// The linear map: its weight (`[hidden, 3]`, row-major; force = pooled · weight + bias)
    /// and bias, in [`crate::FORCE_N_PER_LOSS_UNIT`]s.
    pub fn map(&self) -> (Vec<f32>, [f32; 3]) {
        let values = |t: Tensor<2>| t.into_data().convert::<f32>().try_into_vec::<f32>().expect("f32 after convert");
        let bias = match &self.linear.bias {
            Some(b) => {
                let b = values(b.val().unsqueeze::<2>());
                std::array::from_fn(|k| b[k])
            }
            None => [0.0; 3],
        };
        (values(self.linear.weight.val()), bias)
    }

    /// This head with `weight` (`[hidden, 3]`, row-major) and `bias` as its linear map
    /// ([`map`](Self::map)'s layout and units): a map fitted in closed form on the trained
    /// features (`train`'s refit). Panics where `weight` is not `hidden * 3` long.
    pub fn with_map(mut self, weight: &[f32], bias: [f32; 3]) -> Self {
        let hidden = self.hidden();
        assert_eq!(weight.len(), hidden * 3, "a force map of {} numbers for a head of width {hidden}", weight.len());
        let device = self.linear.weight.val().device();
        let dtype = self.linear.weight.val().dtype();
        let w = Tensor::<2>::from_data(TensorData::new(weight.to_vec(), [hidden, 3]), &device).cast(dtype);
        let b = Tensor::<1>::from_data(TensorData::new(bias.to_vec(), [3]), &device).cast(dtype);
        self.linear.weight = self.linear.weight.map(|_| w);
        self.linear.bias = Some(match self.linear.bias {
            Some(p) => p.map(|_| b),
            None => Param::from_tensor(b),
        });
        self
    }
}

/// A 1x1 convolution with LeakyReLU, averaged over the image: `[N, C_out]`.
fn pooled_1x1(conv: &Conv2d, x: Tensor<4>) -> Tensor<2> {
    let x = conv2d_act(conv, x, Activation::Leaky(LEAKY_SLOPE));
    let [n, c, _, _] = x.dims();
    x.mean_dim(3).mean_dim(2).reshape([n, c])
}
