//! Geometry of a DenseTact sensor, shared by dataset generation, training and inference.
//!
//! Kept free of heavy dependencies so that the deployment crate (`infer`) stays light.

#![deny(unsafe_code)]
// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

#[allow(unsafe_code)] // mallopt
pub mod alloc;
mod correspondence;
mod decode;
mod depth;
mod force;
pub mod frame;
pub mod gate;
mod grid;
pub mod resample;
mod sensor;
pub mod shared;

use std::path::{Path, PathBuf};

pub use correspondence::{Correspondence, RadialMap};
pub use decode::TRAILING_SLACK_BYTES;
pub use depth::{
    CONTACT_THRESHOLD_MM, DEPTH_STEPS_PER_MM, DepthMap, PNG_KPA_PER_STEP, PNG_UM_PER_STEP, PressureMap, depth_step,
    npy_f32, step_depth_mm,
};
pub use force::{DomeAreas, Wrench};
pub use grid::PixelGrid;
pub use sensor::{DEFAULT_FOCAL_PX_PER_RAD, MAX_FRAME_SIDE_PX, PixelRay, SENSOR_FORMAT_VERSION, Sensor};

/// Errors from reading, checking or writing a sensor description.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a valid sensor description: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("invalid sensor description: {0}")]
    Invalid(String),
    #[error("{path}: {message}")]
    InFile { path: PathBuf, message: String },
}

impl SensorError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        SensorError::Io { path: path.to_path_buf(), source }
    }

    /// Attaches the file name to an error found while checking that file's content.
    pub fn in_file(self, path: &Path) -> Self {
        match self {
            SensorError::Invalid(message) => SensorError::InFile { path: path.to_path_buf(), message },
            other => other,
        }
    }
}
