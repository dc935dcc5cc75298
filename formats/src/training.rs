//! What a bundle records of how its weights came to be (`bundle.json`'s `training`), and the
//! per-epoch metrics a run writes: read by `infer` beside every speed figure it prints.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// One epoch's numbers (also a row of a run's `metrics.csv`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    pub epoch: usize,
    pub train_loss: f64,
    pub val_l1_mm: f64,
    pub val_loss: f64,
    pub skipped_steps: u64,
    pub bad_samples: usize,
    pub seconds: f64,
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
    /// Mean per-image L1 (mm, useful pixels, network resolution) on the dataset's test split.
    pub test_l1_mm: Option<f64>,
    /// Test images that number is the mean of.
    pub test_images: usize,
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
            TrainingRecord::Trained(t) => t.test_l1_mm,
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
                seconds: 3.0,
            }],
            test_l1_mm: Some(0.15),
            test_images: 12,
            selected_epoch: 2,
        });
        let imported = TrainingRecord::Imported(Imported { imported_from: "w.pth".into() });
        for record in [trained, imported] {
            let text = serde_json::to_string(&record).unwrap();
            assert_eq!(serde_json::from_str::<TrainingRecord>(&text).unwrap(), record);
        }
        let old: TrainingRecord = serde_json::from_str(r#"{"imported_from": "a.pth"}"#).unwrap();
        assert_eq!(old.test_l1_mm(), None);
    }
}
