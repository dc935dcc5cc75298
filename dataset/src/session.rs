//! A simulated capture session (`dataset generate --unit N --session DIR`): what a lab would
//! bring from its rig, made by a simulated unit, so that calibration, labelling, training and
//! evaluation can run on it exactly as on a real session.
//!
//! ```text
//! DIR/captures.csv          frame,split,trial,a_deg,b_deg,c_deg,z_mm (written last)
//! DIR/frames/NNNNNN.png     the camera's full frame (or .jpg with --jpeg-quality)
//! DIR/reference.png         a frame with nothing touching the sensor
//! DIR/sawtooth.png          the unit's saw-tooth calibration frame
//! DIR/.simulation/          the simulation's own files, which a real session does not have:
//!                           generator.json (settings), rows/ (progress), truth.json (the
//!                           unit's true sensor description, to measure a calibration against)
//! ```
//!
//! Poses and trials are drawn exactly as `generate` draws them for the same seed, so the
//! session's ground truth, labelled with the unit's true sensor, is the generator's dataset.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use formats::dataset::{GeneratorParams, sample_name};
use formats::fs::{write_atomic, write_atomic_unsynced};
use formats::session::{CAPTURES_CSV, Capture, CaptureLog};
use formats::{SplitMix64, write_json};
use sensor::frame::{encode_jpeg_rgb, encode_png_rgb};
use serde::{Deserialize, Serialize};

use crate::calibration::sawtooth::SawToothShot;
use crate::generate::{build_scene, draw_sample, noise_seed};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::render::{PixelGrid, Renderer};
use crate::resumable;
use crate::unit::SensorUnit;

/// The simulation's own folder inside a session.
pub const SIMULATION_DIR: &str = ".simulation";

/// `.simulation/generator.json`: what the session is made of.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionSettings {
    pub params: GeneratorParams,
    pub unit: SensorUnit,
    /// JPEG quality of the frames; `None`: PNG.
    pub jpeg_quality: Option<u8>,
}

/// A simulated session to write (or resume).
pub struct SessionWriter<'a> {
    pub out: PathBuf,
    pub kit: &'a crate::Kit,
    pub unit: &'a SensorUnit,
    pub params: GeneratorParams,
    pub jpeg_quality: Option<u8>,
}

/// What a finished session reports.
pub struct SessionReport {
    pub frames: usize,
    pub made: usize,
    pub seconds: f64,
}

impl SessionWriter<'_> {
    pub fn run(&self) -> Result<SessionReport> {
        let start = Instant::now();
        let sim = self.out.join(SIMULATION_DIR);
        let settings =
            SessionSettings { params: self.params.clone(), unit: self.unit.clone(), jpeg_quality: self.jpeg_quality };
        let rows_dir = format!("{SIMULATION_DIR}/rows");
        let kit = std::path::Path::new(&self.kit.source);
        let inputs: Vec<&std::path::Path> = (self.kit.source != "procedural").then_some(kit).into_iter().collect();
        let _claim = resumable::prepare(
            &self.out,
            formats::output::OutputKind::Session,
            &inputs,
            &["frames", SIMULATION_DIR, &rows_dir],
            &format!("{SIMULATION_DIR}/generator.json"),
            &settings,
            "a simulated session",
            "--session",
        )?;
        write_json(&sim.join("truth.json"), &self.unit.sensor)?;
        let ext = if self.jpeg_quality.is_some() { "jpg" } else { "png" };
        let sensor = &self.unit.sensor;
        let renderer = Renderer::new(self.unit, PixelGrid::frame(sensor, 1));
        let encode = |img: &image::RgbImage| match self.jpeg_quality {
            Some(q) => encode_jpeg_rgb(img, q),
            None => encode_png_rgb(img),
        };
        let (out, rows) = (&self.out, sim.join("rows"));
        let done = resumable::finished(
            "frames",
            0..self.params.count,
            |id| rows.join(format!("{}.json", sample_name(id))),
            |c: &Capture| vec![out.join(&c.frame)],
            |id, c: &Capture| c.frame == format!("frames/{}.{ext}", sample_name(id)),
        )?;
        let todo: Vec<u32> = (0..self.params.count).filter(|id| !done.contains_key(id)).collect();
        let rays = RayBundle::new(sensor);
        let (x0, y0) = sensor.crop_origin_px();
        let (n, fw) = (sensor.crop_size_px as usize, sensor.frame_width_px as usize);
        let made = resumable::make_all(&todo, "simulating frames", |id| {
            let (trial, pose) = draw_sample(self.kit, &self.params, id);
            let scene = build_scene(self.kit, trial, pose)?;
            let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
            let (depth, _) = caster.depth_map(sensor, &rays);
            // The crop's depth in its place in the camera's frame; nothing is pressed outside it.
            let mut frame_depth = vec![0f32; renderer.grid().len()];
            for (y, row) in depth.depth_mm.chunks_exact(n).enumerate() {
                let start = (y0 as usize + y) * fw + x0 as usize;
                frame_depth[start..start + n].copy_from_slice(row);
            }
            let img = renderer.render(&frame_depth, Some(noise_seed(&self.params, id)));
            let frame = format!("frames/{}.{ext}", sample_name(id));
            write_atomic_unsynced(&self.out.join(&frame), &encode(&img))?;
            let capture =
                Capture { line: 0, frame, split: trial.split, trial: trial.number, pose, extra: Default::default() };
            write_atomic_unsynced(
                &rows.join(format!("{}.json", sample_name(id))),
                &serde_json::to_vec_pretty(&capture)?,
            )?;
            Ok((id, capture))
        })?;
        let made_count = made.len();
        let mut all = done;
        all.extend(made);
        let captures: Vec<Capture> = all.into_values().enumerate().map(|(k, c)| Capture { line: k + 2, ..c }).collect();
        let reference =
            renderer.render(&vec![0f32; renderer.grid().len()], Some(SplitMix64::new(self.params.seed).next_u64()));
        write_atomic(&self.out.join("reference.png"), &encode_png_rgb(&reference))?;
        let sawtooth = self.out.join("sawtooth.png");
        if !sawtooth.is_file() {
            let shot = SawToothShot { seed: self.unit.seed.unwrap_or(0), ..Default::default() };
            write_atomic(&sawtooth, &encode_png_rgb(&shot.render(self.unit)))?;
        }
        write_atomic(&self.out.join(CAPTURES_CSV), CaptureLog::to_csv(&captures).as_bytes())?;
        Ok(SessionReport { frames: captures.len(), made: made_count, seconds: start.elapsed().as_secs_f64() })
    }
}
