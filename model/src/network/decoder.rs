//! DenseDepth's decoder: a 1x1 bottleneck convolution, four upsample-concat-conv-conv blocks
//! with LeakyReLU(0.2), and a 3x3 convolution to one channel at half the input resolution; or,
//! with a fifth block whose skip is the input itself, at the input's resolution.

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::densenet::Skips;
use super::upsample::{Upsample, upsample_concat};
use super::{Activation, conv2d, conv2d_act};

const SLOPE: f64 = 0.2;

fn conv3(channels: [usize; 2], device: &Device) -> Conv2d {
    Conv2dConfig::new(channels, [3, 3]).with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1)).init(device)
}

/// Upsample to the skip's size, concatenate [upsampled, skip], conv-LeakyReLU twice.
#[derive(Module, Debug)]
pub struct UpBlock {
    pub conv_a: Conv2d,
    pub conv_b: Conv2d,
}

impl UpBlock {
    fn new(input: usize, output: usize, device: &Device) -> Self {
        UpBlock { conv_a: conv3([input, output], device), conv_b: conv3([output, output], device) }
    }

    pub fn forward(&self, x: Tensor<4>, skip: Tensor<4>, mode: Upsample) -> Tensor<4> {
        let x = upsample_concat(x, skip, mode);
        let x = conv2d_act(&self.conv_a, x, Activation::Leaky(SLOPE));
        conv2d_act(&self.conv_b, x, Activation::Leaky(SLOPE))
    }
}

#[derive(Module, Debug)]
pub struct Decoder {
    pub conv2: Conv2d,
    pub up1: UpBlock,
    pub up2: UpBlock,
    pub up3: UpBlock,
    pub up4: UpBlock,
    /// To the input's resolution, the input as its skip (`DenseDepthConfig::full_resolution`).
    pub up5: Option<UpBlock>,
    pub conv3: Conv2d,
}

impl Decoder {
    /// `skips`: channels of relu0, pool0, transition1, transition2; `widths` from
    /// `DenseDepthConfig::decoder_channels`; `full_input`: the input's channels when the output
    /// is at the input's resolution.
    pub fn new(
        skips: [usize; 4],
        bottleneck: usize,
        widths: [usize; 5],
        full_input: Option<usize>,
        device: &Device,
    ) -> Self {
        let [n, n2, n4, n8, n16] = widths;
        Decoder {
            up5: full_input.map(|c| UpBlock::new(n16 + c, n16, device)),
            conv2: Conv2dConfig::new([bottleneck, n], [1, 1]).init(device),
            up1: UpBlock::new(n + skips[3], n2, device),
            up2: UpBlock::new(n2 + skips[2], n4, device),
            up3: UpBlock::new(n4 + skips[1], n8, device),
            up4: UpBlock::new(n8 + skips[0], n16, device),
            conv3: conv3([n16, 1], device),
        }
    }

    /// `input`: the network's input, used only by the full-resolution block.
    pub fn forward(&self, s: Skips, input: Tensor<4>, mode: Upsample) -> Tensor<4> {
        let x = conv2d(&self.conv2, relu(s.norm5));
        let x = self.up1.forward(x, s.transition2, mode);
        let x = self.up2.forward(x, s.transition1, mode);
        let x = self.up3.forward(x, s.pool0, mode);
        let x = self.up4.forward(x, s.relu0, mode);
        let x = match &self.up5 {
            Some(up5) => up5.forward(x, input, mode),
            None => x,
        };
        conv2d(&self.conv3, x)
    }
}
