//! Checkpoints: model, optimiser and where the run stands, replaced atomically.
//!
//! `RUN/checkpoint/` holds `model.bpk`, `optim.bpk` and `state.json`. A new checkpoint is written
//! into `RUN/checkpoint.new/`, then the old folder is renamed away and the new one into place;
//! a kill between the two renames leaves `checkpoint.old/`, which a resume takes instead.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device};
use model::{DenseDepth, DenseDepthConfig};
use serde::{Deserialize, Serialize};

use formats::training::EpochMetrics;

use crate::config::FitConfig;

/// Where a run stands: the next step to take, and what it has measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    pub config: FitConfig,
    pub model: DenseDepthConfig,
    /// Epoch and batch within it that the run does next.
    pub epoch: usize,
    pub batch: usize,
    pub global_step: u64,
    pub skipped_steps: u64,
    pub bad_samples: Vec<String>,
    /// Validation samples left out (`--on-bad-data skip`).
    #[serde(default)]
    pub bad_val_samples: Vec<String>,
    pub history: Vec<EpochMetrics>,
    /// Sum and count of the training loss over the current epoch so far.
    pub epoch_loss_sum: f64,
    pub epoch_loss_count: u64,
    /// SHA-256 of each data folder's `manifest.json` (every sample's record, a labelled row's
    /// digests among them) when the run began, by folder: a resume on data that changed is
    /// refused. Absent in runs begun before it was recorded (not checked).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub data_sha256: BTreeMap<String, String>,
}

/// The digests [`RunState::data_sha256`] records for `folders`.
pub fn data_digests(folders: &[std::path::PathBuf]) -> anyhow::Result<BTreeMap<String, String>> {
    folders
        .iter()
        .map(|dir| {
            let path = dir.join("manifest.json");
            let bytes = std::fs::read(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            Ok((dir.display().to_string(), formats::fs::sha256_hex(&bytes)))
        })
        .collect()
}

impl RunState {
    /// A run that has not taken a step yet.
    pub fn new(config: FitConfig, model: DenseDepthConfig) -> Self {
        RunState {
            config,
            model,
            epoch: 0,
            batch: 0,
            global_step: 0,
            skipped_steps: 0,
            bad_samples: Vec::new(),
            bad_val_samples: Vec::new(),
            history: Vec::new(),
            epoch_loss_sum: 0.0,
            epoch_loss_count: 0,
            data_sha256: BTreeMap::new(),
        }
    }

    /// The epoch with the lowest validation L1 so far.
    pub fn best(&self) -> Option<&EpochMetrics> {
        self.history.iter().filter(|m| m.val_l1_mm.is_finite()).min_by(|a, b| a.val_l1_mm.total_cmp(&b.val_l1_mm))
    }

    /// Why the run should end before its last epoch, if it should: the validation error has not
    /// improved for `patience` epochs (held-out validation only: stopping on the test split would
    /// leak it), or the epochs so far took `max_minutes`. Decided from the history alone, so a
    /// resumed run stops where an uninterrupted one did.
    pub fn stop_reason(&self) -> Option<String> {
        let last = self.history.last()?;
        if let (Some(patience), Some(best)) = (self.config.patience, self.best())
            && self.config.val_fraction > 0.0
            && last.epoch >= best.epoch + patience
        {
            return Some(format!(
                "stopped early: validation L1 has not improved for {patience} epochs (best {:.4} mm at epoch {})",
                best.val_l1_mm, best.epoch
            ));
        }
        let minutes = self.history.iter().map(|m| m.seconds).sum::<f64>() / 60.0;
        match self.config.max_minutes {
            Some(cap) if minutes >= cap => {
                Some(format!("stopped early: {minutes:.1} minutes of training reached the cap of {cap} minutes"))
            }
            _ => None,
        }
    }

    /// The epoch whose model the run hands on: the best one when it validates on held-out
    /// training samples, else the last (picking on the test split would leak it).
    pub fn selected(&self) -> Option<&EpochMetrics> {
        if self.config.val_fraction > 0.0 { self.best() } else { self.history.last() }
    }
}

pub fn dir(run: &Path) -> PathBuf {
    run.join("checkpoint")
}

/// The model of the best epoch on the held-out validation samples, if the run keeps one.
pub fn best(run: &Path) -> Option<PathBuf> {
    Some(run.join("best")).filter(|d| d.join("state.json").is_file() && d.join("model.bpk").is_file())
}

/// Writes a checkpoint and swaps it in.
pub fn save(run: &Path, net: &DenseDepth, optim: &ModuleOptimizer, state: &RunState) -> Result<()> {
    let optim_bytes = optim.into_bytes().context("serialising the optimiser")?;
    swap_in(run, "checkpoint", net, Some(&optim_bytes), state)
}

/// Writes the best epoch's model (no optimiser: it is for export, not for resuming).
pub fn save_best(run: &Path, net: &DenseDepth, state: &RunState) -> Result<()> {
    swap_in(run, "best", net, None, state)
}

fn swap_in(run: &Path, name: &str, net: &DenseDepth, optim: Option<&[u8]>, state: &RunState) -> Result<()> {
    let final_dir = run.join(name);
    let (new, old) = (run.join(format!("{name}.new")), run.join(format!("{name}.old")));
    let _ = std::fs::remove_dir_all(&new);
    std::fs::create_dir_all(&new).with_context(|| format!("{}: cannot create", new.display()))?;
    // Burn keeps BatchNorm's running statistics per thread and folds them in lazily; a record
    // taken straight from the training module would lag a step. `valid()` folds them first.
    let model_bytes = net.valid().into_record().into_bytes().context("serialising the model")?;
    formats::fs::write_atomic(&new.join("model.bpk"), &model_bytes)?;
    if let Some(bytes) = optim {
        formats::fs::write_atomic(&new.join("optim.bpk"), bytes)?;
    }
    formats::write_json(&new.join("state.json"), state)?;
    if final_dir.exists() {
        let _ = std::fs::remove_dir_all(&old);
        std::fs::rename(&final_dir, &old).with_context(|| format!("{}: cannot rename", final_dir.display()))?;
    }
    std::fs::rename(&new, &final_dir).with_context(|| format!("{}: cannot rename", new.display()))?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// The checkpoint a resume should read, if any.
pub fn latest(run: &Path) -> Option<PathBuf> {
    [dir(run), run.join("checkpoint.old")].into_iter().find(|d| d.join("state.json").is_file())
}

/// Reads a checkpoint's state.
pub fn read_state(ckpt: &Path) -> Result<RunState> {
    let path = ckpt.join("state.json");
    let bytes = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_state(&path, &bytes)
}

/// Parses and checks a checkpoint's `state.json` (`path` names it in errors): its settings pass
/// the CLI's checks, its model is one a file may describe, its position lies within the run.
pub fn parse_state(path: &Path, bytes: &[u8]) -> Result<RunState> {
    let state: RunState =
        serde_json::from_slice(bytes).with_context(|| format!("{}: not a checkpoint state", path.display()))?;
    let bad = |what: String| anyhow::anyhow!("{}: {what}", path.display());
    state.config.validate().map_err(|e| bad(format!("its settings: {e}")))?;
    state.model.check().map_err(|e| bad(format!("its model: {e}")))?;
    if state.epoch > state.config.epochs || state.history.len() > state.epoch {
        return Err(bad(format!(
            "it stands at epoch {} of {} with {} epoch(s) measured",
            state.epoch,
            state.config.epochs,
            state.history.len()
        )));
    }
    Ok(state)
}

fn read(dir: &Path, name: &str) -> Result<Bytes> {
    let path = dir.join(name);
    Ok(Bytes::from_bytes_vec(std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?))
}

/// Restores a saved network on `device`.
pub fn restore_model(dir: &Path, model: &DenseDepthConfig, device: &Device) -> Result<DenseDepth> {
    let record = ModuleRecord::from_bytes(read(dir, "model.bpk")?)
        .with_context(|| format!("{}: not a model record", dir.join("model.bpk").display()))?;
    model
        .init(device)
        .try_load_record(record)
        .with_context(|| format!("{}: does not fit the run's model", dir.join("model.bpk").display()))
}

/// Restores the network (on `device`) and the optimiser from a checkpoint.
pub fn restore(ckpt: &Path, state: &RunState, device: &Device) -> Result<(DenseDepth, ModuleOptimizer)> {
    let net = restore_model(ckpt, &state.model, device)?;
    let optim = crate::config::optimizer()
        .from_bytes(read(ckpt, "optim.bpk")?)
        .with_context(|| format!("{}: not an optimiser record", ckpt.join("optim.bpk").display()))?;
    Ok((net, optim))
}

#[cfg(test)]
mod stop_tests {
    use super::*;

    fn state(val_l1: &[f64], seconds: f64, patience: Option<usize>, max_minutes: Option<f64>) -> RunState {
        let config = FitConfig { patience, max_minutes, ..FitConfig::new("d".into(), [64, 64]) };
        let mut s = RunState::new(config, DenseDepthConfig::new(model::DenseNetConfig::tiny()));
        s.history = val_l1
            .iter()
            .enumerate()
            .map(|(i, &v)| EpochMetrics {
                epoch: i + 1,
                train_loss: 0.1,
                val_l1_mm: v,
                val_loss: 0.1,
                skipped_steps: 0,
                bad_samples: 0,
                bad_val_samples: 0,
                seconds,
                val_pressure_l1_kpa: None,
            })
            .collect();
        s
    }

    #[test]
    fn runs_stop_after_patience_epochs_without_improvement_or_at_the_time_cap() {
        // Best at epoch 2; epochs 3 and 4 no better: patience 2 stops, patience 3 goes on.
        let h = [0.5, 0.3, 0.31, 0.3];
        assert!(state(&h, 10.0, Some(2), None).stop_reason().unwrap().contains("epoch 2"));
        assert!(state(&h, 10.0, Some(3), None).stop_reason().is_none());
        // A NaN validation error is no improvement.
        assert!(state(&[0.5, f64::NAN, f64::NAN], 10.0, Some(2), None).stop_reason().is_some());
        // Four epochs of 30 s: a 2-minute cap is reached, a 2.5-minute one is not.
        assert!(state(&h, 30.0, None, Some(2.0)).stop_reason().unwrap().contains("cap"));
        assert!(state(&h, 30.0, None, Some(2.5)).stop_reason().is_none());
        assert!(state(&[], 30.0, Some(1), Some(0.1)).stop_reason().is_none(), "nothing to decide on yet");
    }
}
