//! A simulated capture session (`dataset generate --unit N --session DIR`): what a lab would
//! bring from its rig, made by a simulated unit, so that calibration, labelling, training and
//! evaluation can run on it exactly as on a real session.
//!
//! ```text
//! DIR/captures.csv          frame,split,trial,a_deg,b_deg,c_deg,z_mm (written last)
//! DIR/frames/NNNNNN.png     the camera's full frame (.jpg for a camera that streams JPEG)
//! DIR/reference.png         a frame with nothing touching the sensor (or .jpg)
//! DIR/sawtooth.png          the unit's saw-tooth calibration frame (or .jpg)
//! DIR/.simulation/          the simulation's own files, which a real session does not have:
//!                           generator.json (settings), rows/ (progress: each finished row
//!                           and its frame's SHA-256), truth.json (the
//!                           unit's true sensor description, to measure a calibration against),
//!                           rig.json (the rig's errors, `RigOffsets`: the frames obey them,
//!                           the log does not)
//! ```
//!
//! Poses and trials are drawn exactly as `generate` draws them for the same seed, so the
//! session's ground truth, labelled with the unit's true sensor, is the generator's dataset.
//! The camera is a [`SessionCamera`]: the project's renderer ([`RendererCamera`]) or another
//! image model (the `gelcam` crate's), filming the same scenes.

use std::path::PathBuf;
use std::time::Instant;

use std::collections::BTreeMap;

use anyhow::{Context, Result};
use formats::dataset::{GeneratorParams, RigPose, sample_name};
use formats::fs::{write_atomic, write_atomic_unsynced};
use formats::session::{CAPTURES_CSV, Capture, CaptureLog};
use formats::{SplitMix64, write_json};
use rayon::prelude::*;
use sensor::Sensor;
use sensor::frame::{encode_jpeg_rgb, encode_png_rgb};
use serde::{Deserialize, Serialize};

use crate::calibration::sawtooth::SawToothShot;
use crate::generate::{build_scene_in, draw_sample, noise_seed};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::render::{PixelGrid, Renderer};
use crate::resumable;
use crate::rig::RigOffsets;
use crate::touch::first_touch_mm;
use crate::unit::SensorUnit;

/// The simulation's own folder inside a session.
pub const SIMULATION_DIR: &str = ".simulation";

/// `.simulation/generator.json`: what the session is made of.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionSettings {
    pub params: GeneratorParams,
    /// The camera's own description ([`SessionCamera::describe`]).
    pub camera: serde_json::Value,
    /// The rig's errors, which the frames obey and the log does not (none: the log is true).
    #[serde(default, skip_serializing_if = "RigOffsets::is_zero")]
    pub rig: RigOffsets,
    /// Frames pressed in z sweeps rather than one drawn z each (absent: drawn).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sweep: Option<Sweep>,
}

/// A rig's z sweep, as a lab presses a shape: the trial, tilts and B drawn as a sample's, then
/// `frames` frames from `lead_mm` above the logged first touch (the log's, not the truth's:
/// the rig's zero is what the lab saw) down in steps of `step_mm`, dwelling at the z range's
/// end if they reach it. The frames before the true
/// touch are untouched; where the image first changes tells the rig's z zero
/// (`dataset::register`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sweep {
    pub frames: u32,
    pub step_mm: f32,
    pub lead_mm: f32,
}

impl Sweep {
    /// Starting this far above the logged touch (mm) leaves a few untouched frames before a true
    /// touch up to 0.3 mm (a z zero) and as much again (the mount's offsets) earlier.
    pub const DEFAULT_LEAD_MM: f32 = 1.0;

    /// The logged z travel of a sweep's frame `j`, given where the log puts first touch.
    pub fn z_mm(&self, first_touch_mm: f32, j: u32) -> f32 {
        first_touch_mm - self.lead_mm + j as f32 * self.step_mm
    }
}

/// The camera a simulated session is filmed with: the project's renderer
/// ([`RendererCamera`]) or another image model written apart from it.
pub trait SessionCamera: Sync {
    /// The true geometry the frames are drawn with (written as `.simulation/truth.json`).
    fn sensor(&self) -> &Sensor;
    /// What the session's settings record of the camera: a resumed session must match it.
    fn describe(&self) -> serde_json::Value;
    /// The camera's full frame for a rigid depth map on the sensor's crop, as its stream
    /// delivers it: the file extension and the bytes.
    fn frame(&self, crop_depth_mm: &[f32], noise_seed: u64) -> (&'static str, Vec<u8>);
    /// The frame with nothing touching the sensor.
    fn reference(&self, noise_seed: u64) -> (&'static str, Vec<u8>);
    /// The frame of the saw-tooth indicator pressed across the sensor, for `dataset calibrate`.
    fn sawtooth(&self) -> (&'static str, Vec<u8>);
}

/// A simulated unit filmed through the project's renderer; frames as PNG, or as JPEG of the
/// given quality.
pub struct RendererCamera<'a> {
    unit: &'a SensorUnit,
    renderer: Renderer,
    jpeg_quality: Option<u8>,
}

impl<'a> RendererCamera<'a> {
    pub fn new(unit: &'a SensorUnit, jpeg_quality: Option<u8>) -> Self {
        RendererCamera { unit, renderer: Renderer::new(unit, PixelGrid::frame(&unit.sensor, 1)), jpeg_quality }
    }

    fn encode(&self, img: &image::RgbImage) -> (&'static str, Vec<u8>) {
        match self.jpeg_quality {
            Some(q) => ("jpg", encode_jpeg_rgb(img, q)),
            None => ("png", encode_png_rgb(img)),
        }
    }
}

impl SessionCamera for RendererCamera<'_> {
    fn sensor(&self) -> &Sensor {
        &self.unit.sensor
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "unit": self.unit, "jpeg_quality": self.jpeg_quality })
    }

    fn frame(&self, crop_depth_mm: &[f32], noise_seed: u64) -> (&'static str, Vec<u8>) {
        let sensor = &self.unit.sensor;
        let (x0, y0) = sensor.crop_origin_px();
        let (n, fw) = (sensor.crop_size_px as usize, sensor.frame_width_px as usize);
        // The crop's depth in its place in the camera's frame; nothing is pressed outside it.
        let mut frame_depth = vec![0f32; self.renderer.grid().len()];
        for (y, row) in crop_depth_mm.chunks_exact(n).enumerate() {
            let start = (y0 as usize + y) * fw + x0 as usize;
            frame_depth[start..start + n].copy_from_slice(row);
        }
        self.encode(&self.renderer.render(&frame_depth, Some(noise_seed)))
    }

    fn reference(&self, noise_seed: u64) -> (&'static str, Vec<u8>) {
        let img = self.renderer.render(&vec![0f32; self.renderer.grid().len()], Some(noise_seed));
        ("png", encode_png_rgb(&img))
    }

    fn sawtooth(&self) -> (&'static str, Vec<u8>) {
        let shot = SawToothShot { seed: self.unit.seed.unwrap_or(0), ..Default::default() };
        ("png", encode_png_rgb(&shot.render(self.unit)))
    }
}

/// `.simulation/rows/NNNNNN.json`: a finished frame's row, and the SHA-256 of the frame file as
/// written, so that a resumed session remakes a frame changed since.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct SimulatedRow {
    capture: Capture,
    frame_sha256: String,
}

/// A simulated session to write (or resume).
pub struct SessionWriter<'a> {
    pub out: PathBuf,
    pub kit: &'a crate::Kit,
    pub camera: &'a dyn SessionCamera,
    pub params: GeneratorParams,
    /// The rig's errors: the frames are filmed at the true poses, the log keeps the drawn ones.
    pub rig: RigOffsets,
    /// z sweeps instead of one drawn z a frame.
    pub sweep: Option<Sweep>,
}

/// A sweep's trial, its tilts and B, and its logged first touch (mm of travel), by sweep.
type SweepPlan<'k> = BTreeMap<u32, (&'k crate::kit::Trial, RigPose, f32)>;

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
        let settings = SessionSettings {
            params: self.params.clone(),
            camera: self.camera.describe(),
            rig: self.rig.clone(),
            sweep: self.sweep,
        };
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
        let sensor = self.camera.sensor();
        write_json(&sim.join("truth.json"), sensor)?;
        write_json(&sim.join("rig.json"), &self.rig)?;
        // Every frame of one camera has the same extension; an empty depth map's frame tells it.
        let (ext, _) = self.camera.frame(&vec![0f32; sensor.crop_len()], 0);
        let (out, rows) = (&self.out, sim.join("rows"));
        let mut done = resumable::finished(
            "frames",
            0..self.params.count,
            |id| rows.join(format!("{}.json", sample_name(id))),
            |r: &SimulatedRow| vec![out.join(&r.capture.frame)],
            |id, r: &SimulatedRow| r.capture.frame == format!("frames/{}.{ext}", sample_name(id)),
        )?;
        // A frame edited or replaced since the earlier run is made again.
        let changed = resumable::drop_changed(&mut done, |_, r: &SimulatedRow| {
            std::fs::read(out.join(&r.capture.frame)).is_ok_and(|b| formats::fs::sha256_hex(&b) == r.frame_sha256)
        });
        if !changed.is_empty() {
            eprintln!("{} frames changed since the earlier run: made again", changed.len());
        }
        let todo: Vec<u32> = (0..self.params.count).filter(|id| !done.contains_key(id)).collect();
        let rays = RayBundle::new(sensor);
        let sweeps = self.plan_sweeps(&todo, &rays)?;
        let made = resumable::make_all(&todo, "simulating frames", |id| {
            let (trial, pose) = match self.sweep {
                None => draw_sample(self.kit, &self.params, id),
                Some(sweep) => {
                    let (k, j) = (id / sweep.frames, id % sweep.frames);
                    let (trial, pose, touch) = sweeps[&k];
                    let z_travel_mm = sweep.z_mm(touch, j).min(self.params.z_travel_mm[1]);
                    (trial, RigPose { z_travel_mm, ..pose })
                }
            };
            // Filmed where the rig truly was; logged where it says it was.
            let truth = self.rig.true_pose(trial.split, trial.number, pose);
            let scene = build_scene_in(self.kit, trial, truth, self.rig.mount())?;
            let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
            let (depth, _) = caster.depth_map(sensor, &rays);
            let (_, bytes) = self.camera.frame(&depth.depth_mm, noise_seed(&self.params, id));
            let frame = format!("frames/{}.{ext}", sample_name(id));
            write_atomic_unsynced(&self.out.join(&frame), &bytes)?;
            let capture = Capture {
                line: 0,
                frame,
                split: trial.split,
                trial: trial.number,
                pose,
                extra: Default::default(),
                measured: None,
            };
            let row = SimulatedRow { capture, frame_sha256: formats::fs::sha256_hex(&bytes) };
            write_atomic_unsynced(&rows.join(format!("{}.json", sample_name(id))), &serde_json::to_vec_pretty(&row)?)?;
            Ok((id, row))
        })?;
        let made_count = made.len();
        let mut all = done;
        all.extend(made);
        let captures: Vec<Capture> =
            all.into_values().enumerate().map(|(k, r)| Capture { line: k + 2, ..r.capture }).collect();
        let (ext, reference) = self.camera.reference(SplitMix64::new(self.params.seed).next_u64());
        write_atomic(&self.out.join(format!("reference.{ext}")), &reference)?;
        let (ext, bytes) = self.camera.sawtooth();
        let sawtooth = self.out.join(format!("sawtooth.{ext}"));
        if !sawtooth.is_file() {
            write_atomic(&sawtooth, &bytes)?;
        }
        write_atomic(&self.out.join(CAPTURES_CSV), CaptureLog::to_csv(&captures).as_bytes())?;
        Ok(SessionReport { frames: captures.len(), made: made_count, seconds: start.elapsed().as_secs_f64() })
    }

    /// The sweeps the frames `ids` belong to: each drawn as sample `k` is, its first touch found
    /// at the logged mount (where the lab's rig believes the sensor is).
    fn plan_sweeps<'k>(&'k self, ids: &[u32], rays: &RayBundle) -> Result<SweepPlan<'k>> {
        let Some(sweep) = self.sweep else { return Ok(BTreeMap::new()) };
        let mut ks: Vec<u32> = ids.iter().map(|id| id / sweep.frames).collect();
        ks.dedup();
        ks.par_iter()
            .map(|&k| {
                let (trial, pose) = draw_sample(self.kit, &self.params, k);
                let touch = first_touch_mm(self.kit, trial, pose, self.camera.sensor(), rays)
                    .with_context(|| format!("sweep {k} (trial {} {})", trial.split, trial.number))?;
                Ok((k, (trial, RigPose { z_travel_mm: 0.0, ..pose }, touch)))
            })
            .collect()
    }
}
