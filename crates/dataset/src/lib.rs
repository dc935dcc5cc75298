//! Ground truth for DenseTact sensors: meshes, kits, scenes posed like the paper's rig, and
//! depth maps ray-cast through the sensor's fisheye correspondence.

// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod calibrate;
pub mod format;
pub mod generate;
pub mod gp;
pub mod holes;
pub mod kit;
pub mod mesh;
pub mod procedural;
pub mod progress;
pub mod raycast;
pub mod rays;
pub mod render;
pub mod rng;
pub mod sawtooth;
pub mod scene;
pub mod shapes;
pub mod unit;

pub use kit::{Kit, Split, Trial};
pub use mesh::{LoadOptions, Mesh, UpAxis};
pub use raycast::{CastStats, RayCaster, Skipping};
pub use rays::Cone;
pub use rays::RayBundle;
pub use render::{PixelGrid, Renderer};
pub use sawtooth::{SawTooth, SawToothShot};
pub use scene::{Indenter, Indicator, RigPose, Scene, SceneDescription};
pub use unit::SensorUnit;
