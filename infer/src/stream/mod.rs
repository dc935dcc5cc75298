//! `infer stream`: frames in as they come, depth, contact and point clouds out, at camera rate.
//!
//! A capture thread takes frames from a [`Source`], decodes and crops them, and hands them to
//! the network's thread through a one-frame mailbox: on a live source the newest frame replaces
//! a waiting one, which is dropped and counted (a robot wants the present, not a queue of the
//! past); an offline source waits instead. Latency runs from a frame's arrival to its result
//! having been handed to every sink.

mod mailbox;
mod report;
#[cfg(feature = "ros2")]
mod ros2;
mod sink;
mod source;
#[cfg(feature = "v4l2")]
mod v4l2;
#[cfg(feature = "view")]
mod view;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use image::RgbImage;
use sensor::{CONTACT_THRESHOLD_MM, DepthMap};

use crate::{InferError, PointCloud, Predictor, ReferenceKeeper, RefreshConfig};
use mailbox::Mailbox;
pub use report::{FrameRecord, Percentiles, StreamReport};
#[cfg(feature = "ros2")]
pub use ros2::{Ros2Sink, messages as ros2_messages, msg as ros2_msg};
pub use sink::{FolderSink, Sink, SinkError};
pub use source::{
    Clock, Delivered, Delivery, FolderSource, GlobSource, RawFrame, Source, SourceError, WallClock, yuyv_to_rgb,
};
#[cfg(feature = "v4l2")]
pub use v4l2::CameraSource;
#[cfg(feature = "view")]
pub use view::ViewSink;

/// A decoded frame waiting for the network.
pub(crate) struct Arrived {
    pub name: String,
    pub arrived: Instant,
    pub image: RgbImage,
}

/// One frame's results, as sinks see them.
pub struct FrameResult<'a> {
    /// The frame's name (its file's path, or the camera's sequence number).
    pub name: &'a str,
    /// When it arrived (its results' timestamp).
    pub arrived: Instant,
    /// The crop the network read, as the camera gave it.
    pub image: &'a RgbImage,
    /// Depth on the crop's grid (mm).
    pub depth: &'a DepthMap,
    /// Whether each pixel of `depth` is deeper than the contact threshold.
    pub contact: &'a [bool],
    /// Pixels deeper than the contact threshold.
    pub contact_pixels: usize,
    /// Points of the contact patch (sensor frame, mm); empty without contact.
    pub cloud: &'a PointCloud,
    /// Whether the network ran (false: the contact gate saw an untouched frame).
    pub network_ran: bool,
    /// Contact pressure and wrench, from a bundle with the force output.
    pub force: Option<&'a crate::Force>,
}

/// When a stream stops besides its source's end or Ctrl-C.
#[derive(Clone, Debug, Default)]
pub struct StreamLimits {
    /// Stop after this many frames have been processed.
    pub max_frames: Option<u64>,
    /// Print a progress line this often (to stderr).
    pub progress_every: Option<Duration>,
    /// Whether the reference frame follows the camera from untouched frames (the default) or
    /// stays the bundle's (`--fixed-reference`; every frame's global drift is taken out either way).
    pub reference: ReferencePolicy,
}

/// What a stream does with its reference frame. Following is the default: a global balance
/// cannot take out drift that is not the same everywhere (one LED warming), and on a drifting
/// simulated camera (`cargo xtask bench drift`) the fixed reference then ran the network on
/// most untouched frames, where following gated them all at the same contact accuracy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReferencePolicy {
    /// Stays the bundle's for the whole stream.
    Fixed,
    /// Follows the camera's drift from untouched frames ([`ReferenceKeeper`]).
    Follow(RefreshConfig),
}

impl Default for ReferencePolicy {
    fn default() -> Self {
        ReferencePolicy::Follow(RefreshConfig::default())
    }
}

/// Why a stream failed as a whole (a single bad frame does not fail it).
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error("no frame could be used; the first problem: {0}")]
    NothingUsable(String),
    #[error(transparent)]
    Sink(#[from] SinkError),
}

/// Runs `source` through `predictor` until the source ends, `stop` is set (Ctrl-C) or a limit
/// is reached, giving each frame's results to every sink. Bad frames are counted and reported
/// by name; the stream goes on.
pub fn run(
    predictor: &Predictor,
    mut source: Box<dyn Source>,
    sinks: &mut [&mut dyn Sink],
    limits: &StreamLimits,
    stop: &AtomicBool,
) -> Result<StreamReport, StreamError> {
    let mailbox = Mailbox::new(source.delivery());
    let mut report = StreamReport::new(source.describe(), source.delivery());
    let mut records = Vec::new();
    let started = Instant::now();
    // The network's side reads against a reference that may follow the camera; the capture
    // side needs only the sensor and the first frame's channel check.
    let mut live = predictor.clone();
    let mut keeper = match limits.reference {
        ReferencePolicy::Follow(config) if predictor.reference.is_some() => Some(ReferenceKeeper::new(config)),
        _ => None,
    };
    std::thread::scope(|scope| {
        scope.spawn(|| {
            capture(&mut *source, predictor, &mailbox, stop);
            mailbox.close();
        });
        let mut last_progress = Instant::now();
        let result = (|| -> Result<(), StreamError> {
            while let Some(frame) = mailbox.take() {
                // The capture made it the crop: its size is not checked again.
                let crate::Prediction { depth, force, network_ran } = live.predict_all_crop(&frame.image);
                let contact = Predictor::contact_mask(&depth, CONTACT_THRESHOLD_MM);
                let contact_pixels = contact.iter().filter(|&&c| c).count();
                let cloud = if contact_pixels > 0 {
                    live.point_cloud(&depth, CONTACT_THRESHOLD_MM)
                } else {
                    PointCloud::default()
                };
                let result = FrameResult {
                    name: &frame.name,
                    arrived: frame.arrived,
                    image: &frame.image,
                    depth: &depth,
                    contact: &contact,
                    contact_pixels,
                    cloud: &cloud,
                    network_ran,
                    force: force.as_ref(),
                };
                for sink in sinks.iter_mut() {
                    sink.frame(&live, &result).map_err(StreamError::Sink)?;
                }
                // Untouched as the gate (closed) and the network (no contact pixel) both say:
                // the reference may follow it.
                let untouched = contact_pixels == 0 && (live.gate.is_none() || !network_ran);
                let seen_s = frame.arrived.saturating_duration_since(started).as_secs_f64();
                if let (Some(keeper), Some(reference)) = (keeper.as_mut(), live.reference.as_ref())
                    && let Some(updated) = keeper.observe(seen_s, &frame.image, untouched, reference)
                    && let Err(e) = live.set_reference(predictor.undrifted(updated))
                {
                    mailbox.failed(format!("{}: the reference could not follow it: {e}", frame.name));
                }
                records.push(FrameRecord {
                    name: frame.name.clone(),
                    arrived_s: frame.arrived.saturating_duration_since(started).as_secs_f64(),
                    latency_ms: frame.arrived.elapsed().as_secs_f64() * 1e3,
                    network_ran,
                    contact_pixels,
                    max_depth_mm: depth.max_mm(),
                    fx_n: force.as_ref().map(|f| f.wrench.force_n[0]),
                    fy_n: force.as_ref().map(|f| f.wrench.force_n[1]),
                    fz_n: force.as_ref().map(|f| f.wrench.force_n[2]),
                });
                if limits.max_frames.is_some_and(|m| records.len() as u64 >= m) {
                    stop.store(true, Ordering::Relaxed);
                    break;
                }
                if limits.progress_every.is_some_and(|every| last_progress.elapsed() >= every) {
                    last_progress = Instant::now();
                    report.update(&records, &mailbox.counts(), started.elapsed());
                    eprintln!("{}", report.progress_line());
                }
            }
            Ok(())
        })();
        // The capture thread ends at its next look once stopped, also after a sink failed.
        stop.store(true, Ordering::Relaxed);
        mailbox.close();
        result
    })?;
    let mut counts = mailbox.counts();
    counts.problems.extend(source.unfinished());
    report.update(&records, &counts, started.elapsed());
    report.reference_follows = keeper.is_some();
    report.reference_updates = keeper.map_or(0, |k| k.updates);
    report.frames = records;
    if report.processed == 0
        && let Some(first) = counts.problems.first()
    {
        return Err(StreamError::NothingUsable(first.clone()));
    }
    Ok(report)
}

/// The capture thread: frames from `source`, decoded and cropped, into the mailbox.
fn capture(source: &mut dyn Source, predictor: &Predictor, mailbox: &Mailbox, stop: &AtomicBool) {
    let mut channels_checked = false;
    while let Some(delivered) = source.next(stop) {
        match delivered {
            Delivered::Skipped(n) => mailbox.skipped(n),
            Delivered::Unreadable { name, message } => mailbox.unreadable(format!("{name}: {message}")),
            Delivered::Frame { name, arrived, raw } => {
                let path = std::path::Path::new(&name);
                let image = match raw {
                    RawFrame::Encoded(bytes) => sensor::frame::decode(path, &bytes).map_err(InferError::from),
                    RawFrame::Rgb(image) => Ok(image),
                }
                // A source's channel order does not change: the first frame that passes tells.
                .and_then(|image| predictor.accept_frame(path, image, !channels_checked));
                match image {
                    Ok(image) => {
                        channels_checked = true;
                        mailbox.put(Arrived { name, arrived, image })
                    }
                    Err(e) => mailbox.unreadable(e.to_string()),
                }
            }
        }
        if mailbox.is_closed() {
            return;
        }
    }
}
