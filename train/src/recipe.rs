//! Training recipes: what `train fit` trains unless told otherwise, and what the quickstart
//! trains. One definition, so that the README's real-sensor commands train what was measured
//! best (BENCHMARKS.md, "Accuracy where the sensor is pressed").

use std::path::PathBuf;

use crate::config::{FitConfig, Schedule};

/// A recipe: the network and the training settings together.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Recipe {
    /// The best measured on these sensors: the compact preset at 128x128 reading RGB and its
    /// difference to the unit's reference frame, output at the input's resolution, depth in
    /// 0.01..1 units, Adam peaking at 1e-3 after 100 warm-up steps with a cosine schedule, 14
    /// epochs at batch 4, the contact-weighted loss (5), the best epoch on 10 % held out; the
    /// pressure output and the force head trained beside depth (force weight 1).
    Quickstart,
    /// The paper's: DenseNet-161 at 480x640 reading RGB, output at half resolution, the paper's
    /// depth units and loss, Adam at 1e-4, 16 epochs at batch 4.
    Paper,
}

/// The network a recipe trains.
#[derive(Clone, Debug, PartialEq)]
pub struct RecipeNetwork {
    pub preset: model::Preset,
    pub input_hw: [usize; 2],
    pub channels: model::InputChannels,
    pub full_resolution: bool,
}

impl Recipe {
    pub fn network(self) -> RecipeNetwork {
        match self {
            Recipe::Quickstart => RecipeNetwork {
                preset: model::Preset::Compact,
                input_hw: [128, 128],
                channels: model::InputChannels::RgbDifference,
                full_resolution: true,
            },
            Recipe::Paper => RecipeNetwork {
                preset: model::Preset::Densenet161,
                input_hw: [480, 640],
                channels: model::InputChannels::Rgb,
                full_resolution: false,
            },
        }
    }

    /// The recipe's training settings on `data` at its own input size.
    pub fn fit_config(self, data: PathBuf) -> FitConfig {
        let base = FitConfig::new(data, self.network().input_hw);
        match self {
            Recipe::Quickstart => FitConfig {
                epochs: 14,
                batch: 4,
                lr: 1e-3,
                net_range: model::UNIT_NET_RANGE,
                schedule: Schedule::Cosine,
                warmup_steps: 100,
                val_fraction: 0.1,
                contact_weight: 5.0,
                // The force outputs train beside depth: the force head's force, 3.5 % of the mean
                // force against the solve's 8.8 % on a depth-alone network, for a contact L1
                // 0.98x that network's over three seeds (BENCHMARKS.md, "The force head").
                force_weight: FitConfig::DEFAULT_FORCE_WEIGHT,
                ..base
            },
            Recipe::Paper => FitConfig {
                epochs: 16,
                batch: 4,
                lr: 1e-4,
                net_range: model::PAPER_NET_RANGE,
                schedule: Schedule::Constant,
                warmup_steps: 0,
                val_fraction: 0.1,
                contact_weight: 0.0,
                ..base
            },
        }
    }

    /// The recipe's network configuration.
    pub fn model_config(self) -> anyhow::Result<model::DenseDepthConfig> {
        let n = self.network();
        Ok(model::DenseDepthConfig::new(n.preset.config())
            .with_input(n.channels)
            .with_full_resolution(n.full_resolution))
    }
}
