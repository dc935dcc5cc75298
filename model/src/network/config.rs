//! Model configuration: a torchvision-compatible DenseNet encoder and the DenseDepth decoder.

use burn::config::Config;

use crate::input::InputChannels;

/// A torchvision `DenseNet` (four dense blocks).
#[derive(Config, Debug, PartialEq)]
pub struct DenseNetConfig {
    /// Channels each dense layer adds.
    pub growth_rate: usize,
    /// Dense layers per block (four blocks).
    pub block_config: [usize; 4],
    /// Channels of the stem convolution.
    pub num_init_features: usize,
    /// Bottleneck width of a dense layer, in multiples of the growth rate.
    pub bn_size: usize,
}

impl DenseNetConfig {
    pub fn densenet121() -> Self {
        Self::new(32, [6, 12, 24, 16], 64, 4)
    }

    /// The paper's encoder: 28.7 M parameters with the classifier, 2208 bottleneck channels.
    pub fn densenet161() -> Self {
        Self::new(48, [6, 12, 36, 24], 96, 4)
    }

    pub fn densenet169() -> Self {
        Self::new(32, [6, 12, 32, 32], 64, 4)
    }

    pub fn densenet201() -> Self {
        Self::new(32, [6, 12, 48, 32], 64, 4)
    }

    /// A small DenseNet that trains on a 2-core CPU in minutes (about 0.2 M encoder parameters).
    pub fn compact() -> Self {
        Self::new(12, [2, 4, 6, 4], 32, 4)
    }

    /// Between compact and DenseNet-121 (`cargo xtask bench table`'s family): growth 16,
    /// blocks of 3, 6, 12, 8 layers.
    pub fn small() -> Self {
        Self::new(16, [3, 6, 12, 8], 48, 4)
    }

    /// Between small and DenseNet-121: growth 24, blocks of 4, 8, 16, 12 layers.
    pub fn medium() -> Self {
        Self::new(24, [4, 8, 16, 12], 64, 4)
    }

    /// The encoder of `shared/fixtures/densedepth_tiny.pth`.
    pub fn tiny() -> Self {
        Self::new(10, [2, 3, 4, 3], 24, 2)
    }

    /// Looks a preset up by name.
    pub fn preset(name: &str) -> Option<Self> {
        Some(match name {
            "densenet121" => Self::densenet121(),
            "densenet161" => Self::densenet161(),
            "densenet169" => Self::densenet169(),
            "densenet201" => Self::densenet201(),
            "compact" => Self::compact(),
            "small" => Self::small(),
            "medium" => Self::medium(),
            "tiny" => Self::tiny(),
            _ => return None,
        })
    }

    /// A preset by name, or an error listing the presets.
    pub fn by_name(name: &str) -> Result<Self, String> {
        Self::preset(name).ok_or_else(|| format!("unknown preset {name:?}: {}", Self::PRESETS.join(", ")))
    }

    /// The preset this configuration is, if any.
    pub fn preset_name(&self) -> Option<&'static str> {
        Self::PRESETS.into_iter().find(|name| Self::preset(name).as_ref() == Some(self))
    }

    pub const PRESETS: [&'static str; 8] =
        ["compact", "small", "medium", "tiny", "densenet121", "densenet161", "densenet169", "densenet201"];

    /// Channels after each dense block (before its transition halves them).
    pub fn block_channels(&self) -> [usize; 4] {
        let mut c = self.num_init_features;
        let mut out = [0; 4];
        for (i, &n) in self.block_config.iter().enumerate() {
            c += n * self.growth_rate;
            out[i] = c;
            if i < 3 {
                c /= 2;
            }
        }
        out
    }

    /// Channels of the four skips (relu0, pool0, transition1, transition2) and the bottleneck (norm5).
    pub fn skip_channels(&self) -> ([usize; 4], usize) {
        let b = self.block_channels();
        ([self.num_init_features, self.num_init_features, b[0] / 2, b[1] / 2], b[3])
    }
}

/// DenseDepth: the DenseNet encoder and a decoder of four upsample-concat-conv-conv blocks.
#[derive(Config, Debug, PartialEq)]
pub struct DenseDepthConfig {
    pub encoder: DenseNetConfig,
    /// Decoder channels as a fraction of the bottleneck's (DenseDepth uses 0.5).
    #[config(default = 0.5)]
    pub decoder_width: f64,
    /// What the network reads: RGB (the paper's; configurations written before this field) or
    /// RGB and its difference to the unit's reference frame.
    #[config(default = "InputChannels::Rgb")]
    pub input: InputChannels,
    /// Output at the input's resolution (a fifth decoder block whose skip is the input)
    /// instead of DenseDepth's half: edges of contact patches and small bumps survive.
    #[config(default = false)]
    pub full_resolution: bool,
}

impl DenseDepthConfig {
    /// The decoder's widths: `n = int(bottleneck * width)`, then `n/2, n/4, n/8, n/16`.
    pub fn decoder_channels(&self) -> [usize; 5] {
        let (_, bottleneck) = self.encoder.skip_channels();
        let n = (bottleneck as f64 * self.decoder_width) as usize;
        [n, n / 2, n / 4, n / 8, n / 16]
    }

    /// The output's height and width for an input of `[h, w]`: the input's, or the stem's
    /// (a stride-2 convolution padded by 3: half, rounded up).
    pub fn output_hw(&self, [h, w]: [usize; 2]) -> [usize; 2] {
        if self.full_resolution { [h, w] } else { [h.div_ceil(2), w.div_ceil(2)] }
    }

    /// The smallest input side, PyTorch's too: the stem's convolution and max pool halve
    /// rounding up, the three transitions' 2x2 average pools halve rounding down, and the last
    /// must leave a pixel: ceil(ceil(n / 2) / 2) >= 8, so n >= 29. Any side from here up works;
    /// the decoder upsamples every block to its skip's own size.
    pub const MIN_INPUT_SIDE: usize = 29;

    /// Checks an input size `[h, w]`; the error says why it is refused.
    pub fn check_input_hw([h, w]: [usize; 2]) -> Result<(), String> {
        let min = Self::MIN_INPUT_SIDE;
        if h < min || w < min {
            return Err(format!("input {h}x{w}: both sides must be at least {min} px (five halvings leave one pixel)"));
        }
        Ok(())
    }

    /// Checks a configuration read from a file: every size positive and within what a network
    /// of this family could hold, so that a corrupted file is an error rather than an attempt to
    /// allocate terabytes.
    pub fn check(&self) -> Result<(), String> {
        let e = &self.encoder;
        let within = |v: usize, max: usize| (1..=max).contains(&v);
        if !within(e.growth_rate, 512)
            || !within(e.num_init_features, 2048)
            || !within(e.bn_size, 64)
            || !e.block_config.iter().all(|&n| within(n, 256))
        {
            return Err(format!(
                "encoder sizes out of range: growth_rate {} (1..=512), block_config {:?} (1..=256 each), \
                 num_init_features {} (1..=2048), bn_size {} (1..=64)",
                e.growth_rate, e.block_config, e.num_init_features, e.bn_size
            ));
        }
        if !(self.decoder_width > 0.0 && self.decoder_width <= 4.0) || self.decoder_channels()[4] == 0 {
            return Err(format!(
                "decoder_width {} leaves the decoder without channels (widths {:?}); it must be in (0, 4]",
                self.decoder_width,
                self.decoder_channels()
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_counts_match_torchvision_and_the_fixture() {
        // densedepth_tiny.json: skip channels [24, 24, 22, 26], bottleneck 63.
        assert_eq!(DenseNetConfig::tiny().skip_channels(), ([24, 24, 22, 26], 63));
        // DenseNet-161: 96, 96, 192, 384 skips and 2208 bottleneck channels.
        assert_eq!(DenseNetConfig::densenet161().skip_channels(), ([96, 96, 192, 384], 2208));
        assert_eq!(DenseNetConfig::densenet121().skip_channels(), ([64, 64, 128, 256], 1024));
        let cfg = DenseDepthConfig::new(DenseNetConfig::densenet161());
        assert_eq!(cfg.decoder_channels(), [1104, 552, 276, 138, 69]);
        for name in DenseNetConfig::PRESETS {
            let preset = DenseNetConfig::preset(name).unwrap();
            DenseDepthConfig::new(preset).check().unwrap();
        }
        let mut absurd = DenseDepthConfig::new(DenseNetConfig::tiny());
        absurd.encoder.growth_rate = 1 << 40;
        assert!(absurd.check().unwrap_err().contains("growth_rate"));
        absurd = DenseDepthConfig::new(DenseNetConfig::tiny()).with_decoder_width(0.001);
        assert!(absurd.check().unwrap_err().contains("decoder_width"));
    }
}
