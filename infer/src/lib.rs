//! Light inference from an exported bundle: depth maps, contact masks and point clouds from
//! camera frames. Depends on the network and the bundle format only: no autodiff, no training.

#![deny(unsafe_code)]

pub mod bench;
pub mod cloud;
pub mod colour;
pub mod eval;
pub mod icp;
pub mod kdtree;
pub mod plot;
pub mod predictor;
pub mod refresh;
pub mod stream;

pub use cloud::{PointCloud, write_ply};
pub use predictor::{Force, InferError, Prediction, Predictor};
pub use refresh::{ReferenceKeeper, RefreshConfig};
