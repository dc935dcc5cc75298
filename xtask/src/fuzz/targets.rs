//! The parsers of outside files, their real files, and what a value each must hold.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result};
use dataset::generate::generate_with_unit;
use dataset::session::{RendererCamera, SessionWriter};
use dataset::{Kit, LoadOptions, Mesh, SensorUnit};
use formats::dataset::{GeneratorParams, Manifest};
use formats::session::CaptureLog;
use model::bundle::BundleFile;
use model::{DenseDepthConfig, DenseNetConfig};
use sensor::gate::ContactGate;
use sensor::{DepthMap, RadialMap, Sensor};

use super::{Check, Outcome, Shape, Target};

fn refused(e: impl std::fmt::Display) -> Outcome {
    Outcome::Refused(e.to_string())
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| path.display().to_string())
}

/// Makes the real files in `work` (a small dataset, a simulated session, a trained run and its
/// bundle) and returns every target with them.
pub fn build_targets(work: &Path, kit: Option<&Path>) -> Result<Vec<Target>> {
    let procedural = Kit::procedural(25.0);
    let unit = SensorUnit::from_seed(3, 25.0);
    let data = work.join("data");
    let params = GeneratorParams { test_fraction: 0.25, ..GeneratorParams::new(5, 12, &procedural.source) };
    let report = generate_with_unit(&data, &procedural, 3, 25.0, params)?;
    let session = work.join("session");
    let camera = RendererCamera::new(&unit, Some(90));
    let writer = SessionWriter {
        out: session.clone(),
        kit: &procedural,
        camera: &camera,
        params: GeneratorParams::new(5, 3, &procedural.source),
        rig: Default::default(),
        sweep: None,
    };
    writer.run()?;
    let run = work.join("run");
    let config = train::FitConfig { epochs: 1, batch: 4, ..train::FitConfig::new(data.clone(), [64, 64]) };
    let start = train::Start { model_config: DenseDepthConfig::new(DenseNetConfig::tiny()), weights: None };
    let fitted = train::fit(&run, &config, start, &model::backend::default_device(), false)?;
    let bundle = work.join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[&run])?;

    // Samples with the most contact give the depth maps, images and point cloud.
    let mut samples = report.manifest.samples.clone();
    samples.sort_by(|a, b| b.stats.contact_fraction.total_cmp(&a.stats.contact_fraction));
    let depth_files: Vec<Vec<u8>> = samples[..2].iter().map(|s| read(&data.join(&s.depth))).collect::<Result<_>>()?;
    let crop_frames: Vec<Vec<u8>> = samples[..2]
        .iter()
        .map(|s| read(&data.join(s.image.as_ref().expect("a unit's image"))))
        .collect::<Result<_>>()?;
    let depth = DepthMap::decode_png_um(Path::new("depth"), &depth_files[0])?;
    let cloud = infer::cloud::PointCloud::from_depth(&depth, &unit.sensor, Some(0.02));
    let small = infer::cloud::PointCloud { points_mm: cloud.points_mm.iter().step_by(97).copied().collect() };

    let mut frames: Vec<std::path::PathBuf> =
        std::fs::read_dir(session.join("frames"))?.map(|e| e.map(|e| e.path())).collect::<Result<_, _>>()?;
    frames.sort();
    let jpegs: Vec<Vec<u8>> = frames.iter().take(2).map(|p| read(p)).collect::<Result<_>>()?;
    let reference_png = read(&session.join("reference.png"))?;
    let log = read(&session.join(formats::session::CAPTURES_CSV))?;
    let log_crlf = String::from_utf8(log.clone())?.replace('\n', "\r\n").replacen("\r\n", ",note\r\n", 1);

    // A calibration's table: the ideal fisheye sampled every 10 px past the crop's corner.
    let mut tabulated = Sensor::default();
    let radius_px: Vec<f64> = (0..=42).map(|k| k as f64 * 10.0).collect();
    let theta_rad = radius_px.iter().map(|r| r / sensor::DEFAULT_FOCAL_PX_PER_RAD).collect();
    tabulated.correspondence.radial = RadialMap::Tabulated { radius_px, theta_rad };
    let json = |s: &Sensor| serde_json::to_vec_pretty(s).expect("a sensor serialises");

    let MeshFiles { stl, obj, ascii_stl } = meshes(kit)?;
    let reference = sensor::frame::crop(
        Path::new("reference"),
        sensor::frame::decode(Path::new("reference"), &reference_png)?,
        &unit.sensor,
    )?;
    let frame_seeds: Vec<Vec<u8>> = [vec![reference_png.clone()], crop_frames.clone(), jpegs.clone()].concat();
    let frame_check = frame_check(unit.sensor.clone(), reference, frame_seeds);
    Ok(vec![
        Target {
            name: "mesh-stl",
            file: "part.stl",
            shape: Shape::Binary,
            seeds: [stl, vec![ascii_stl]].concat(),
            check: Arc::new(mesh_check),
        },
        Target { name: "mesh-obj", file: "part.obj", shape: Shape::Text, seeds: obj, check: Arc::new(mesh_check) },
        Target {
            name: "point-cloud-ply",
            file: "cloud.ply",
            shape: Shape::Binary,
            seeds: vec![infer::cloud::ply_bytes(&small), infer::cloud::ply_bytes(&cloud)],
            check: Arc::new(ply_check),
        },
        Target {
            name: "sensor-json",
            file: "sensor.json",
            shape: Shape::Text,
            seeds: vec![json(&unit.sensor), json(&Sensor::default()), json(&tabulated)],
            check: Arc::new(sensor_check),
        },
        Target {
            name: "bundle-json",
            file: "bundle.json",
            shape: Shape::Text,
            seeds: vec![read(&bundle.join(model::bundle::BUNDLE_JSON))?],
            check: Arc::new(bundle_check),
        },
        Target {
            name: "bundle-folder-weights",
            file: model::bundle::WEIGHTS_SAFETENSORS,
            shape: Shape::Binary,
            seeds: vec![read(&bundle.join(model::bundle::WEIGHTS_SAFETENSORS))?],
            check: bundle_folder_check(&bundle, model::bundle::WEIGHTS_SAFETENSORS)?,
        },
        Target {
            name: "bundle-folder-reference",
            file: model::bundle::REFERENCE_PNG,
            shape: Shape::Png,
            seeds: vec![read(&bundle.join(model::bundle::REFERENCE_PNG))?],
            check: bundle_folder_check(&bundle, model::bundle::REFERENCE_PNG)?,
        },
        Target {
            name: "checkpoint-state-json",
            file: "state.json",
            shape: Shape::Text,
            seeds: vec![read(&train::checkpoint::dir(&run).join("state.json"))?],
            check: Arc::new(state_check),
        },
        Target {
            name: "dataset-manifest-json",
            file: "manifest.json",
            shape: Shape::Text,
            seeds: vec![read(&data.join("manifest.json"))?],
            check: Arc::new(manifest_check),
        },
        Target {
            name: "capture-log-csv",
            file: "captures.csv",
            shape: Shape::Text,
            seeds: vec![log, log_crlf.into_bytes()],
            check: Arc::new(log_check),
        },
        Target {
            name: "capture-log-resume",
            file: "captures.csv",
            shape: Shape::Text,
            seeds: vec![read(&session.join(formats::session::CAPTURES_CSV))?],
            check: super::resume::resume_check(work, &session, unit.sensor.clone(), Kit::procedural(25.0))?,
        },
        Target {
            name: "frame-png",
            file: "frame.png",
            shape: Shape::Png,
            seeds: [vec![reference_png], crop_frames].concat(),
            check: frame_check.clone(),
        },
        Target { name: "frame-jpeg", file: "frame.jpg", shape: Shape::Binary, seeds: jpegs, check: frame_check },
        Target {
            name: "depth-png",
            file: "depth.png",
            shape: Shape::Png,
            seeds: depth_files,
            check: Arc::new(depth_check),
        },
    ])
}

/// Real mesh files of each format.
struct MeshFiles {
    stl: Vec<Vec<u8>>,
    obj: Vec<Vec<u8>>,
    ascii_stl: Vec<u8>,
}

/// STL files (the kit's smallest indenter and indicator, or procedural parts), both as OBJ, and
/// the first as ASCII STL.
fn meshes(kit: Option<&Path>) -> Result<MeshFiles> {
    let stl: Vec<Vec<u8>> = match kit {
        Some(kit) => {
            let smallest = |dir: &str| -> Result<Vec<u8>> {
                let folder = kit.join("stl").join(dir);
                let mut files: Vec<(u64, std::path::PathBuf)> = std::fs::read_dir(&folder)
                    .with_context(|| folder.display().to_string())?
                    .map(|e| e.and_then(|e| Ok((e.metadata()?.len(), e.path()))))
                    .collect::<Result<_, _>>()?;
                files.sort();
                read(&files.first().with_context(|| format!("{}: no meshes", folder.display()))?.1)
            };
            vec![smallest("indenters")?, smallest("indicators")?]
        }
        None => {
            vec![dataset::shapes::sphere(4.0, 24).to_binary_stl(), dataset::shapes::torus(6.0, 1.5, 24).to_binary_stl()]
        }
    };
    let first = Mesh::from_soup(dataset::parse_stl(Path::new("seed.stl"), &stl[0])?);
    let second = Mesh::from_soup(dataset::parse_stl(Path::new("seed.stl"), &stl[1])?);
    let obj = vec![first.to_obj().into_bytes(), second.to_obj().into_bytes()];
    Ok(MeshFiles { stl, obj, ascii_stl: first.to_ascii_stl().into_bytes() })
}

fn mesh_check(path: &Path, bytes: &[u8]) -> Outcome {
    let mesh = match Mesh::parse(path, bytes, LoadOptions::default()) {
        Ok(m) => m,
        Err(e) => return refused(e),
    };
    if let Some(t) = mesh.triangles.iter().find(|t| t.iter().any(|&i| i as usize >= mesh.vertices.len())) {
        return Outcome::Invalid(format!("triangle {t:?} indexes past {} vertices", mesh.vertices.len()));
    }
    if !mesh.vertices.iter().all(|v| v.is_finite()) {
        return Outcome::Invalid("a vertex is not finite".into());
    }
    let (lo, hi) = mesh.bounds();
    let extent = (hi - lo).max_element();
    if !(dataset::mesh::MIN_EXTENT_MM..=dataset::mesh::MAX_EXTENT_MM).contains(&extent) {
        return Outcome::Invalid(format!("the mesh is {extent} mm across"));
    }
    Outcome::Accepted
}

fn ply_check(path: &Path, bytes: &[u8]) -> Outcome {
    match infer::cloud::parse_ply(path, bytes) {
        Err(e) => refused(e),
        Ok(c) if c.points_mm.iter().flatten().all(|v| v.is_finite()) => Outcome::Accepted,
        Ok(_) => Outcome::Invalid("a point is not finite".into()),
    }
}

fn sensor_check(path: &Path, bytes: &[u8]) -> Outcome {
    let sensor = match Sensor::from_json(path, bytes) {
        Ok(s) => s,
        Err(e) => return refused(e),
    };
    if let Err(e) = sensor.validate() {
        return Outcome::Invalid(format!("accepted but invalid: {e}"));
    }
    // A sensor that loads must be usable: its crop's angles, and for a camera of ordinary
    // size its mask (larger ones are valid but take seconds).
    let n = sensor.crop_size_px;
    let _ = (sensor.crop_theta(0, 0), sensor.crop_theta(n / 2, n / 2), sensor.crop_theta(n - 1, n - 1));
    if n <= 1024 {
        let _ = sensor.valid_count();
    }
    Outcome::Accepted
}

fn bundle_check(path: &Path, bytes: &[u8]) -> Outcome {
    match BundleFile::parse(path, bytes) {
        Err(e) => refused(e),
        Ok(b) => round_trip(&b, |bytes| BundleFile::parse(path, bytes).map_err(|e| e.to_string())),
    }
}

/// A bundle folder with its file `name` replaced by the mutated bytes, loaded: whole (the
/// bytes are the exported ones) or refused naming the file, never loaded with other bytes.
fn bundle_folder_check(bundle: &Path, name: &'static str) -> Result<Check> {
    let files: Vec<(std::ffi::OsString, Vec<u8>)> = std::fs::read_dir(bundle)?
        .map(|e| {
            let e = e?;
            Ok((e.file_name(), read(&e.path())?))
        })
        .collect::<Result<_>>()?;
    let original = read(&bundle.join(name))?;
    Ok(Arc::new(move |_path: &Path, bytes: &[u8]| {
        let tmp = match tempfile::tempdir() {
            Ok(t) => t,
            Err(e) => return Outcome::Invalid(format!("no temporary folder: {e}")),
        };
        let dir = tmp.path().join("bundle");
        let copied = std::fs::create_dir(&dir).and_then(|()| {
            files.iter().try_for_each(|(n, b)| std::fs::write(dir.join(n), if n == name { bytes } else { b }))
        });
        if let Err(e) = copied {
            return Outcome::Invalid(format!("cannot copy the bundle: {e}"));
        }
        match model::bundle::load_bundle(&dir, &model::backend::default_device()) {
            Err(e) => refused(e),
            Ok(_) if bytes == original.as_slice() => Outcome::Accepted,
            Ok(_) => Outcome::Invalid(format!("a bundle whose {name} was edited loaded")),
        }
    }))
}

fn state_check(path: &Path, bytes: &[u8]) -> Outcome {
    match train::checkpoint::parse_state(path, bytes) {
        Err(e) => refused(format!("{e:#}")),
        Ok(s) => round_trip(&s, |b| train::checkpoint::parse_state(path, b).map_err(|e| format!("{e:#}"))),
    }
}

fn manifest_check(path: &Path, bytes: &[u8]) -> Outcome {
    match Manifest::parse(path, bytes) {
        Err(e) => refused(e),
        Ok(m) => round_trip(&m, |b| Manifest::parse(path, b).map_err(|e| e.to_string())),
    }
}

/// What a tool reads it must be able to write back and read again as the same JSON (compared
/// as JSON: a NaN that a file holds as `null` is the same either way).
fn round_trip<T: serde::Serialize>(value: &T, parse: impl Fn(&[u8]) -> Result<T, String>) -> Outcome {
    let json = serde_json::to_value(value).expect("a parsed value serialises");
    match parse(&serde_json::to_vec(&json).expect("JSON serialises")) {
        Ok(back) if serde_json::to_value(&back).expect("serialises") == json => Outcome::Accepted,
        Ok(_) => Outcome::Invalid("written back, it reads differently".into()),
        Err(e) => Outcome::Invalid(format!("written back, it no longer reads: {e}")),
    }
}

fn log_check(path: &Path, bytes: &[u8]) -> Outcome {
    let log = match CaptureLog::parse(path, bytes) {
        Ok(log) => log,
        Err(e) => return refused(e),
    };
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    if let Some(e) = log.bad.iter().find(|e| !e.to_string().contains(name)) {
        return Outcome::Invalid(format!("a bad row's error does not name the file: {e}"));
    }
    let mut frames = std::collections::BTreeSet::new();
    for row in &log.rows {
        let p = row.pose;
        let finite = [p.a_axis_deg, p.b_axis_deg, p.c_axis_deg, p.z_travel_mm].iter().all(|v| v.is_finite());
        if !finite || row.frame.is_empty() || row.line < 2 || !frames.insert(row.frame.clone()) {
            return Outcome::Invalid(format!("row {row:?} is not a usable capture"));
        }
    }
    Outcome::Accepted
}

/// A frame through everything a command does with it: decode, crop, the channel-order check
/// against the unit's reference, the contact gate. A frame that decodes must be whole: the
/// start of one of the real files `seeds` (a copy cut short), or one with bytes appended beyond
/// the slack, is a failure if accepted.
fn frame_check(sensor: Sensor, reference: image::RgbImage, seeds: Vec<Vec<u8>>) -> Check {
    let mask = sensor.valid_mask();
    Arc::new(move |path: &Path, bytes: &[u8]| {
        let crop = match sensor::frame::decode(path, bytes).and_then(|img| sensor::frame::crop(path, img, &sensor)) {
            Ok(c) => c,
            Err(e) => return refused(e),
        };
        if let Some(seed) = seeds.iter().find(|s| s.len() > bytes.len() && s.starts_with(bytes)) {
            return Outcome::Invalid(format!(
                "the first {} of a {}-byte frame's bytes were accepted",
                bytes.len(),
                seed.len()
            ));
        }
        if seeds.iter().any(|s| bytes.len() > s.len() + sensor::TRAILING_SLACK_BYTES && bytes.starts_with(s)) {
            return Outcome::Invalid(format!("a frame with {} bytes appended was accepted", bytes.len()));
        }
        if crop.dimensions() != (sensor.crop_size_px, sensor.crop_size_px) {
            return Outcome::Invalid(format!("a crop of {:?}", crop.dimensions()));
        }
        if let Err(e) = sensor::frame::check_channel_order(path, &crop, &reference, &mask) {
            return refused(e);
        }
        let _ = ContactGate { grey_levels: 15.0, min_pixels: 200 }.differs(&crop, &reference, &mask);
        Outcome::Accepted
    })
}

fn depth_check(path: &Path, bytes: &[u8]) -> Outcome {
    match DepthMap::decode_png_um(path, bytes) {
        Err(e) => refused(e),
        Ok(d) if d.depth_mm.len() != (d.size_px as usize).pow(2) => Outcome::Invalid("not square".into()),
        Ok(d) if !d.depth_mm.iter().all(|v| v.is_finite() && *v >= 0.0) => Outcome::Invalid("a negative depth".into()),
        Ok(_) => Outcome::Accepted,
    }
}
