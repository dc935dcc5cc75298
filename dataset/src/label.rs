//! Ground truth for a real sensor's capture session (`dataset label`): each logged frame is
//! cropped around the calibrated optical centre and paired with the depth ray-cast for its
//! logged pose through the sensor's correspondence, in the dataset format `train` reads.
//!
//! Deterministic (nothing is drawn), parallel, resumable like the generator, and strict: rows
//! of the log that name a missing, unreadable, wrongly sized, greyscale or BGR frame, a trial
//! not in the kit's index, a pose out of range or a frame twice are named with their line, and
//! either stop the run or are skipped, counted and listed. It also reports the frames whose
//! ground truth has no contact, and among them those whose image differs from the reference
//! frame (a logging slip: the rig pressed, the log says it did not).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use formats::dataset::{
    CaptureInfo, DATASET_FORMAT_VERSION, DepthStats, LabelParams, Manifest, RigPose, SampleRecord, SplitSummary,
    sample_name,
};
use formats::fs::{write_atomic, write_atomic_unsynced};
use formats::session::{CaptureLog, reference_frame};
use formats::write_json;
use image::RgbImage;
use rayon::prelude::*;
use sensor::frame::{FrameError, check_channel_order, crop, decode, encode_png_rgb, read_crop};
use sensor::gate::GateFrame;
use sensor::{DepthMap, Sensor};
use serde::{Deserialize, Serialize};

use crate::generate::{build_scene, build_scene_in, write_force_label};
use crate::kit::{Kit, Split, Trial};
use crate::mechanics::{Dome, Material};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::register::{self, Registration};
use crate::resumable;
use crate::rig::RigOffsets;
use crate::touch::{Z_ZERO_COLUMN, ZFrom, ZReading, first_touch_mm};

/// What a bad row of the log does to the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum OnBadRow {
    /// Stop at the first, naming its line and the problem.
    Stop,
    /// Leave it out; the report counts and lists them.
    Skip,
}

/// A labelled contact shallower than this (mm) may not show in the image at all (measured on
/// simulated sweeps: the change rises out of the noise about 0.07 to 0.1 mm past first touch):
/// the slip check's gate is fitted without such frames.
const VISIBLE_DEPTH_MM: f32 = 0.15;

/// Tilts beyond this (degrees) would turn the indicator's base towards the sensor.
pub const MAX_TILT_DEG: f32 = 90.0;
pub use crate::touch::MIN_Z_TRAVEL_MM;

/// A labelling job.
pub struct Labeller<'a> {
    pub session: PathBuf,
    pub out: PathBuf,
    pub sensor: &'a Sensor,
    pub kit: &'a Kit,
    pub on_bad_row: OnBadRow,
    /// What the log's z measures (default: travel from the seated pose).
    pub z: ZReading,
    /// The elastomer whose contact model gives each sample's force labels (pressure map and
    /// wrench); `None`: depth labels only.
    pub force: Option<Material>,
    /// Label only this share of the rows (`--shard K/N`: rows whose 0-based position in the log
    /// is K modulo N); `None`: all.
    pub shard: Option<formats::Shard>,
    /// Whether the rig's offsets estimated from the log's z sweeps are applied to the labels
    /// (`--register`); without it they are estimated and reported only.
    pub register: bool,
}

/// A labelling as `dataset label` (or the Python package's `label_session`) asks for it, by
/// names and numbers: opened and checked here, then run.
pub struct LabelRequest {
    /// The session folder (made absolute here).
    pub session: PathBuf,
    /// `procedural` or the kit's folder ([`Kit::open`]).
    pub kit: String,
    pub kit_scale: f32,
    pub sensor: Sensor,
    pub out: PathBuf,
    pub on_bad_row: OnBadRow,
    pub z: ZReading,
    pub force: Option<Material>,
    pub shard: Option<formats::Shard>,
    /// See [`Labeller::register`].
    pub register: bool,
    /// Whether errors name the command line's flags (`--kit`) or the arguments' plain names.
    pub flags: bool,
}

impl LabelRequest {
    pub fn run(&self) -> Result<LabelReport> {
        let name = |flag: &str| if self.flags { format!("--{}", flag.replace('_', "-")) } else { flag.to_string() };
        if let Some(material) = &self.force {
            material
                .validate()
                .with_context(|| format!("{} / {}", name("youngs_modulus_mpa"), name("poisson_ratio")))?;
        }
        let kit = Kit::open(&self.kit, self.kit_scale, self.sensor.radius_mm as f32, &name("kit"))?;
        Labeller {
            session: crate::kit::absolute_dir(&self.session, &name("session"))?,
            out: self.out.clone(),
            sensor: &self.sensor,
            kit: &kit,
            on_bad_row: self.on_bad_row,
            z: self.z,
            force: self.force,
            shard: self.shard,
            register: self.register,
        }
        .run()
    }
}

/// What a finished labelling reports.
pub struct LabelReport {
    pub manifest: Manifest,
    pub labelled: usize,
    pub resumed: usize,
    /// Lines of rows an earlier run labelled that changed since (the row, its line or its
    /// frame's bytes), labelled again.
    pub relabelled: Vec<usize>,
    pub seconds: f64,
    /// Rows left out, each `captures.csv: line N: problem`.
    pub skipped: Vec<String>,
    /// Frames whose ground truth has no contact (`line`, frame).
    pub no_contact: Vec<(usize, String)>,
    /// Of those, frames whose image differs from the reference frame (`line`, frame, pixels).
    pub slips: Vec<(usize, String, usize)>,
    /// How the log's z was read.
    pub z: ZReading,
    /// The rig's offsets seen in the log's z sweeps (`None`: the log has none), and whether
    /// they were applied.
    pub registration: Option<Registration>,
    pub registered: bool,
}

/// One row ready to label: its id in the dataset, the trial and the row.
struct Job<'k> {
    id: u32,
    trial: &'k Trial,
    capture: formats::session::Capture,
    /// Its machine zero, for a log in machine coordinates.
    zero_mm: Option<f32>,
}

impl Labeller<'_> {
    /// Labels every row not labelled yet, then writes the manifest.
    pub fn run(&self) -> Result<LabelReport> {
        let start = Instant::now();
        let log = CaptureLog::read(&self.session)?;
        let mut skipped: Vec<(usize, String)> = Vec::new();
        let mut refuse = |line: usize, e: String| -> Result<()> {
            match self.on_bad_row {
                OnBadRow::Stop => bail!("{e} (use --on-bad-row skip to leave such rows out)"),
                OnBadRow::Skip => {
                    skipped.push((line, e));
                    Ok(())
                }
            }
        };
        for e in &log.bad {
            refuse(e.line().unwrap_or(0), e.to_string())?;
        }
        let row_error = |line: usize, message: String| format!("{}: line {line}: {message}", log.path.display());
        if self.z.from == ZFrom::Machine
            && self.z.zero_mm.is_none()
            && log.rows.iter().any(|r| !r.extra.contains_key(Z_ZERO_COLUMN))
        {
            bail!(
                "{}: --z-from machine needs the machine's z at the seated pose: --z-zero-mm, or a {Z_ZERO_COLUMN} column \
                 in every row",
                log.path.display()
            );
        }
        let mut jobs = Vec::new();
        for (id, capture) in log.rows.iter().enumerate() {
            if !formats::Shard::includes(self.shard, id as u32) {
                continue;
            }
            let trial = self.kit.trial(capture.split, capture.trial);
            let problem = match trial {
                None => Some(format!(
                    "trial {} is not in the kit's {} index ({} lists trials 1..={})",
                    capture.trial,
                    capture.split,
                    self.kit.source,
                    self.kit.trials_in(capture.split).iter().map(|t| t.number).max().unwrap_or(0)
                )),
                // A z counted otherwise is checked once read as travel (`travel`).
                Some(_) if self.z.from == ZFrom::Seated => pose_problem(capture.pose, self.sensor),
                Some(_) => pose_problem(RigPose { z_travel_mm: 0.0, ..capture.pose }, self.sensor),
            };
            let zero = match capture.extra.get(Z_ZERO_COLUMN).filter(|_| self.z.from == ZFrom::Machine) {
                Some(text) => match text.parse::<f32>() {
                    Ok(v) if v.is_finite() => Ok(Some(v)),
                    _ => Err(format!("{Z_ZERO_COLUMN} = {text:?} is not a number of millimetres")),
                },
                None => Ok(self.z.zero_mm),
            };
            match (problem, trial, zero) {
                (Some(p), _, _) => refuse(capture.line, row_error(capture.line, p))?,
                (None, _, Err(p)) => refuse(capture.line, row_error(capture.line, p))?,
                (None, Some(trial), Ok(zero_mm)) => {
                    jobs.push(Job { id: id as u32, trial, capture: capture.clone(), zero_mm })
                }
                (None, None, _) => unreachable!("a missing trial is a problem"),
            }
        }
        let reference_path = reference_frame(&self.session).with_context(|| {
            format!(
                "{}: the session has no reference.png or reference.jpg (a frame with nothing touching the sensor)",
                self.session.display()
            )
        })?;
        let reference = read_crop(&reference_path, self.sensor)?;
        // From the whole log whatever the shard, so that every share applies the same offsets.
        // Registration reads z as travel from the seated pose; a log counted otherwise would
        // have its convention taken for the rig's zero.
        let registration = if !self.z.is_seated() {
            if self.register {
                bail!(
                    "{}: --register reads the log's z as travel from the seated pose (--z-from seated), and this log is \
                     read {:?}",
                    log.path.display(),
                    self.z.from
                );
            }
            None
        } else if let Some(found) = register::register(&self.session, self.kit, self.sensor, &log.rows, &reference)? {
            Some(found)
        } else if self.register {
            bail!(
                "{}: --register needs z sweeps in the log (rows of one trial, tilts and B at {} or more z), and it \
                 has none",
                log.path.display(),
                register::MIN_SWEEP_FRAMES
            );
        } else {
            None
        };
        let applied = registration.as_ref().filter(|_| self.register);
        let params = LabelParams {
            session: self.session.display().to_string(),
            kit: self.kit.source.clone(),
            rows: log.rows.len() as u32,
        };
        // The log may grow (or change) between runs: what the folder is fixed to is the session,
        // the kit and the sensor, and each row is checked by its digest.
        let source = LabelSource {
            session: params.session.clone(),
            kit: params.kit.clone(),
            z: self.z,
            force: self.force,
            shard: self.shard,
        };
        let file = LabelFile {
            format_version: DATASET_FORMAT_VERSION,
            sensor: self.sensor.clone(),
            params: source,
            registration: applied.cloned(),
        };
        let kit = std::path::Path::new(&self.kit.source);
        let mut inputs = vec![self.session.as_path()];
        inputs.extend((self.kit.source != "procedural").then_some(kit));
        let _claim = resumable::prepare(
            &self.out,
            formats::output::OutputKind::Dataset,
            &inputs,
            &["samples", "depth", "images", "unit", "pressure"],
            LABEL_JSON,
            &file,
            "a labelled session",
            "--out",
        )?;
        write_atomic(&self.out.join("unit/reference.png"), &encode_png_rgb(&reference))?;

        let out = &self.out;
        let done = resumable::finished(
            "samples",
            jobs.iter().map(|j| j.id),
            |id| out.join(format!("samples/{}.json", sample_name(id))),
            |r: &SampleRecord| r.files().map(|f| out.join(f)).collect(),
            |id, r: &SampleRecord| r.id == id && r.pressure.is_some() == self.force.is_some(),
        )?;
        let by_id: BTreeMap<u32, &Job> = jobs.iter().map(|j| (j.id, j)).collect();
        // A row edited or moved, or a frame file replaced, since the earlier run: labelled again.
        let mut done = done;
        let stale = resumable::drop_changed(&mut done, |id, r: &SampleRecord| {
            let Some(recorded) = r.capture.as_ref() else { return false };
            // A frame that cannot be read now is labelled again, and named as a bad row.
            let c = &by_id[&id].capture;
            let now = std::fs::read(self.session.join(&c.frame)).ok().map(|bytes| row_digest(c, &bytes));
            recorded.line == c.line && recorded.sha256.is_some() && recorded.sha256 == now
        });
        let relabelled: Vec<usize> = stale.iter().map(|id| by_id[id].capture.line).collect();
        let resumed = done.len();
        let todo: Vec<&Job> = jobs.iter().filter(|j| !done.contains_key(&j.id)).collect();
        let rays = RayBundle::new(self.sensor);
        let mask = self.sensor.valid_mask();
        let dome = self.force.map(|_| rays.dome(self.sensor));
        let ids: Vec<u32> = (0..todo.len() as u32).collect();
        // A bad row is the row's problem; a failing write (a full disk, permissions) stops the
        // run whatever --on-bad-row says.
        let outcomes = resumable::make_all(&ids, "labelling", |k| {
            let job = todo[k as usize];
            self.label_row(job, &rays, &mask, &reference, dome.as_ref(), applied.map(|r| &r.offsets))
        })?;
        let mut records = done;
        let mut labelled = 0;
        for (job, outcome) in todo.iter().zip(outcomes) {
            match outcome {
                Ok(record) => {
                    records.insert(record.id, record);
                    labelled += 1;
                }
                Err(e) => refuse(job.capture.line, row_error(job.capture.line, format!("{e:#}")))?,
            }
        }
        // Samples of rows the log no longer has, or that are bad now, are removed: the folder
        // holds what a fresh labelling of the log as it stands writes.
        resumable::remove_others(out, &["samples", "depth", "images", "pressure"], |id| records.contains_key(&id))?;
        let samples: Vec<SampleRecord> = records.into_values().collect();
        if samples.is_empty() {
            bail!("{}: no row could be labelled", log.path.display());
        }
        let mut summary = BTreeMap::new();
        for split in [Split::Train, Split::Test] {
            summary.insert(split, SplitSummary::of(samples.iter().filter(|s| s.split == split)));
        }
        // A frame labelled untouched that differs from the reference by more than this unit's
        // noise (a gate fitted to the labelled contact frames alone, their noise taken from
        // their pixels far from contact) is a slip of the log.
        let measured: Vec<(&SampleRecord, GateFrame)> = samples
            .par_iter()
            .map(|s| -> Result<_> {
                let image = read_crop(&out.join(s.image.as_ref().expect("labelled records have images")), self.sensor)?;
                let depth_path = out.join(&s.depth);
                let depth = DepthMap::decode_png_um(&depth_path, &std::fs::read(&depth_path)?)?;
                Ok((s, GateFrame::labelled(&image, &reference, &mask, &depth)))
            })
            .collect::<Result<_>>()?;
        // Contacts too shallow to show in any image (the first frames past a sweep's touch) are
        // left out of the fit: kept open for, they would open it on noise, and every untouched
        // frame would read as a slip.
        let pressed: Vec<GateFrame> = measured
            .iter()
            .filter(|m| m.1.contact && m.0.stats.max_depth_mm >= VISIBLE_DEPTH_MM)
            .map(|m| m.1.clone())
            .collect();
        let gate = sensor::gate::fit(&pressed);
        let (mut no_contact, mut slips) = (Vec::new(), Vec::new());
        for (s, frame) in measured.iter().filter(|m| !m.1.contact) {
            let capture = s.capture.as_ref().expect("labelled records carry their row");
            no_contact.push((capture.line, capture.frame.clone()));
            if let Some(gate) = gate
                && let Some(level) = sensor::gate::GATE_LEVELS.iter().position(|&l| l == gate.grey_levels)
                && frame.changed[level] as usize >= gate.min_pixels
            {
                slips.push((capture.line, capture.frame.clone(), frame.changed[level] as usize));
            }
        }
        let manifest = Manifest {
            format_version: DATASET_FORMAT_VERSION,
            sensor: self.sensor.clone(),
            generator: None,
            labelled: Some(params),
            samples,
            summary,
        };
        write_json(&out.join("manifest.json"), &manifest)?;
        skipped.sort();
        Ok(LabelReport {
            manifest,
            labelled,
            resumed,
            relabelled,
            seconds: start.elapsed().as_secs_f64(),
            skipped: skipped.into_iter().map(|(_, e)| e).collect(),
            no_contact,
            slips,
            z: self.z,
            registered: applied.is_some(),
            registration,
        })
    }

    /// One row: its frame's crop checked and written, its depth cast and written, its record.
    /// What is wrong with the row (its frame, its scene) is the inner error; a failing write is
    /// the outer one.
    fn label_row(
        &self,
        job: &Job,
        rays: &RayBundle,
        mask: &[bool],
        reference: &RgbImage,
        dome: Option<&Dome>,
        rig: Option<&RigOffsets>,
    ) -> Result<Result<SampleRecord, anyhow::Error>> {
        let c = &job.capture;
        let frame_path = self.session.join(&c.frame);
        // Read once: the bytes that are hashed are the bytes that are labelled.
        let bytes = match std::fs::read(&frame_path) {
            Ok(bytes) => bytes,
            Err(source) => return Ok(Err(FrameError::Io { path: frame_path, source }.into())),
        };
        let digest = row_digest(c, &bytes);
        let checked = decode(&frame_path, &bytes)
            .and_then(|img| crop(&frame_path, img, self.sensor))
            .and_then(|crop| check_channel_order(&frame_path, &crop, reference, mask).map(|()| crop));
        let crop = match checked {
            Ok(crop) => crop,
            Err(e) => return Ok(Err(e.into())),
        };
        // A registered rig: the pose it truly had, in the mount it truly has.
        let pressed = |pose: RigPose| match rig {
            Some(rig) => {
                build_scene_in(self.kit, job.trial, rig.true_pose(job.trial.split, job.trial.number, pose), rig.mount())
            }
            None => build_scene(self.kit, job.trial, pose),
        };
        let scene = match self.travel(job, rays).and_then(pressed) {
            Ok(scene) => scene,
            Err(e) => return Ok(Err(e)),
        };
        let caster = RayCaster::new(&scene.part_refs(), self.sensor.radius_mm, Skipping::On);
        let (depth, cast) = caster.depth_map(self.sensor, rays);
        let name = sample_name(job.id);
        let (depth_rel, image_rel) = (format!("depth/{name}.png"), format!("images/{name}.png"));
        write_atomic_unsynced(&self.out.join(&depth_rel), &depth.to_png_um())?;
        write_atomic_unsynced(&self.out.join(&image_rel), &encode_png_rgb(&crop))?;
        let (pressure, wrench) = match (dome, &self.force) {
            (Some(dome), Some(material)) => {
                let (rel, label) = write_force_label(&self.out, &name, dome, &depth, material)?;
                (Some(rel), Some(label.wrench))
            }
            _ => (None, None),
        };
        let record = SampleRecord {
            id: job.id,
            split: job.trial.split,
            trial: job.trial.number,
            scene: scene.description,
            depth: depth_rel,
            image: Some(image_rel),
            reference: None,
            stats: DepthStats::of(&depth, mask),
            cast,
            pressure,
            wrench,
            capture: Some(CaptureInfo {
                frame: c.frame.clone(),
                line: c.line,
                extra: c.extra.clone(),
                measured_wrench: c.measured,
                sha256: Some(digest),
            }),
        };
        let json = serde_json::to_vec_pretty(&record)?;
        write_atomic_unsynced(&self.out.join(format!("samples/{name}.json")), &json)?;
        Ok(Ok(record))
    }
}

impl Labeller<'_> {
    /// The row's pose with its z as travel from the seated pose, however the log counts it.
    fn travel(&self, job: &Job, rays: &RayBundle) -> Result<RigPose> {
        let logged = job.capture.pose;
        let z_travel_mm = match self.z.from {
            ZFrom::Seated => return Ok(logged),
            ZFrom::Machine => logged.z_travel_mm - job.zero_mm.expect("checked when the rows were read"),
            ZFrom::FirstTouch => logged.z_travel_mm + first_touch_mm(self.kit, job.trial, logged, self.sensor, rays)?,
        };
        let pose = RigPose { z_travel_mm, ..logged };
        match pose_problem(pose, self.sensor) {
            Some(p) => bail!("read as {:?}: {p}", self.z.from),
            None => Ok(pose),
        }
    }
}

/// SHA-256 of a row (all but its line, which moves when rows above it are added) and its
/// frame file's bytes.
fn row_digest(c: &formats::session::Capture, frame: &[u8]) -> String {
    let row = serde_json::to_vec(&formats::session::Capture { line: 0, ..c.clone() }).expect("a row serialises");
    formats::fs::sha256_hex(&[row.as_slice(), b"\n", frame].concat())
}

/// `label.json`: the sensor and where the rows come from, fixed for the life of the folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LabelFile {
    pub format_version: u32,
    pub sensor: Sensor,
    pub params: LabelSource,
    /// The rig's offsets estimated from the log's sweeps and applied to the labels
    /// (`--register`; absent: the log's poses as they are).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub registration: Option<Registration>,
}

/// The session and the kit a labelled folder is made from (absolute paths, so that a resume
/// from another working folder is the same run). The log's rows are not fixed: rows added,
/// edited or removed since an earlier run are labelled or removed on resume.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LabelSource {
    pub session: String,
    pub kit: String,
    /// How the log's z is read (absent: from the seated pose).
    #[serde(default, skip_serializing_if = "ZReading::is_seated")]
    pub z: ZReading,
    /// The elastomer the force labels are solved with (absent: no force labels).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force: Option<Material>,
    /// The share of the log's rows this folder labels (absent: all); `dataset merge` joins
    /// the shares.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<formats::Shard>,
}

/// The parameters file of a labelled dataset.
pub const LABEL_JSON: &str = "label.json";

/// What is wrong with a logged pose, if anything.
pub fn pose_problem(pose: formats::dataset::RigPose, sensor: &Sensor) -> Option<String> {
    let tilt = |name: &str, v: f32| {
        (v.abs() > MAX_TILT_DEG)
            .then(|| format!("{name} = {v} degrees is beyond the +-{MAX_TILT_DEG} degree tilts of the rig"))
    };
    tilt("a_deg", pose.a_axis_deg).or_else(|| tilt("c_deg", pose.c_axis_deg)).or_else(|| {
        let max = sensor.max_depth_mm as f32;
        (!(MIN_Z_TRAVEL_MM..=max).contains(&pose.z_travel_mm)).then(|| {
            format!(
                "z_mm = {} is outside {MIN_Z_TRAVEL_MM}..{max} mm (deeper than the sensor's {max} mm depth range \
                 would clip every contact pixel)",
                pose.z_travel_mm
            )
        })
    })
}

/// Human-readable lines of a finished labelling.
pub fn report_lines(r: &LabelReport) -> Vec<String> {
    let mut lines = vec![
        format!(
            "{} samples ({} new, {} from an earlier run) in {:.1} s: {:.1} samples/s",
            r.manifest.samples.len(),
            r.labelled,
            r.resumed,
            r.seconds,
            r.labelled as f64 / r.seconds.max(1e-9)
        ),
        r.z.describe(),
    ];
    if r.z.is_seated() {
        lines.extend(registration_lines(r.registration.as_ref(), r.registered));
    } else {
        lines.push("rig offsets not checked: registration reads z as travel from the seated pose".into());
    }
    for (split, s) in &r.manifest.summary {
        lines.push(format!(
            "  {:5}: {:6} samples, contact {:5.1}% of useful pixels, mean contact depth {:.3} mm",
            split.name(),
            s.samples,
            100.0 * s.mean_contact_fraction,
            s.mean_contact_depth_mm
        ));
    }
    if !r.relabelled.is_empty() {
        lines.push(format!(
            "{} rows changed since the earlier run (the row, its line or its frame; lines {}): labelled again",
            r.relabelled.len(),
            list_lines(r.relabelled.iter().copied())
        ));
    }
    if !r.skipped.is_empty() {
        lines.push(format!("{} rows skipped:", r.skipped.len()));
        lines.extend(r.skipped.iter().map(|e| format!("  {e}")));
    }
    if !r.no_contact.is_empty() {
        lines.push(format!(
            "{} frames have no contact in their ground truth (z too small for their trial?): lines {}",
            r.no_contact.len(),
            list_lines(r.no_contact.iter().map(|(l, _)| *l))
        ));
    }
    // Most untouched frames "slipping" says the check cannot tell them from the labelled contact
    // frames (contacts the camera hardly shows: a broad shell pressed concentric with the dome,
    // or a log off in z), not that the log slipped that often.
    if r.slips.len() > SLIPS_LISTED.max(r.no_contact.len() / 5) {
        lines.push(format!(
            "warning: {} of the {} frames without contact in their ground truth differ from the reference as much as \
             the least visible labelled contact frame: some labelled contacts do not show in their frames (a shell \
             pressed flat, or the log off in z: see the rig offsets above), so the slip check cannot single out \
             slips (lines {})",
            r.slips.len(),
            r.no_contact.len(),
            list_lines(r.slips.iter().map(|(l, _, _)| *l))
        ));
        return lines;
    }
    for (line, frame, px) in &r.slips {
        lines.push(format!(
            "warning: line {line} ({frame}): the ground truth has no contact but {px}+ pixels differ from the \
             reference frame: a logging slip (pose or frame)?"
        ));
    }
    lines
}

/// Beyond these, offsets the labels did not apply are warned about: z (mm), x and y (mm),
/// tilts and B (degrees). 0.05 mm of z is about a third of the network's contact error.
const TOLERATED: [f32; 3] = [0.05, 0.05, 0.1];

/// The report's account of the rig's offsets seen in the log's sweeps.
fn registration_lines(reg: Option<&Registration>, applied: bool) -> Vec<String> {
    let Some(reg) = reg else {
        return vec!["rig offsets not checked: the log has no z sweeps (see --register)".into()];
    };
    let (o, sd) = (&reg.offsets, &reg.sd);
    let how =
        if applied { "applied to the labels (--register)" } else { "NOT applied (label with --register to apply)" };
    let mut lines = vec![format!(
        "rig offsets from {} z sweeps, {how}: x {:+.3} +- {:.3} mm, y {:+.3} +- {:.3} mm, tilt about x {:+.2} +- {:.2} deg, \
         about y {:+.2} +- {:.2} deg, B zero {:+.2} +- {:.2} deg (one sd)",
        reg.sweeps,
        o.x_mm,
        sd.x_mm,
        o.y_mm,
        sd.y_mm,
        o.tilt_x_deg,
        sd.tilt_x_deg,
        o.tilt_y_deg,
        sd.tilt_y_deg,
        o.b_zero_deg,
        sd.b_zero_deg
    )];
    let zeros: Vec<String> = o
        .z_zero_by_trial_mm
        .iter()
        .map(|(t, z)| format!("{t} {z:+.3} +- {:.3}", sd.z_zero_by_trial_mm.get(t).copied().unwrap_or(0.0)))
        .collect();
    lines.push(format!("  z zeros (mm, added to the log's z): {}", zeros.join(", ")));
    if !reg.unswept_trials.is_empty() {
        lines.push(format!("  trials with no sweep used (z zero as logged): {}", reg.unswept_trials.join(", ")));
    }
    for why in &reg.left_out {
        lines.push(format!("  sweep left out: {why}"));
    }
    if !applied {
        // Beyond the tolerance by more than two standard deviations: really there.
        let beyond = |v: f32, s: f32, tol: f32| v.abs() > tol + 2.0 * s;
        let mut seen = Vec::new();
        for (t, &z) in &o.z_zero_by_trial_mm {
            if beyond(z, sd.z_zero_by_trial_mm.get(t).copied().unwrap_or(0.0), TOLERATED[0]) {
                seen.push(format!("{t} z zero {z:+.3} mm"));
            }
        }
        for (name, v, s, tol) in [
            ("x", o.x_mm, sd.x_mm, TOLERATED[1]),
            ("y", o.y_mm, sd.y_mm, TOLERATED[1]),
            ("tilt about x", o.tilt_x_deg, sd.tilt_x_deg, TOLERATED[2]),
            ("tilt about y", o.tilt_y_deg, sd.tilt_y_deg, TOLERATED[2]),
            ("B zero", o.b_zero_deg, sd.b_zero_deg, TOLERATED[2]),
        ] {
            if beyond(v, s, tol) {
                seen.push(format!("{name} {v:+.3}"));
            }
        }
        if !seen.is_empty() {
            lines.push(format!(
                "warning: the frames say the log's poses are off beyond what the labels bear ({} mm of z, {} mm of x/y, \
                 {} degrees): {}; label with --register to correct them",
                TOLERATED[0],
                TOLERATED[1],
                TOLERATED[2],
                seen.join(", ")
            ));
        }
    }
    lines
}

/// Up to this many slips are listed one a line (more where a fifth of the untouched frames is).
const SLIPS_LISTED: usize = 5;

/// Line numbers for a report: the first twenty, then how many more.
fn list_lines(lines: impl ExactSizeIterator<Item = usize>) -> String {
    let n = lines.len();
    let shown: Vec<String> = lines.take(20).map(|l| l.to_string()).collect();
    if n > shown.len() { format!("{} and {} more", shown.join(", "), n - shown.len()) } else { shown.join(", ") }
}
