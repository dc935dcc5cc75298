//! Training, resuming and fine-tuning DenseDepth on generated DenseTact datasets, and export of
//! the bundle that `infer` loads.

pub mod checkpoint;
pub mod data;
pub mod export;
pub mod parallel;
pub mod training;

pub use training::{FitConfig, OnBadData, fit, fit_on};
