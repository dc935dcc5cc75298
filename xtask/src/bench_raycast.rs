//! Ray-casting benchmark: the kit scene of test trial 2 (indicator 72 with indenters 37 and 36),
//! the default sensor's 570x570 crop, our caster with and without skipping, and Open3D's
//! RaycastingScene (Embree) on the same triangles and rays, all in one run.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use dataset::generate::{Generator, build_scene};
use dataset::{Kit, RayBundle, RayCaster, Renderer, RigPose, SensorUnit, Skipping, Split};
use formats::dataset::GeneratorParams;
use sensor::Sensor;

use crate::timing::time;

#[derive(clap::Args)]
pub struct Args {
    /// The DenseTact kit folder.
    #[arg(long, default_value = "../shared/densetact-kit")]
    kit: PathBuf,
    /// Repetitions per measurement (the median is reported).
    #[arg(long, default_value_t = 15)]
    reps: usize,
    /// Python interpreter with open3d and numpy for the peer; "none" skips it.
    #[arg(long, default_value = "python3")]
    python: String,
    /// Samples for the generator's throughput.
    #[arg(long, default_value_t = 200)]
    samples: u32,
    /// Simulated unit whose images the generator renders (unit 1 streams JPEG: the slowest of
    /// the first ten).
    #[arg(long, default_value_t = 1)]
    unit: u64,
}

pub fn run(args: Args) -> Result<()> {
    let sensor = Sensor::default();
    let kit = Kit::load_dir(&args.kit).with_context(|| format!("loading {}", args.kit.display()))?;
    let trial = kit
        .trials_in(Split::Test)
        .into_iter()
        .find(|t| t.number == 2)
        .context("the kit's test index has no trial 2")?
        .clone();
    let pose = RigPose { b_axis_deg: 0.0, z_travel_mm: 1.0, ..RigPose::default() };
    let scene = build_scene(&kit, &trial, pose)?;
    let parts = scene.part_refs();
    let triangles: usize = parts.iter().map(|p| p.triangles.len()).sum();
    let rays = RayBundle::new(&sensor);
    let threads = rayon::current_num_threads();
    println!(
        "scene: {} with {:?}, pose {:?}",
        scene.description.indicator,
        scene.description.placements.iter().map(|p| &p.indenter).collect::<Vec<_>>(),
        pose
    );
    println!(
        "{} triangles, {} rays (570x570 crop, useful pixels), {threads} threads, median of {} runs",
        triangles,
        rays.len(),
        args.reps
    );

    let mut rows = Vec::new();
    let mut reference = None;
    for (name, skipping) in [("ours, no skipping", Skipping::Off), ("ours, skipping", Skipping::On)] {
        let (build_s, caster) = time(args.reps, || RayCaster::new(&parts, sensor.radius_mm, skipping));
        let (cast_s, (depth, stats)) = time(args.reps, || caster.depth_map(&sensor, &rays));
        match &reference {
            None => reference = Some(depth),
            Some(r) => {
                if *r != depth {
                    bail!("skipping changed the depth map");
                }
            }
        }
        rows.push((name.to_string(), build_s, cast_s, stats.rays_cast, stats.triangles_kept));
    }

    if args.python != "none" {
        let dir = std::env::temp_dir().join("densetact-bench");
        std::fs::create_dir_all(&dir)?;
        let file = dir.join("raycast_scene.bin");
        let reference = reference.as_ref().expect("measured above");
        let ours: Vec<f32> = rays.indices.iter().map(|&i| reference.depth_mm[i as usize]).collect();
        write_scene(&file, &parts, &rays, &ours)?;
        let (scene, reps, threads) =
            (file.to_str().context("a temporary path that is not UTF-8")?, args.reps.to_string(), threads.to_string());
        let text = crate::peer::run(&args.python, "raycast_open3d.py", &[scene, &reps, &threads])?;
        let field = |key: &str| {
            crate::peer::field(&text, key).with_context(|| format!("Open3D's peer printed no number for {key}"))
        };
        let (build_s, cast_s, max_err) = (field("build_s=")?, field("cast_s=")?, field("max_abs_depth_diff_mm=")?);
        rows.push(("Open3D RaycastingScene (Embree)".into(), build_s, cast_s, rays.len(), triangles));
        println!("Open3D vs ours (no skipping): largest depth difference {max_err:.2e} mm over the useful pixels");
    }

    println!();
    println!(
        "| caster | triangles used | rays cast | build ms | cast ms | ms per scene | Mrays/s (all rays / cast time) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for (name, build_s, cast_s, cast, kept) in &rows {
        println!(
            "| {name} | {kept} | {cast} | {:.2} | {:.2} | {:.2} | {:.1} |",
            build_s * 1e3,
            cast_s * 1e3,
            (build_s + cast_s) * 1e3,
            rays.len() as f64 / cast_s / 1e6
        );
    }

    // Whole generator, depth PNG writes included: the embedded kit and the authors' kit, depth
    // only and with a simulated unit's RGB images rendered and written too, each without and
    // with force labels (pressure PNG and wrench).
    println!();
    let kits = [("procedural kit", Kit::procedural(sensor.radius_mm as f32)), ("DenseTact kit", kit)];
    let unit = SensorUnit::from_seed(args.unit, sensor.radius_mm);
    let renderer = Renderer::for_crop(&unit);
    for (name, kit) in &kits {
        for (with_images, force_labels) in [(false, false), (false, true), (true, false), (true, true)] {
            let dir = std::env::temp_dir().join(format!("densetact-bench-gen-{}", std::process::id()));
            std::fs::remove_dir_all(&dir).ok();
            let params = GeneratorParams {
                unit: with_images.then_some(args.unit),
                force_labels,
                ..GeneratorParams::new(1, args.samples, &kit.source)
            };
            let (sensor, renderer) = if with_images { (&unit.sensor, Some(&renderer)) } else { (&sensor, None) };
            let report = Generator { out: dir.clone(), sensor, kit, params, skipping: Skipping::On, renderer }.run()?;
            std::fs::remove_dir_all(&dir).ok();
            let what = match (with_images, force_labels) {
                (false, false) => "depth PNGs",
                (false, true) => "depth PNGs + force labels",
                (true, false) => "depth PNG + camera image",
                (true, true) => "depth PNG + camera image + force labels",
            };
            println!(
                "generator ({name}, {what} written): {} samples in {:.2} s = {:.1} samples/s",
                report.generated,
                report.seconds,
                report.generated as f64 / report.seconds
            );
        }
    }
    Ok(())
}

/// Triangles, rays and our depths for the peer: little-endian u32 counts, f32 values.
fn write_scene(path: &PathBuf, parts: &[&dataset::Mesh], rays: &RayBundle, ours_mm: &[f32]) -> Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let n: usize = parts.iter().map(|p| p.triangles.len()).sum();
    out.write_all(&(n as u32).to_le_bytes())?;
    for p in parts {
        for i in 0..p.triangles.len() {
            for v in p.triangle(i) {
                for x in v.to_array() {
                    out.write_all(&x.to_le_bytes())?;
                }
            }
        }
    }
    out.write_all(&(rays.len() as u32).to_le_bytes())?;
    for d in &rays.dirs {
        for x in d.to_array() {
            out.write_all(&x.to_le_bytes())?;
        }
    }
    // Our depth per ray, to check that the peer agrees.
    for d in ours_mm {
        out.write_all(&d.to_le_bytes())?;
    }
    out.flush()?;
    Ok(())
}
