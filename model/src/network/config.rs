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

    /// The preset this configuration is, if any.
    pub fn preset(&self) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.config() == *self)
    }

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

/// The DenseNet encoders by name: the paper's DenseNet-161, its torchvision siblings, and the
/// smaller ones this project trains on a CPU (`compact` is the quickstart's).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Preset {
    Compact,
    Small,
    Medium,
    Tiny,
    Densenet121,
    Densenet161,
    Densenet169,
    Densenet201,
}

impl Preset {
    pub const ALL: [Preset; 8] = [
        Preset::Compact,
        Preset::Small,
        Preset::Medium,
        Preset::Tiny,
        Preset::Densenet121,
        Preset::Densenet161,
        Preset::Densenet169,
        Preset::Densenet201,
    ];

    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Compact => "compact",
            Preset::Small => "small",
            Preset::Medium => "medium",
            Preset::Tiny => "tiny",
            Preset::Densenet121 => "densenet121",
            Preset::Densenet161 => "densenet161",
            Preset::Densenet169 => "densenet169",
            Preset::Densenet201 => "densenet201",
        }
    }

    /// The encoder's configuration.
    pub fn config(self) -> DenseNetConfig {
        match self {
            Preset::Compact => DenseNetConfig::compact(),
            Preset::Small => DenseNetConfig::small(),
            Preset::Medium => DenseNetConfig::medium(),
            Preset::Tiny => DenseNetConfig::tiny(),
            Preset::Densenet121 => DenseNetConfig::densenet121(),
            Preset::Densenet161 => DenseNetConfig::densenet161(),
            Preset::Densenet169 => DenseNetConfig::densenet169(),
            Preset::Densenet201 => DenseNetConfig::densenet201(),
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = formats::UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        formats::find_by_name("preset", s, &Preset::ALL, Preset::name)
    }
}

impl std::fmt::Display for Preset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a network's configuration or input is refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("input {h}x{w}: both sides must be at least {min} px (five halvings leave one pixel)")]
    InputTooSmall { h: usize, w: usize, min: usize },
    #[error("this DenseDepth takes {want} input channels ([N, {want}, H, W]), got {got}")]
    InputChannels { want: usize, got: usize },
    #[error(
        "encoder sizes out of range: growth_rate {growth_rate} (1..=512), block_config {block_config:?} (1..=256 \
         each), num_init_features {num_init_features} (1..=2048), bn_size {bn_size} (1..=64)"
    )]
    EncoderSizes { growth_rate: usize, block_config: [usize; 4], num_init_features: usize, bn_size: usize },
    #[error("decoder_width {width} leaves the decoder without channels (widths {channels:?}); it must be in (0, 4]")]
    DecoderWidth { width: f64, channels: [usize; 5] },
    #[error("force_head {hidden}: the force head's width must be in 1..=4096")]
    ForceHead { hidden: usize },
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
    /// A second output, the contact pressure on the depth's grid (`PressureScale`), from its
    /// own 3x3 convolution on the decoder's last features; trained beside depth
    /// (`train fit --force-weight`). Configurations written before this field have none.
    #[config(default = false)]
    pub pressure: bool,
    /// A force head of this hidden width on the encoder's last features (`ForceHead`): the
    /// contact's total force as three numbers, trained beside depth on the labels' force
    /// (`train fit --force-weight`). `None` (and configurations written before this field): none.
    pub force_head: Option<usize>,
    /// `Some(true)`: the force head reads transition2's features too (`ForceHead::skip`; on the
    /// quickstart's scenes 4.07 -> 3.46 % of the mean force, BENCHMARKS.md). `None`
    /// (configurations written before this field) or `Some(false)`: norm5's alone.
    pub force_head_skip: Option<bool>,
}

impl DenseDepthConfig {
    /// Whether the force head, where there is one, reads transition2 too.
    pub fn force_head_reads_transition2(&self) -> bool {
        self.force_head_skip == Some(true)
    }

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
    pub fn check_input_hw([h, w]: [usize; 2]) -> Result<(), ConfigError> {
        let min = Self::MIN_INPUT_SIDE;
        if h < min || w < min {
            return Err(ConfigError::InputTooSmall { h, w, min });
        }
        Ok(())
    }

    /// Checks a configuration read from a file: every size positive and within what a network
    /// of this family could hold, so that a corrupted file is an error rather than an attempt to
    /// allocate terabytes.
    pub fn check(&self) -> Result<(), ConfigError> {
        let e = &self.encoder;
        let within = |v: usize, max: usize| (1..=max).contains(&v);
        if !within(e.growth_rate, 512)
            || !within(e.num_init_features, 2048)
            || !within(e.bn_size, 64)
            || !e.block_config.iter().all(|&n| within(n, 256))
        {
            return Err(ConfigError::EncoderSizes {
                growth_rate: e.growth_rate,
                block_config: e.block_config,
                num_init_features: e.num_init_features,
                bn_size: e.bn_size,
            });
        }
        if !(self.decoder_width > 0.0 && self.decoder_width <= 4.0) || self.decoder_channels()[4] == 0 {
            return Err(ConfigError::DecoderWidth { width: self.decoder_width, channels: self.decoder_channels() });
        }
        if let Some(hidden) = self.force_head.filter(|&h| !within(h, 4096)) {
            return Err(ConfigError::ForceHead { hidden });
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
        for preset in Preset::ALL {
            assert_eq!(preset.name().parse::<Preset>(), Ok(preset));
            assert_eq!(preset.config().preset(), Some(preset));
            DenseDepthConfig::new(preset.config()).check().unwrap();
        }
        let unknown = "densenet".parse::<Preset>().unwrap_err().to_string();
        assert!(Preset::ALL.iter().all(|p| unknown.contains(p.name())), "{unknown}");
        let mut absurd = DenseDepthConfig::new(DenseNetConfig::tiny());
        absurd.encoder.growth_rate = 1 << 40;
        assert!(absurd.check().unwrap_err().to_string().contains("growth_rate"));
        absurd = DenseDepthConfig::new(DenseNetConfig::tiny()).with_decoder_width(0.001);
        assert!(absurd.check().unwrap_err().to_string().contains("decoder_width"));
        absurd = DenseDepthConfig::new(DenseNetConfig::tiny()).with_force_head(Some(1 << 40));
        assert!(absurd.check().unwrap_err().to_string().contains("force_head"));
    }

    /// A configuration written before the force head (or its skip) reads as one without it, and
    /// one with it reads back as it was written.
    #[test]
    fn the_force_head_is_optional_in_configuration_files() {
        let with = DenseDepthConfig::new(DenseNetConfig::tiny())
            .with_pressure(true)
            .with_force_head(Some(64))
            .with_force_head_skip(Some(true));
        let mut json = serde_json::to_value(&with).unwrap();
        assert_eq!(serde_json::from_value::<DenseDepthConfig>(json.clone()).unwrap(), with);
        // Before the skip: a head on norm5 alone.
        json.as_object_mut().unwrap().remove("force_head_skip");
        let before_skip: DenseDepthConfig = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(before_skip, with.clone().with_force_head_skip(None));
        assert!(!before_skip.force_head_reads_transition2() && with.force_head_reads_transition2());
        json.as_object_mut().unwrap().remove("force_head");
        let old: DenseDepthConfig = serde_json::from_value(json).unwrap();
        assert_eq!(old, with.with_force_head(None).with_force_head_skip(None));
    }
}
