//! The dataset generator: deterministic per sample, parallel, resumable.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use sensor::{DepthMap, PressureMap, Sensor};

use formats::dataset::{
    DATASET_FORMAT_VERSION, DepthStats, GeneratorFile, GeneratorParams, LIFTED_Z_TRAVEL_MM, Manifest, SampleRecord,
    SplitSummary, depth_u8_file, sample_name,
};
use formats::fs::{write_atomic, write_atomic_unsynced};
use formats::{SplitMix64, write_json};
use sensor::frame::encode_png_rgb;

use crate::kit::{Kit, Split, Trial};
use crate::looks::random_look;
use crate::mechanics::{Dome, ForceLabel, GridConfig, Material, force_label};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::render::Renderer;
use crate::resumable;
use crate::scene::{RigPose, Scene};
use crate::unit::SensorUnit;
use formats::output::OutputKind;

/// Draws sample `id`'s trial and pose from its own random stream.
pub fn draw_sample<'k>(kit: &'k Kit, params: &GeneratorParams, id: u32) -> (&'k Trial, RigPose) {
    let mut rng = SplitMix64::for_item(params.seed, id as u64);
    let wanted = if rng.unit() < params.test_fraction as f64 { Split::Test } else { Split::Train };
    let mut trials = kit.trials_in(wanted);
    if trials.is_empty() {
        trials = kit.trials.iter().collect();
    }
    let trial = trials[rng.below(trials.len())];
    let [b0, b1] = params.b_axis_deg;
    let [z0, z1] = params.z_travel_mm;
    let mut pose = RigPose {
        b_axis_deg: rng.range(b0 as f64, b1 as f64) as f32,
        z_travel_mm: rng.range(z0 as f64, z1 as f64) as f32,
        ..RigPose::default()
    };
    // Drawn after the rest and only when asked for, so that datasets made without lifting or
    // tilts keep their samples.
    if params.lifted_fraction > 0.0 && rng.unit() < params.lifted_fraction as f64 {
        pose.z_travel_mm = LIFTED_Z_TRAVEL_MM;
    }
    if !params.a_axis_deg.is_zero() {
        pose.a_axis_deg = params.a_axis_deg.pick(rng.unit());
    }
    if !params.c_axis_deg.is_zero() {
        pose.c_axis_deg = params.c_axis_deg.pick(rng.unit());
    }
    (trial, pose)
}

/// The noise seed of sample `id`'s camera image.
pub fn noise_seed(params: &GeneratorParams, id: u32) -> u64 {
    SplitMix64::for_item(params.seed ^ 0x1a6e, id as u64).next_u64()
}

/// The seed of sample `id`'s look (`looks::random_look`) where the dataset draws one per sample.
pub fn look_seed(params: &GeneratorParams, id: u32) -> u64 {
    SplitMix64::for_item(params.seed ^ 0x100c, id as u64).next_u64()
}

/// The share of contact pixels that sit at the sensor's maximum depth (clipped) when up to
/// `probes` of the kit's trials, spread over its index, are pressed to five travels spread over
/// the z range `params` draws from: a figure to refuse or warn about travel that would clip
/// most of the contact.
pub fn clipped_fraction(kit: &Kit, params: &GeneratorParams, sensor: &Sensor, probes: usize) -> Result<f64> {
    let rays = RayBundle::new(sensor);
    let max = sensor.max_depth_mm as f32;
    let step = (kit.trials.len() / probes.max(1)).max(1);
    let (mut contact, mut clipped) = (0usize, 0usize);
    let [z0, z1] = params.z_travel_mm;
    for trial in kit.trials.iter().step_by(step).take(probes) {
        for q in [0.1, 0.3, 0.5, 0.7, 0.9] {
            let pose = RigPose { z_travel_mm: z0 + (z1 - z0) * q, ..RigPose::default() };
            let scene = build_scene(kit, trial, pose)?;
            let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
            for &d in &caster.depth_map(sensor, &rays).0.depth_mm {
                contact += (d > sensor::CONTACT_THRESHOLD_MM) as usize;
                clipped += (d >= max - 1e-4) as usize;
            }
        }
    }
    Ok(clipped as f64 / contact.max(1) as f64)
}

/// Builds a trial's scene in the given pose.
pub fn build_scene(kit: &Kit, trial: &Trial, pose: RigPose) -> Result<Scene> {
    build_scene_in(kit, trial, pose, glam::Affine3A::IDENTITY)
}

/// [`build_scene`] on a rig whose frame is `mount` in the sensor's ([`crate::rig::RigOffsets::mount`]).
pub fn build_scene_in(kit: &Kit, trial: &Trial, pose: RigPose, mount: glam::Affine3A) -> Result<Scene> {
    let indicator = &kit.indicators[trial.indicator];
    let indenters: Vec<_> = trial.indenters.iter().map(|&(j, a)| (&kit.indenters[j], a)).collect();
    Scene::assemble_in(indicator, &indenters, pose, mount)
        .with_context(|| format!("{} trial {}", trial.split.name(), trial.number))
}

/// Everything a run needs, prepared once.
pub struct Generator<'a> {
    pub out: PathBuf,
    pub sensor: &'a Sensor,
    pub kit: &'a Kit,
    pub params: GeneratorParams,
    pub skipping: Skipping,
    /// Renders each sample's camera image; its unit's geometry must be `sensor`.
    pub renderer: Option<&'a Renderer>,
}

/// Generates (or resumes) a dataset of `kit`'s scenes with the images of simulated unit
/// `unit_seed` (radius `radius_mm`), whose true geometry becomes the dataset's sensor.
pub fn generate_with_unit(
    out: &Path,
    kit: &Kit,
    unit_seed: u64,
    radius_mm: f64,
    params: GeneratorParams,
) -> Result<RunReport> {
    let unit = SensorUnit::from_seed(unit_seed, radius_mm);
    let renderer = Renderer::for_crop(&unit);
    let params = GeneratorParams { unit: Some(unit_seed), ..params };
    Generator {
        out: out.to_path_buf(),
        sensor: &unit.sensor,
        kit,
        params,
        skipping: Skipping::On,
        renderer: Some(&renderer),
    }
    .run()
}

/// What a finished run reports.
pub struct RunReport {
    pub manifest: Manifest,
    pub generated: usize,
    pub resumed: usize,
    pub seconds: f64,
}

impl Generator<'_> {
    /// Generates every missing sample, then writes the manifest. Safe to kill at any moment and
    /// run again with the same arguments.
    pub fn run(&self) -> Result<RunReport> {
        let start = Instant::now();
        let _claim = self.prepare_folder()?;
        let out = &self.out;
        let ids: Vec<u32> = formats::Shard::ids(self.params.shard, self.params.count).collect();
        let done = resumable::finished(
            "samples",
            ids.iter().copied(),
            |id| out.join(format!("samples/{}.json", sample_name(id))),
            |r: &SampleRecord| r.files().chain(&self.params.unrecorded_files(r.id)).map(|f| out.join(f)).collect(),
            |id, r: &SampleRecord| {
                r.id == id
                    && r.image.is_some() == self.renderer.is_some()
                    && r.reference.is_some() == (self.renderer.is_some() && self.params.random_looks)
                    && r.pressure.is_some() == self.params.force_labels
            },
        )?;
        let resumed = done.len();
        let todo: Vec<u32> = ids.into_iter().filter(|id| !done.contains_key(id)).collect();
        let rays = RayBundle::new(self.sensor);
        let mask = self.sensor.valid_mask();
        let dome = self.params.force_labels.then(|| rays.dome(self.sensor));
        let fresh = resumable::make_all(&todo, "generating", |id| self.make_sample(id, &rays, &mask, dome.as_ref()))?;
        let mut records = done;
        let generated = fresh.len();
        records.extend(fresh.into_iter().map(|r| (r.id, r)));
        let samples: Vec<SampleRecord> = records.into_values().collect();
        let mut summary = BTreeMap::new();
        for split in [Split::Train, Split::Test] {
            summary.insert(split, SplitSummary::of(samples.iter().filter(|s| s.split == split)));
        }
        let manifest = Manifest {
            format_version: DATASET_FORMAT_VERSION,
            sensor: self.sensor.clone(),
            generator: Some(self.params.clone()),
            labelled: None,
            samples,
            summary,
        };
        write_json(&self.out.join("manifest.json"), &manifest)?;
        Ok(RunReport { manifest, generated, resumed, seconds: start.elapsed().as_secs_f64() })
    }

    fn make_sample(&self, id: u32, rays: &RayBundle, mask: &[bool], dome: Option<&Dome>) -> Result<SampleRecord> {
        let (trial, pose) = draw_sample(self.kit, &self.params, id);
        let scene = build_scene(self.kit, trial, pose)?;
        let caster = RayCaster::new(&scene.part_refs(), self.sensor.radius_mm, self.skipping);
        let (depth, cast) = caster.depth_map(self.sensor, rays);
        let name = sample_name(id);
        let depth_rel = format!("depth/{name}.png");
        // Sample files are renamed into place without a sync each (the sync cost more than
        // the encoding); a resume checks that they are whole instead.
        write_atomic_unsynced(&self.out.join(&depth_rel), &depth.to_png_um())?;
        if self.params.depth_u8 {
            let bytes = depth.to_png_u8(self.sensor.max_depth_mm as f32);
            write_atomic_unsynced(&self.out.join(depth_u8_file(id)), &bytes)?;
        }
        let (pressure, wrench, contact) = match dome {
            Some(dome) => {
                let material = self.renderer.map_or(Material::PAPER, |r| r.unit().elastomer.material());
                let (rel, label) = write_force_label(&self.out, &name, dome, &depth, &material)?;
                (Some(rel), Some(label.wrench), Some(label.contact))
            }
            None => (None, None, None),
        };
        let (mut image, mut reference) = (None, None);
        if let Some(renderer) = self.renderer {
            let styled;
            let renderer = if self.params.random_looks {
                styled = renderer.restyled(&random_look(renderer.unit(), look_seed(&self.params, id)));
                &styled
            } else {
                renderer
            };
            // A unit that streams JPEG stores its stream's bytes, as a rig logs them.
            let seed = noise_seed(&self.params, id);
            // The image's membrane is the surface of the contact the label solved.
            let capture = renderer.capture_solved(&depth.depth_mm, contact.as_ref(), Some(seed));
            let (ext, bytes) = capture.file();
            let rel = format!("images/{name}.{ext}");
            write_atomic_unsynced(&self.out.join(&rel), &bytes)?;
            image = Some(rel);
            if self.params.random_looks {
                // The look's untouched frame as a lab would capture it: its own noise, its
                // stream's encoding.
                let untouched = renderer.capture(&vec![0.0; depth.depth_mm.len()], Some(seed ^ 0x5eed_0f2e));
                let (ext, bytes) = untouched.file();
                let rel = format!("references/{name}.{ext}");
                write_atomic_unsynced(&self.out.join(&rel), &bytes)?;
                reference = Some(rel);
            }
        }
        let record = SampleRecord {
            id,
            split: trial.split,
            trial: trial.number,
            scene: scene.description,
            depth: depth_rel,
            image,
            reference,
            stats: DepthStats::of(&depth, mask),
            cast,
            pressure,
            wrench,
            capture: None,
        };
        let json = serde_json::to_vec_pretty(&record).expect("record serialises");
        write_atomic_unsynced(&self.out.join(format!("samples/{name}.json")), &json)?;
        Ok(record)
    }

    /// Creates the folder, or checks that an existing one was made with the same parameters,
    /// and removes temporary files left by a killed run.
    fn prepare_folder(&self) -> Result<formats::output::Claim> {
        let mut subs = vec!["samples", "depth"];
        if self.params.depth_u8 {
            subs.push("depth_u8");
        }
        if self.params.force_labels {
            subs.push("pressure");
        }
        if self.renderer.is_some() {
            subs.extend(["images", "unit"]);
            if self.params.random_looks {
                subs.push("references");
            }
        }
        let file = GeneratorFile {
            format_version: DATASET_FORMAT_VERSION,
            sensor: self.sensor.clone(),
            params: self.params.clone(),
        };
        let kit = std::path::Path::new(&self.kit.source);
        let inputs: Vec<&Path> = (self.kit.source != "procedural").then_some(kit).into_iter().collect();
        let claim = resumable::prepare(
            &self.out,
            OutputKind::Dataset,
            &inputs,
            &subs,
            "generator.json",
            &file,
            "a dataset",
            "--out",
        )?;
        if let Some(renderer) = self.renderer {
            write_unit_files(&self.out.join("unit"), renderer)?;
        }
        Ok(claim)
    }
}

/// Solves the contact `depth` shows and writes its pressure map as `pressure/NAME.png` under
/// `out`; returns the file (relative to `out`) and the label (its wrench for the sample's
/// record, its contact for the image).
pub fn write_force_label(
    out: &Path,
    name: &str,
    dome: &Dome,
    depth: &DepthMap,
    material: &Material,
) -> Result<(String, ForceLabel)> {
    let mut label = force_label(dome, depth, material, &GridConfig::default())
        .with_context(|| format!("sample {name}'s contact"))?;
    let rel = format!("pressure/{name}.png");
    let map = PressureMap { size_px: depth.size_px, pressure_kpa: std::mem::take(&mut label.pressure_kpa) };
    write_atomic_unsynced(&out.join(&rel), &map.to_png())?;
    Ok((rel, label))
}

/// The unit's description, its true geometry and its no-contact image.
pub fn write_unit_files(dir: &Path, renderer: &Renderer) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))?;
    let unit: &SensorUnit = renderer.unit();
    write_json(&dir.join("unit.json"), unit)?;
    write_json(&dir.join("truth.json"), &unit.sensor)?;
    write_atomic(&dir.join("reference.png"), &encode_png_rgb(&renderer.reference_image(1)))?;
    Ok(())
}

/// Human-readable statistics of a finished run.
pub fn report_lines(report: &RunReport) -> Vec<String> {
    let m = &report.manifest;
    let share = m.generator.as_ref().and_then(|p| p.shard).map_or(String::new(), |s| format!(" (shard {s})"));
    let mut lines = vec![format!(
        "{} samples{share} ({} new, {} from an earlier run) in {:.1} s: {:.1} samples/s",
        m.samples.len(),
        report.generated,
        report.resumed,
        report.seconds,
        report.generated as f64 / report.seconds.max(1e-9)
    )];
    for (split, s) in &m.summary {
        lines.push(format!(
            "  {:5}: {:6} samples, contact {:5.1}% of useful pixels, mean contact depth {:.3} mm, max depth {:.3} mm",
            split.name(),
            s.samples,
            100.0 * s.mean_contact_fraction,
            s.mean_contact_depth_mm,
            s.max_depth_mm
        ));
    }
    let n = m.samples.len().max(1) as f64;
    let kept: f64 =
        m.samples.iter().map(|s| s.cast.triangles_kept as f64 / s.cast.triangles_total.max(1) as f64).sum::<f64>() / n;
    let cast: f64 =
        m.samples.iter().map(|s| s.cast.rays_cast as f64 / s.cast.rays_total.max(1) as f64).sum::<f64>() / n;
    lines.push(format!(
        "  skipping: {:.1}% of triangles kept, {:.1}% of rays cast (mean per sample)",
        100.0 * kept,
        100.0 * cast
    ));
    lines
}
