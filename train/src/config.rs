//! What defines a training run: its settings with the CLI's defaults, and their checks.

use std::path::PathBuf;

use model::DepthScale;
use serde::{Deserialize, Serialize};

/// What a bad sample does to a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum OnBadData {
    /// Stop with the file's name and the problem.
    Stop,
    /// Leave the sample out, count it and report it.
    Skip,
}

/// How the learning rate changes over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// The given rate throughout.
    #[default]
    Constant,
    /// Half a cosine from the given rate down to 1 % of it at the last step.
    Cosine,
}

/// Everything that defines a run; a resume must match it. [`FitConfig::new`] gives the CLI's
/// defaults; [`FitConfig::validate`] says which setting is out of range.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitConfig {
    /// The dataset folder.
    pub data: PathBuf,
    /// Network input, height and width (each at least 29). Default: none (the caller's choice).
    pub input_hw: [usize; 2],
    /// Default 10.
    pub epochs: usize,
    /// Default 4.
    pub batch: usize,
    /// Adam's learning rate. Default 1e-4.
    pub lr: f64,
    /// Weights, data order, augmentation and the validation hold-out follow from it. Default 0.
    pub seed: u64,
    /// Checkpoint every this many steps (and at every epoch's end). Default 50.
    pub checkpoint_every: u64,
    /// Default: stop.
    pub on_bad_data: OnBadData,
    /// Consecutive non-finite steps after which the run stops. Default 5.
    pub max_bad_steps: u64,
    /// Train the decoder only. Default false.
    pub freeze_encoder: bool,
    /// Train on this fraction of the training split (a seeded subset, at least one sample):
    /// fine-tuning from a little of a new unit's data. Default 1.
    #[serde(default = "one")]
    pub train_fraction: f64,
    /// Network units of zero and maximum depth: the paper's 10..1000 (the default), or 0.01..1,
    /// which a network trained from scratch on a short budget reaches in far fewer steps.
    #[serde(default = "paper_range")]
    pub net_range: [f32; 2],
    /// Learning-rate schedule after the warm-up. Default constant.
    #[serde(default)]
    pub schedule: Schedule,
    /// Steps over which the learning rate ramps up linearly from zero. Default 0.
    #[serde(default)]
    pub warmup_steps: u64,
    /// Fraction of the (used) training split held out, seeded, to validate each epoch and pick
    /// the best epoch; the test split is never seen during training. Default 0.1. With 0 the
    /// test split is measured each epoch and the last epoch is kept.
    #[serde(default)]
    pub val_fraction: f64,
    /// Weight of the training loss's extra L1 term over contact pixels (see
    /// `model::DepthLossConfig::contact_weight`). Default 0: DenseDepth's loss.
    #[serde(default)]
    pub contact_weight: f64,
    /// Stop when the held-out validation L1 has not improved for this many epochs. Default
    /// none: every epoch runs.
    #[serde(default)]
    pub patience: Option<usize>,
    /// Stop after the first epoch that ends with this many minutes of training behind the run.
    /// Default none.
    #[serde(default)]
    pub max_minutes: Option<f64>,
    /// Further dataset folders, other units' (a base model for new units), trained on together
    /// with `data`, each sample read with its own unit's geometry and reference frame; `data`'s
    /// unit is the one a bundle describes. Default none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub more_data: Vec<PathBuf>,
    /// Vary each training sample's look as units differ (`train::data::Look`: colour gains
    /// and a tone exponent on the frame and its reference alike), for a base model that should
    /// read units it never saw. Default false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub vary_look: bool,
    /// Weight of the force outputs' terms in the loss (`model::DepthLossConfig::pressure_weight`);
    /// above zero the network gets the pressure output and the force head and trains them on the
    /// samples' pressure maps and force. Default 0: depth only.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub force_weight: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn one() -> f64 {
    1.0
}

fn paper_range() -> [f32; 2] {
    model::PAPER_NET_RANGE
}

/// The optimiser every run uses (Adam, Burn's defaults); a checkpoint restores its state.
pub fn optimizer() -> burn::optim::ModuleOptimizer {
    burn::optim::AdamConfig::new().init()
}

/// A setting out of range: which one (with its command-line flag), its value and why.
#[derive(Debug, thiserror::Error)]
#[error("{flag} must be {rule}, got {value}")]
pub struct SettingError {
    pub flag: &'static str,
    pub rule: &'static str,
    pub value: String,
}

impl FitConfig {
    /// The defaults of the settings no recipe sets: `FitConfig::new` and the command line's
    /// defaults are these (one definition of each).
    pub const DEFAULT_SEED: u64 = 0;
    /// `--force-weight` where the network has (or the recipe gives it) a pressure output.
    pub const DEFAULT_FORCE_WEIGHT: f64 = 1.0;
    pub const DEFAULT_CHECKPOINT_EVERY: u64 = 50;
    pub const DEFAULT_ON_BAD_DATA: OnBadData = OnBadData::Stop;
    pub const DEFAULT_MAX_BAD_STEPS: u64 = 5;
    pub const DEFAULT_TRAIN_FRACTION: f64 = 1.0;

    /// A run on `data` at `input_hw` with the CLI's defaults.
    pub fn new(data: PathBuf, input_hw: [usize; 2]) -> Self {
        FitConfig {
            data,
            input_hw,
            epochs: 10,
            batch: 4,
            lr: 1e-4,
            seed: Self::DEFAULT_SEED,
            checkpoint_every: Self::DEFAULT_CHECKPOINT_EVERY,
            on_bad_data: Self::DEFAULT_ON_BAD_DATA,
            max_bad_steps: Self::DEFAULT_MAX_BAD_STEPS,
            freeze_encoder: false,
            train_fraction: Self::DEFAULT_TRAIN_FRACTION,
            net_range: paper_range(),
            schedule: Schedule::Constant,
            warmup_steps: 0,
            val_fraction: 0.1,
            contact_weight: 0.0,
            patience: None,
            max_minutes: None,
            more_data: Vec::new(),
            vary_look: false,
            force_weight: 0.0,
        }
    }

    /// What a fine-tuning of the network `from` on `data` starts from (`train finetune`'s
    /// defaults): [`FitConfig::new`]'s, with the force terms where `from` has the pressure output.
    pub fn finetune(data: PathBuf, input_hw: [usize; 2], from: &model::DenseDepthConfig) -> Self {
        let force_weight = if from.pressure { Self::DEFAULT_FORCE_WEIGHT } else { 0.0 };
        FitConfig { force_weight, ..FitConfig::new(data, input_hw) }
    }

    /// Every dataset folder of the run: `data`, then `more_data`.
    pub fn folders(&self) -> Vec<PathBuf> {
        std::iter::once(self.data.clone()).chain(self.more_data.iter().cloned()).collect()
    }

    /// Checks every setting; the error names the first one out of range.
    pub fn validate(&self) -> Result<(), SettingError> {
        let check =
            |ok: bool, flag, rule, value: String| if ok { Ok(()) } else { Err(SettingError { flag, rule, value }) };
        let [h, w] = self.input_hw;
        check(
            model::DenseDepthConfig::check_input_hw(self.input_hw).is_ok(),
            "--input",
            "HxW with both sides at least 29",
            format!("{h}x{w}"),
        )?;
        check(self.epochs > 0, "--epochs", "at least 1", self.epochs.to_string())?;
        check(self.batch > 0, "--batch", "at least 1", self.batch.to_string())?;
        check(self.lr.is_finite() && self.lr > 0.0, "--lr", "a positive finite number", self.lr.to_string())?;
        check(self.checkpoint_every > 0, "--checkpoint-every", "at least 1", self.checkpoint_every.to_string())?;
        check(self.max_bad_steps > 0, "--max-bad-steps", "at least 1", self.max_bad_steps.to_string())?;
        check(
            self.train_fraction > 0.0 && self.train_fraction <= 1.0,
            "--train-fraction",
            "in (0, 1]",
            self.train_fraction.to_string(),
        )?;
        check((0.0..1.0).contains(&self.val_fraction), "--val-fraction", "in [0, 1)", self.val_fraction.to_string())?;
        check(
            self.contact_weight.is_finite() && self.contact_weight >= 0.0,
            "--contact-weight",
            "a finite number at least 0",
            self.contact_weight.to_string(),
        )?;
        check(
            self.force_weight.is_finite() && self.force_weight >= 0.0,
            "--force-weight",
            "a finite number at least 0",
            self.force_weight.to_string(),
        )?;
        check(self.patience != Some(0), "--patience", "at least 1", "0".into())?;
        check(
            self.patience.is_none() || self.val_fraction > 0.0,
            "--patience",
            "used with a validation hold-out (--val-fraction above 0)",
            format!("{:?} with --val-fraction 0", self.patience),
        )?;
        check(
            self.max_minutes.is_none_or(|m| m.is_finite() && m > 0.0),
            "--max-minutes",
            "a positive finite number",
            format!("{:?}", self.max_minutes),
        )?;
        let [lo, hi] = self.net_range;
        check(
            lo.is_finite() && hi.is_finite() && lo < hi,
            "--depth-units",
            "an increasing range",
            format!("{lo}..{hi}"),
        )
    }

    /// The depth scale of this run for a sensor whose depth is clipped at `max_depth_mm`.
    pub fn scale(&self, max_depth_mm: f64) -> DepthScale {
        DepthScale { max_depth_mm: max_depth_mm as f32, net_min: self.net_range[0], net_max: self.net_range[1] }
    }

    /// The training loss for depths in `scale`'s units: SSIM over its range, this run's contact
    /// weight, contact where the target is deeper than `sensor::CONTACT_THRESHOLD_MM`.
    pub fn loss(&self, scale: &DepthScale) -> model::DepthLossConfig {
        model::DepthLossConfig::new()
            .with_dynamic_range(scale.range() as f64)
            .with_contact_weight(self.contact_weight)
            .with_contact_above(scale.to_net(sensor::CONTACT_THRESHOLD_MM) as f64)
            .with_pressure_weight(self.force_weight)
    }

    /// The learning rate of (1-based) step `step` of `total` steps.
    pub fn learning_rate(&self, step: u64, total: u64) -> f64 {
        if step <= self.warmup_steps {
            return self.lr * step as f64 / (self.warmup_steps + 1) as f64;
        }
        match self.schedule {
            Schedule::Constant => self.lr,
            Schedule::Cosine => {
                let span = total.saturating_sub(self.warmup_steps).max(1) as f64;
                let t = ((step - self.warmup_steps) as f64 / span).min(1.0);
                let floor = 0.01;
                self.lr * (floor + (1.0 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_clis_and_bad_settings_are_named() {
        let c = FitConfig::new("d".into(), [64, 64]);
        c.validate().unwrap();
        assert_eq!((c.val_fraction, c.batch, c.epochs), (0.1, 4, 10));
        let cases: [(FitConfig, &str); 11] = [
            (FitConfig { patience: Some(0), ..c.clone() }, "--patience"),
            (FitConfig { patience: Some(2), val_fraction: 0.0, ..c.clone() }, "--patience"),
            (FitConfig { max_minutes: Some(f64::NAN), ..c.clone() }, "--max-minutes"),
            (FitConfig { contact_weight: -1.0, ..c.clone() }, "--contact-weight"),
            (FitConfig { batch: 0, ..c.clone() }, "--batch"),
            (FitConfig { epochs: 0, ..c.clone() }, "--epochs"),
            (FitConfig { lr: f64::NAN, ..c.clone() }, "--lr"),
            (FitConfig { lr: f64::INFINITY, ..c.clone() }, "--lr"),
            (FitConfig { input_hw: [64, 28], ..c.clone() }, "--input"),
            (FitConfig { val_fraction: 1.0, ..c.clone() }, "--val-fraction"),
            (FitConfig { train_fraction: 0.0, ..c.clone() }, "--train-fraction"),
        ];
        for (bad, flag) in cases {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.starts_with(flag), "{e}");
        }
    }

    #[test]
    fn the_schedule_warms_up_and_decays_to_one_percent() {
        let c =
            FitConfig { lr: 1.0, warmup_steps: 9, schedule: Schedule::Cosine, ..FitConfig::new("d".into(), [32, 32]) };
        assert!((c.learning_rate(5, 100) - 0.5).abs() < 1e-12);
        assert!((c.learning_rate(10, 100) - 1.0).abs() < 0.01);
        assert!((c.learning_rate(100, 100) - 0.01).abs() < 1e-9);
    }
}
