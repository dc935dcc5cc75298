//! DenseDepth's decoder: a 1x1 bottleneck convolution, four upsample-concat-conv-conv blocks
//! with LeakyReLU(0.2), and a 3x3 convolution to one channel at half the input resolution; or,
//! with a fifth block whose skip is the input itself, at the input's resolution. A network with
//! a pressure output reads the same last features, cut from the graph, with a second 3x3
//! convolution; one with a force head reads the encoder's last features (`ForceHead`), and
//! transition2's where it has its skip.

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::densenet::Skips;
use super::force_head::ForceHead;
use super::upsample::{Upsample, upsample_concat};
use super::{Activation, LEAKY_SLOPE, conv2d, conv2d_act};

pub(crate) fn conv3(channels: [usize; 2], device: &Device) -> Conv2d {
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
        let leaky = Activation::Leaky(LEAKY_SLOPE);
        // On plain flex the first convolution reads the upsampled concatenation row by row.
        let fused = (mode == Upsample::Native)
            .then(|| crate::kernels::upsample_concat_conv(&x, &skip, &self.conv_a, leaky))
            .flatten();
        let x = fused.unwrap_or_else(|| conv2d_act(&self.conv_a, upsample_concat(x, skip, mode), leaky));
        conv2d_act(&self.conv_b, x, leaky)
    }
}

/// The network's outputs, network units.
#[derive(Clone, Debug)]
pub struct Heads {
    pub depth: Tensor<4>,
    /// Contact pressure, where the network has the channel: computed from the decoder's last
    /// features detached from the graph, so that its loss terms train the pressure convolution
    /// and leave the features, which depth shares, to depth (BENCHMARKS.md, "The force head").
    pub pressure: Option<Tensor<4>>,
    /// The contact force (`[N, 3]`, x, y, z in [`crate::FORCE_N_PER_LOSS_UNIT`]s, sensor frame),
    /// where the network has the force head.
    pub force: Option<Tensor<2>>,
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
    /// The contact pressure's channel (`DenseDepthConfig::pressure`), beside `conv3`.
    pub pressure: Option<Conv2d>,
    /// The force head (`DenseDepthConfig::force_head`), on the encoder's last features (and
    /// transition2's, `DenseDepthConfig::force_head_skip`).
    pub force: Option<ForceHead>,
}

impl Decoder {
    /// `skips`: channels of relu0, pool0, transition1, transition2; `widths` from
    /// `DenseDepthConfig::decoder_channels`; `full_input`: the input's channels when the output
    /// is at the input's resolution; `force_head`: the force head's width and whether it reads
    /// transition2 too.
    pub fn new(
        skips: [usize; 4],
        bottleneck: usize,
        widths: [usize; 5],
        full_input: Option<usize>,
        pressure: bool,
        force_head: Option<(usize, bool)>,
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
            pressure: pressure.then(|| conv3([n16, 1], device)),
            force: force_head
                .map(|(hidden, skip)| ForceHead::new(bottleneck, skip.then_some(skips[3]), hidden, device)),
        }
    }

    /// Depth, and pressure where the decoder has its channel. `input`: the network's input,
    /// used only by the full-resolution block.
    pub fn forward(&self, s: Skips, input: Tensor<4>, mode: Upsample) -> Heads {
        self.forward_marked(s, input, mode, &mut |_| {})
    }

    /// [`forward`](Self::forward), calling `mark` with each stage's name as it ends.
    pub(crate) fn forward_marked(
        &self,
        s: Skips,
        input: Tensor<4>,
        mode: Upsample,
        mark: &mut dyn FnMut(&'static str),
    ) -> Heads {
        let features = relu(s.norm5);
        let force = self.force.as_ref().map(|head| head.forward(features.clone(), s.transition2.clone()));
        let x = conv2d(&self.conv2, features);
        mark("decoder.conv2");
        let x = self.up1.forward(x, s.transition2, mode);
        mark("decoder.up1");
        let x = self.up2.forward(x, s.transition1, mode);
        mark("decoder.up2");
        let x = self.up3.forward(x, s.pool0, mode);
        mark("decoder.up3");
        let x = self.up4.forward(x, s.relu0, mode);
        mark("decoder.up4");
        let x = match &self.up5 {
            Some(up5) => {
                let x = up5.forward(x, input, mode);
                mark("decoder.up5");
                x
            }
            None => x,
        };
        // Cut from the graph (nothing to cut at inference): the pressure's terms shaping the
        // shared features cost depth 1.14x its contact error over three seeds.
        let pressure = self.pressure.as_ref().map(|c| conv2d(c, x.clone().detach()));
        let depth = conv2d(&self.conv3, x);
        mark("decoder.heads");
        Heads { depth, pressure, force }
    }
}
