//! `infer stream --view` (feature `view`): each frame's results in a Rerun viewer, or recorded
//! to a `.rrd` file (`--view-save`): the frame with its contact mask over it, the depth in false
//! colour, the contact patch's points coloured by depth, with a force bundle the pressure and
//! the force as an arrow, and the rates and contact figures as time series, on the timelines
//! `frame` (processed frame number) and `stream_time` (seconds since the stream started).

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use view::{FORCE_ARROW_MM_PER_N, Target, View, ViewError, entity, timeline};

use super::{FrameResult, Sink, SinkError};
use crate::Predictor;
use crate::colour::depth_colour;

/// Sends a stream's frames to a view.
pub struct ViewSink {
    view: View,
    frames: i64,
    started: Option<Instant>,
    /// Arrivals within the last second, for the frame rate.
    recent: VecDeque<Instant>,
    /// Whether a force arrow is showing (cleared when the contact goes).
    arrow_shown: bool,
    /// The images, cloud and pressure of every `every`-th frame only.
    every: u32,
    /// The frames as JPEG of this quality, else raw.
    jpeg_quality: Option<u8>,
}

impl ViewSink {
    /// Opens the view on `target`, with the images, cloud and pressure of every `every`-th
    /// frame (the first, then each `every` on; 1: all) and the time series of all; the frames
    /// as JPEG of `jpeg_quality` where one is given, else raw; laid out with a pressure panel
    /// where the bundle has a force output (`has_force`).
    pub fn open(target: &Target, every: u32, jpeg_quality: Option<u8>, has_force: bool) -> Result<Self, SinkError> {
        let view = View::open("densetact_stream", target)?;
        view.lay_out(&view::stream_columns(has_force))?;
        let every = every.max(1);
        Ok(ViewSink {
            view,
            frames: 0,
            started: None,
            recent: VecDeque::new(),
            arrow_shown: false,
            every,
            jpeg_quality,
        })
    }

    /// Sends what is pending; a recording gets its name. Returns the recording's path.
    pub fn finish(self) -> Result<Option<PathBuf>, SinkError> {
        Ok(self.view.finish()?)
    }

    fn log(&mut self, predictor: &Predictor, result: &FrameResult) -> Result<(), ViewError> {
        let view = &self.view;
        let started = *self.started.get_or_insert(result.arrived);
        view.at(timeline::FRAME, self.frames);
        view.at_seconds(timeline::STREAM_TIME, result.arrived.saturating_duration_since(started).as_secs_f64());
        let pictured = self.frames % i64::from(self.every) == 0;
        self.frames += 1;
        let max_mm = predictor.file.sensor.max_depth_mm as f32;
        let depth = result.depth;
        // A point's depth is the dome's radius less its distance from the centre.
        let radius_mm = predictor.file.sensor.radius_mm as f32;
        let points = &result.cloud.points_mm;
        if pictured {
            match self.jpeg_quality {
                Some(quality) => view.rgb_jpeg(entity::FRAME, result.image, quality)?,
                None => view.rgb(entity::FRAME, result.image)?,
            }
            view.mask(entity::CONTACT, depth.size_px, result.contact)?;
            view.depth_um(entity::DEPTH, [depth.size_px; 2], &depth.depth_mm, max_mm)?;
            let colours: Vec<[u8; 3]> = points.iter().map(|p| depth_colour(radius_mm - norm(*p), max_mm)).collect();
            view.points_mm(entity::CLOUD, points, Some(&colours))?;
        }
        if let Some(force) = result.force {
            if pictured {
                view.pressure(entity::PRESSURE, &force.pressure)?;
            }
            let f = force.wrench.force_n;
            for (name, value) in
                entity::FORCE_N.iter().zip(f).chain(entity::TORQUE_NMM.iter().zip(force.wrench.torque_nmm))
            {
                view.scalar(name, value)?;
            }
            if points.is_empty() {
                if self.arrow_shown {
                    view.clear(entity::FORCE_ARROW)?;
                    self.arrow_shown = false;
                }
            } else {
                let n = points.len() as f32;
                let centroid = points.iter().fold([0f32; 3], |c, p| std::array::from_fn(|i| c[i] + p[i] / n));
                view.arrow_mm(entity::FORCE_ARROW, centroid, f.map(|v| v as f32 * FORCE_ARROW_MM_PER_N))?;
                self.arrow_shown = true;
            }
        }
        self.recent.push_back(result.arrived);
        while self.recent.front().is_some_and(|&t| result.arrived.saturating_duration_since(t) > Duration::from_secs(1))
        {
            self.recent.pop_front();
        }
        // Frames over the span they cover, once there are two; a single frame has no rate.
        if let (Some(first), true) = (self.recent.front(), self.recent.len() > 1) {
            let span_s = result.arrived.saturating_duration_since(*first).as_secs_f64();
            if span_s > 0.0 {
                view.scalar(entity::FPS, (self.recent.len() - 1) as f64 / span_s)?;
            }
        }
        view.scalar(entity::LATENCY_MS, result.arrived.elapsed().as_secs_f64() * 1e3)?;
        view.scalar(entity::NETWORK_RAN, f64::from(u8::from(result.network_ran)))?;
        view.scalar(entity::CONTACT_PIXELS, result.contact_pixels as f64)?;
        view.scalar(entity::MAX_DEPTH_MM, f64::from(depth.max_mm()))
    }
}

fn norm(p: [f32; 3]) -> f32 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
}

impl Sink for ViewSink {
    fn frame(&mut self, predictor: &Predictor, result: &FrameResult) -> Result<(), SinkError> {
        Ok(self.log(predictor, result)?)
    }
}
