//! Training, resuming and fine-tuning DenseDepth on dataset folders, and export of the bundle
//! that `infer` loads.

#![deny(unsafe_code)]

pub mod checkpoint;
mod config;
mod contrast;
pub mod data;
pub mod elastomer;
pub mod export;
mod fit;
mod force_refit;
pub mod gate;
mod loader;
pub mod parallel;
mod recipe;
mod view;

pub use config::{FitConfig, OnBadData, Schedule, SettingError, optimizer};
pub use fit::{Evaluation, Fitted, RunOptions, Start, fit, fit_on, fit_with, permutation, select, validate};
pub use force_refit::ForceRefit;
pub use formats::training::EpochMetrics;
pub use loader::{BatchLoader, DecodedBatch};
pub use recipe::{Recipe, RecipeNetwork};
