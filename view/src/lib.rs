//! Live views for people: a stream's frames, depth, contact and point cloud, or a training run's
//! losses and held-out predictions, sent to a Rerun viewer or recorded to a `.rrd` file that the
//! viewer opens later (`rerun FILE.rrd`), and read back by tests.
//!
//! Without its `rerun` feature the crate is only the options ([`ViewArgs`]) and the names
//! below: the Rerun SDK (about 500 crates) is built only where a view is asked for.
//!
//! The entity paths are this crate's ([`entity`]), so that the stream, the training run and their
//! tests name the same things alike.

mod args;
#[cfg(feature = "rerun")]
mod layout;
#[cfg(feature = "rerun")]
mod readback;
#[cfg(feature = "rerun")]
mod record;

pub use args::{Target, ViewArgs};
#[cfg(feature = "rerun")]
pub use layout::{Panel, panels_by_name, stream_columns, training_columns};
#[cfg(feature = "rerun")]
pub use readback::{Recording, read_back};
#[cfg(feature = "rerun")]
pub use record::{View, ViewError};

/// The entity paths a view logs under (one definition for writers and readers).
pub mod entity {
    /// The camera's crop as it came (RGB).
    pub const FRAME: &str = "camera/frame";
    /// The contact mask, drawn over the frame (class 1: deeper than the contact threshold).
    pub const CONTACT: &str = "camera/contact";
    /// The depth map (mm), false colour in the viewer.
    pub const DEPTH: &str = "depth";
    /// The contact pressure (kPa), from a bundle with the force output.
    pub const PRESSURE: &str = "pressure";
    /// The contact patch's points (mm, sensor frame).
    pub const CLOUD: &str = "sensor/cloud";
    /// The contact force as an arrow from the patch's centroid (mm per newton: [`super::FORCE_ARROW_MM_PER_N`]).
    pub const FORCE_ARROW: &str = "sensor/force";
    /// Frames per second over the last second of the stream.
    pub const FPS: &str = "rates/fps";
    /// A frame's latency from its arrival to its results (ms).
    pub const LATENCY_MS: &str = "rates/latency_ms";
    /// 1 where the network ran, 0 where the contact gate skipped it.
    pub const NETWORK_RAN: &str = "rates/network_ran";
    /// The deepest point of a frame (mm).
    pub const MAX_DEPTH_MM: &str = "contact/max_depth_mm";
    /// Pixels deeper than the contact threshold.
    pub const CONTACT_PIXELS: &str = "contact/pixels";
    /// The force's components (N, sensor frame).
    pub const FORCE_N: [&str; 3] = ["force/fx_n", "force/fy_n", "force/fz_n"];
    /// The torque's components about the dome's centre (N mm, sensor frame).
    pub const TORQUE_NMM: [&str; 3] = ["torque/tx_nmm", "torque/ty_nmm", "torque/tz_nmm"];
    /// A training step's loss and learning rate.
    pub const TRAIN_LOSS: &str = "train/loss";
    pub const LEARNING_RATE: &str = "train/learning_rate";
    /// An epoch's mean training loss.
    pub const EPOCH_LOSS: &str = "train/epoch_loss";
    /// An epoch's validation L1 (mm) and loss, and pressure L1 (kPa) where there is one.
    pub const VAL_L1_MM: &str = "validation/l1_mm";
    pub const VAL_LOSS: &str = "validation/loss";
    pub const VAL_PRESSURE_L1_KPA: &str = "validation/pressure_l1_kpa";
    /// Held-out samples, `held_out/K/{input,truth,prediction,error}`.
    pub fn held_out(k: usize, what: &str) -> String {
        format!("held_out/{k}/{what}")
    }
}

/// The timelines: a stream's frames (sequence and seconds since the start), a run's steps and
/// epochs.
pub mod timeline {
    pub const FRAME: &str = "frame";
    pub const STREAM_TIME: &str = "stream_time";
    pub const STEP: &str = "step";
    pub const EPOCH: &str = "epoch";
}

/// Length of the force arrow per newton (mm): 1 N spans about a fifth of the dome's radius.
pub const FORCE_ARROW_MM_PER_N: f32 = 5.0;
