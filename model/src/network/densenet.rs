//! A torchvision-compatible DenseNet encoder that returns DenseDepth's skip connections.

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AvgPool2d, AvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::config::DenseNetConfig;
use super::{Activation, conv2d, conv2d_act};
use crate::kernels::{self, DenseLayerParams, inference_affine, max_pool2d, norm_relu};

fn conv(channels: [usize; 2], kernel: usize, stride: usize, padding: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(padding, padding, padding, padding))
        .with_bias(false)
        .init(device)
}

/// BN-ReLU-Conv1x1-BN-ReLU-Conv3x3, adding `growth_rate` channels. `norm2` is `None` once it
/// has been folded into `conv1` for inference.
#[derive(Module, Debug)]
pub struct DenseLayer {
    pub norm1: BatchNorm,
    pub conv1: Conv2d,
    pub norm2: Option<BatchNorm>,
    pub conv2: Conv2d,
}

impl DenseLayer {
    fn new(input: usize, growth: usize, bn_size: usize, device: &Device) -> Self {
        DenseLayer {
            norm1: BatchNormConfig::new(input).init(device),
            conv1: conv([input, bn_size * growth], 1, 1, 0, device),
            norm2: Some(BatchNormConfig::new(bn_size * growth).init(device)),
            conv2: conv([bn_size * growth, growth], 3, 1, 1, device),
        }
    }

    /// The new channels for the concatenated features `x`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = conv2d(&self.conv1, norm_relu(&self.norm1, x));
        let x = match &self.norm2 {
            Some(norm) => norm_relu(norm, x),
            None => relu(x),
        };
        conv2d(&self.conv2, x)
    }
}

/// Dense layers whose outputs are concatenated to their inputs.
#[derive(Module, Debug)]
pub struct DenseBlock {
    pub layers: Vec<DenseLayer>,
}

impl DenseBlock {
    fn new(input: usize, layers: usize, growth: usize, bn_size: usize, device: &Device) -> Self {
        DenseBlock {
            layers: (0..layers).map(|i| DenseLayer::new(input + i * growth, growth, bn_size, device)).collect(),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match kernels::dense_block(&self.kernel_params(), &x) {
            Some(out) => out,
            None => self.forward_layers(x),
        }
    }

    /// What the dense-block kernel needs of each layer.
    pub(crate) fn kernel_params(&self) -> Vec<DenseLayerParams<'_>> {
        self.layers
            .iter()
            .map(|l| DenseLayerParams { norm1: &l.norm1, conv1: &l.conv1, norm2: l.norm2.as_ref(), conv2: &l.conv2 })
            .collect()
    }

    /// Layer by layer through Burn's operations (what autodiff and other backends run).
    pub(crate) fn forward_layers(&self, x: Tensor<4>) -> Tensor<4> {
        let mut features = x;
        for layer in &self.layers {
            let new = layer.forward(features.clone());
            features = Tensor::cat(vec![features, new], 1);
        }
        features
    }
}

/// BN-ReLU-Conv1x1 halving the channels, then 2x2 average pooling.
#[derive(Module, Debug)]
pub struct Transition {
    pub norm: BatchNorm,
    pub conv: Conv2d,
    pub pool: AvgPool2d,
}

impl Transition {
    fn new(input: usize, device: &Device) -> Self {
        Transition {
            norm: BatchNormConfig::new(input).init(device),
            conv: conv([input, input / 2], 1, 1, 0, device),
            pool: AvgPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
        }
    }

    /// Pools before the convolution: a 1x1 convolution and an average commute exactly (both
    /// are linear per pixel, and the bias averages to itself), and the convolution then runs on
    /// a quarter of the pixels.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        conv2d(&self.conv, kernels::norm_relu_avg_pool2(&self.norm, &self.pool, x))
    }
}

/// The encoder's outputs that the decoder uses (DenseDepth's `features[3, 4, 6, 8, 12]`).
pub struct Skips {
    /// relu0, 1/2 resolution.
    pub relu0: Tensor<4>,
    /// pool0, 1/4.
    pub pool0: Tensor<4>,
    /// transition1, 1/8.
    pub transition1: Tensor<4>,
    /// transition2, 1/16.
    pub transition2: Tensor<4>,
    /// norm5 (before its ReLU), 1/32.
    pub norm5: Tensor<4>,
}

/// torchvision's `DenseNet.features`, field for field.
#[derive(Module, Debug)]
pub struct DenseNetEncoder {
    pub conv0: Conv2d,
    /// `None` once folded into `conv0` for inference.
    pub norm0: Option<BatchNorm>,
    pub pool0: MaxPool2d,
    pub denseblock1: DenseBlock,
    pub transition1: Transition,
    pub denseblock2: DenseBlock,
    pub transition2: Transition,
    pub denseblock3: DenseBlock,
    pub transition3: Transition,
    pub denseblock4: DenseBlock,
    pub norm5: BatchNorm,
}

impl DenseNetConfig {
    /// The encoder of RGB images (torchvision's).
    pub fn init(&self, device: &Device) -> DenseNetEncoder {
        self.init_for(3, device)
    }

    /// The encoder of images with `in_channels` channels.
    pub fn init_for(&self, in_channels: usize, device: &Device) -> DenseNetEncoder {
        let (g, bn) = (self.growth_rate, self.bn_size);
        let c = self.block_channels();
        let [b1, b2, b3, b4] = self.block_config;
        let c0 = self.num_init_features;
        DenseNetEncoder {
            conv0: conv([in_channels, c0], 7, 2, 3, device),
            norm0: Some(BatchNormConfig::new(c0).init(device)),
            pool0: MaxPool2dConfig::new([3, 3])
                .with_strides([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(),
            denseblock1: DenseBlock::new(c0, b1, g, bn, device),
            transition1: Transition::new(c[0], device),
            denseblock2: DenseBlock::new(c[0] / 2, b2, g, bn, device),
            transition2: Transition::new(c[1], device),
            denseblock3: DenseBlock::new(c[1] / 2, b3, g, bn, device),
            transition3: Transition::new(c[2], device),
            denseblock4: DenseBlock::new(c[2] / 2, b4, g, bn, device),
            norm5: BatchNormConfig::new(c[3]).init(device),
        }
    }
}

impl DenseNetEncoder {
    /// The same encoder reading `channels` input channels: the stem's weights for channels
    /// beyond those it has start at zero, so the network computes what it did. Fewer channels
    /// than it has is a programming error.
    pub fn with_input_channels(mut self, channels: usize) -> Self {
        let [out, have, kh, kw] = self.conv0.weight.dims();
        assert!(channels >= have, "cannot narrow the stem from {have} to {channels} channels");
        if channels > have {
            let w = self.conv0.weight.val();
            let zeros = Tensor::<4>::zeros([out, channels - have, kh, kw], &w.device());
            self.conv0.weight = burn::module::Param::from_tensor(Tensor::cat(vec![w, zeros], 1));
        }
        self
    }

    pub fn forward(&self, x: Tensor<4>) -> Skips {
        self.forward_marked(x, &mut |_| {})
    }

    /// [`forward`](Self::forward), calling `mark` with each stage's name as it ends (for
    /// per-stage timers: flex runs each operation when it is called).
    pub(crate) fn forward_marked(&self, x: Tensor<4>, mark: &mut dyn FnMut(&'static str)) -> Skips {
        let relu0 = match &self.norm0 {
            Some(norm) => norm_relu(norm, conv2d(&self.conv0, x)),
            None => conv2d_act(&self.conv0, x, Activation::Relu),
        };
        mark("encoder.conv0");
        let pool0 = max_pool2d(&self.pool0, relu0.clone());
        mark("encoder.pool0");
        let b1 = self.denseblock1.forward(pool0.clone());
        mark("encoder.denseblock1");
        let transition1 = self.transition1.forward(b1);
        mark("encoder.transition1");
        let b2 = self.denseblock2.forward(transition1.clone());
        mark("encoder.denseblock2");
        let transition2 = self.transition2.forward(b2);
        mark("encoder.transition2");
        let b3 = self.denseblock3.forward(transition2.clone());
        mark("encoder.denseblock3");
        let t3 = self.transition3.forward(b3);
        mark("encoder.transition3");
        let b4 = self.denseblock4.forward(t3);
        mark("encoder.denseblock4");
        let norm5 = self.norm5.forward(b4);
        mark("encoder.norm5");
        Skips { relu0, pool0, transition1, transition2, norm5 }
    }
}

/// `bn(conv(x))` as one convolution: `W' = W scale`, `b' = b scale + shift`, with the batch
/// norm's per-channel `scale` and `shift` (`inference_affine`). Inference only.
pub fn fold_batch_norm(mut conv: Conv2d, bn: &BatchNorm) -> Conv2d {
    let (scale, shift) = inference_affine(bn);
    let [out, _, _, _] = conv.weight.dims();
    let weight = conv.weight.val() * scale.clone().reshape([out, 1, 1, 1]);
    let bias = match &conv.bias {
        Some(b) => b.val() * scale + shift,
        None => shift,
    };
    conv.weight = burn::module::Param::from_tensor(weight);
    conv.bias = Some(burn::module::Param::from_tensor(bias));
    conv
}

impl DenseNetEncoder {
    /// Folds every BatchNorm that directly follows a convolution (norm0, each layer's norm2)
    /// into it: the same eval-mode result with fewer passes over the feature maps.
    pub fn folded(mut self) -> Self {
        if let Some(norm) = self.norm0.take() {
            self.conv0 = fold_batch_norm(self.conv0, &norm);
        }
        for block in [&mut self.denseblock1, &mut self.denseblock2, &mut self.denseblock3, &mut self.denseblock4] {
            for layer in &mut block.layers {
                if let Some(norm) = layer.norm2.take() {
                    layer.conv1 = fold_batch_norm(layer.conv1.clone(), &norm);
                }
            }
        }
        self
    }
}
