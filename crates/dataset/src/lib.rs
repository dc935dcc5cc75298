//! Ground truth for DenseTact sensors: meshes, kits, scenes posed like the paper's rig, and
//! depth maps ray-cast through the sensor's fisheye correspondence.

pub mod format;
pub mod generate;
pub mod holes;
pub mod kit;
pub mod mesh;
pub mod procedural;
pub mod progress;
pub mod rays;
pub mod raycast;
pub mod rng;
pub mod scene;
pub mod shapes;

pub use kit::{Kit, Split, Trial};
pub use mesh::{LoadOptions, Mesh, UpAxis};
pub use rays::RayBundle;
pub use raycast::{CastStats, RayCaster, Skipping};
pub use rays::Cone;
pub use scene::{Indenter, Indicator, RigPose, Scene, SceneDescription};
