//! What a bundle records of how its weights came to be (`bundle.json`'s `training`), and the
//! per-epoch metrics a run writes: read by `infer` beside every speed figure it prints.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// One epoch's numbers (also a row of a run's `metrics.csv`). JSON has no NaN: a number that
/// was not finite is written as `null` and read back as NaN, so such a record still loads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    pub epoch: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub train_loss: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub val_l1_mm: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub val_loss: f64,
    pub skipped_steps: u64,
    /// Training samples left out so far (`--on-bad-data skip`).
    pub bad_samples: usize,
    /// Validation samples left out (`--on-bad-data skip`): the epoch's validation error is over
    /// the others.
    #[serde(default)]
    pub bad_val_samples: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub seconds: f64,
    /// Mean per-image pressure L1 (kPa, useful pixels, network resolution) of a network with
    /// the pressure output.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val_pressure_l1_kpa: Option<f64>,
}

/// A number, or NaN for `null` (what serde_json writes for a NaN or an infinity).
pub fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A test error as a bundle records it: the mean and how many images it is the mean of.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TestError {
    /// Mean per-image L1 (mm, useful pixels, network resolution).
    pub l1_mm: f64,
    pub images: usize,
}

/// A bundle's origin: a training run of this project, or PyTorch weights imported.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum TrainingRecord {
    Trained(Trained),
    Imported(Imported),
}

/// A run of `train fit` or `train finetune`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trained {
    /// The dataset folder it trained on.
    pub data: PathBuf,
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    pub seed: u64,
    pub steps: u64,
    pub skipped_steps: u64,
    pub bad_samples: Vec<String>,
    pub history: Vec<EpochMetrics>,
    /// The error on the dataset's whole test split; `None` when there is no test split or a test
    /// image could not be read (an incomplete evaluation is not recorded).
    #[serde(default)]
    pub test: Option<TestError>,
    /// Why `test` is `None`, when it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test_missing: Option<String>,
    /// Bundles written before `test` existed recorded the mean alone (read, never written).
    #[serde(default, skip_serializing)]
    pub test_l1_mm: Option<f64>,
    /// The epoch whose weights the bundle holds.
    pub selected_epoch: usize,
}

/// Weights imported from a PyTorch `state_dict`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Imported {
    pub imported_from: PathBuf,
}

impl TrainingRecord {
    /// The test error the run measured, if it did.
    pub fn test_l1_mm(&self) -> Option<f64> {
        match self {
            TrainingRecord::Trained(t) => t.test.map(|t| t.l1_mm).or(t.test_l1_mm),
            TrainingRecord::Imported(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_tell_their_kind() {
        let trained = TrainingRecord::Trained(Trained {
            data: "out/data".into(),
            epochs: 2,
            batch: 4,
            lr: 1e-3,
            seed: 1,
            steps: 10,
            skipped_steps: 0,
            bad_samples: vec![],
            history: vec![EpochMetrics {
                epoch: 1,
                train_loss: 0.5,
                val_l1_mm: 0.2,
                val_loss: 0.4,
                skipped_steps: 0,
                bad_samples: 0,
                bad_val_samples: 0,
                seconds: 3.0,
                val_pressure_l1_kpa: Some(4.5),
            }],
            test: Some(TestError { l1_mm: 0.15, images: 12 }),
            test_missing: None,
            test_l1_mm: None,
            selected_epoch: 2,
        });
        let imported = TrainingRecord::Imported(Imported { imported_from: "w.pth".into() });
        for record in [trained, imported] {
            let text = serde_json::to_string(&record).unwrap();
            assert_eq!(serde_json::from_str::<TrainingRecord>(&text).unwrap(), record);
        }
        let old: TrainingRecord = serde_json::from_str(r#"{"imported_from": "a.pth"}"#).unwrap();
        assert_eq!(old.test_l1_mm(), None);
        // A NaN written as null reads back as NaN.
        let m: EpochMetrics = serde_json::from_str(
            r#"{"epoch": 3, "train_loss": null, "val_l1_mm": null, "val_loss": 1.0, "skipped_steps": 9,
                "bad_samples": 0, "seconds": 2.0}"#,
        )
        .unwrap();
        assert!(m.train_loss.is_nan() && m.val_l1_mm.is_nan() && m.bad_val_samples == 0);
    }
}
