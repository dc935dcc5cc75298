//! The whole network.

use burn::module::Module;
use burn::tensor::{Device, Tensor};

use super::config::DenseDepthConfig;
use super::decoder::Decoder;
use super::densenet::DenseNetEncoder;
use super::upsample::{Upsample, upsample_mode_for};

/// DenseDepth: RGB image in [0, 1] ([N, 3, H, W], H and W multiples of 32) to depth in
/// network units at half resolution ([N, 1, H/2, W/2]).
#[derive(Module, Debug)]
pub struct DenseDepth {
    pub encoder: DenseNetEncoder,
    pub decoder: Decoder,
}

impl DenseDepthConfig {
    pub fn init(&self, device: &Device) -> DenseDepth {
        let (skips, bottleneck) = self.encoder.skip_channels();
        DenseDepth {
            encoder: self.encoder.init(device),
            decoder: Decoder::new(skips, bottleneck, self.decoder_channels(), device),
        }
    }
}

impl DenseDepth {
    /// Forward pass. Upsampling uses Burn's native bilinear kernel unless gradients are being
    /// recorded on a backend whose `interpolate` has no backward pass.
    pub fn forward(&self, images: Tensor<4>) -> Tensor<4> {
        let mode = upsample_mode_for(&images.device());
        self.forward_with(images, mode)
    }

    pub fn forward_with(&self, images: Tensor<4>, mode: Upsample) -> Tensor<4> {
        let [_, c, h, w] = images.dims();
        assert!(c == 3, "DenseDepth takes RGB images ([N, 3, H, W]), got {c} channels");
        assert!(
            h % DenseDepthConfig::STRIDE == 0 && w % DenseDepthConfig::STRIDE == 0 && h > 0 && w > 0,
            "input sides must be positive multiples of {}, got {h}x{w}",
            DenseDepthConfig::STRIDE
        );
        self.decoder.forward(self.encoder.forward(images), mode)
    }

    /// The same network for inference only: BatchNorms that follow a convolution are folded
    /// into it (see `DenseNetEncoder::folded`). Do not train the result.
    pub fn folded(self) -> Self {
        DenseDepth { encoder: self.encoder.folded(), decoder: self.decoder }
    }

    /// Number of trainable parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[should_panic(expected = "multiples of 32")]
    fn input_sides_must_be_multiples_of_32() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny()).init(&device);
        model.forward(Tensor::zeros([1, 3, 48, 64], &device));
    }
}
