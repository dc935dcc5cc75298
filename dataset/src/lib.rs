//! Ground truth for DenseTact sensors: meshes, kits, scenes posed like the paper's rig, depth
//! maps ray-cast through the sensor's fisheye correspondence, simulated units' camera images,
//! and the fisheye calibration from a saw-tooth frame.
//!
//! The dataset folder format itself lives in the `formats` crate, which training and inference
//! read without this crate's dependencies.

#![deny(unsafe_code)]
// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod calibration;
pub mod cli;
pub mod generate;
pub mod holes;
pub mod kit;
pub mod label;
pub mod looks;
pub mod merge;
pub mod mesh;
pub mod procedural;
// AVX2 kernels in some of their modules (which allow unsafe code by name), reached only
// through `simd::Avx2` tokens (or `simd`'s own dispatch).
pub mod raycast;
pub mod register;
pub mod render;
mod resumable;
pub mod rig;
pub mod scene;
pub mod session;
pub mod shapes;
#[allow(unsafe_code)]
mod simd;
pub mod touch;
pub mod unit;

/// The elastomer's contact mechanics (its own crate, shared with `infer`).
pub use ::mechanics;
pub use calibration::sawtooth::{SawTooth, SawToothShot};
pub use kit::{Kit, Split, Trial};
pub use mesh::{LoadOptions, Mesh, MeshError, UpAxis, parse_obj, parse_stl};
pub use raycast::{Cone, RayBundle, RayCaster, Skipping};
pub use render::{Capture, PixelGrid, Renderer};
pub use scene::{Indenter, Indicator, RigPose, Scene, SceneDescription};
pub use unit::SensorUnit;
