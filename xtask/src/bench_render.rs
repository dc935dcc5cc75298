//! Rendering benchmark: where a simulated unit's sample spends its time (ray cast, shading,
//! noise and quantisation, PNG encoding, the atomic write), one thread, median per sample;
//! then the saw-tooth frame and its calibration, with the calibration's error.

use anyhow::Result;
use dataset::calibration::{CalibrationOptions, calibrate, compare};
use dataset::generate::{build_scene, draw_sample};
use dataset::{Kit, RayBundle, RayCaster, Renderer, SawToothShot, SensorUnit, Skipping};
use formats::dataset::GeneratorParams;
use formats::stats::median;

use crate::timing::{once, time};

#[derive(clap::Args)]
pub struct Args {
    /// Samples drawn from the embedded kit (each timed once; medians reported).
    #[arg(long, default_value_t = 60)]
    samples: u32,
    /// Seed of the simulated unit.
    #[arg(long, default_value_t = 1)]
    unit: u64,
}

/// The row that times the first image model's render beside the unit's: not summed.
const COMPARISON: &str = "render, image model 1 (same depth)";

pub fn run(args: Args) -> Result<()> {
    let unit = SensorUnit::from_seed(args.unit, 25.0);
    let sensor = &unit.sensor;
    let (setup_s, renderer) = once(|| Renderer::for_crop(&unit));
    // The same unit through the first image model (the membrane follows the indenter; a sharp,
    // linear camera without JPEG): what the solved membrane, blur, tone curve and JPEG cost,
    // same run.
    let rigid = Renderer::for_crop(&unit.with_first_image_model());
    let kit = Kit::procedural(sensor.radius_mm as f32);
    let rays = RayBundle::new(sensor);
    let params = GeneratorParams { unit: Some(args.unit), ..GeneratorParams::new(1, args.samples, &kit.source) };
    let dir = tempfile_dir()?;
    let stages = [
        "scene (place the meshes)",
        "ray caster build",
        "ray cast",
        "render (solve, membrane, shade, blur, noise, tone, JPEG)",
        COMPARISON,
        "image file (PNG; a JPEG unit's stream as is)",
        "depth PNG encode",
        "image write",
    ];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); stages.len()];
    let (mut shaded, mut bytes) = (0usize, 0usize);
    for id in 0..args.samples {
        let (trial, pose) = draw_sample(&kit, &params, id);
        let (t_scene, scene) = once(|| build_scene(&kit, trial, pose));
        let scene = scene?;
        let (t_build, caster) = once(|| RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On));
        let (t_cast, (depth, _)) = once(|| caster.depth_map(sensor, &rays));
        let (t_render, capture) = once(|| renderer.capture(&depth.depth_mm, Some(id as u64)));
        let (t_rigid, _) = once(|| rigid.render(&depth.depth_mm, Some(id as u64)));
        let (t_png, (_, png)) = once(|| capture.file());
        let (t_depth_png, _) = once(|| depth.to_png_um());
        let path = dir.join(format!("{id}.png"));
        let (t_write, written) = once(|| formats::fs::write_atomic(&path, &png));
        written?;
        for (v, t) in times.iter_mut().zip([t_scene, t_build, t_cast, t_render, t_rigid, t_png, t_depth_png, t_write]) {
            v.push(t * 1e3);
        }
        shaded += depth.depth_mm.iter().filter(|&&d| d > 0.0).count();
        bytes += png.len();
    }
    std::fs::remove_dir_all(&dir).ok();
    let n = args.samples as f64;
    println!("unit {}: renderer set-up {:.1} ms (once per run)", args.unit, setup_s * 1e3);
    println!(
        "per sample, one thread, over {} samples (mean {:.0} pressed pixels, {:.0} kB image file):",
        args.samples,
        shaded as f64 / n,
        bytes as f64 / n / 1e3
    );
    let (mut total, mut total_mean) = (0.0, 0.0);
    println!("  {:50} {:>9} {:>9}", "stage", "median", "mean");
    for (name, v) in stages.iter().zip(times) {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let m = median(v);
        // The first image model's render is the comparison, not a stage of the sample.
        if *name != COMPARISON {
            (total, total_mean) = (total + m, total_mean + mean);
        }
        println!("  {name:50} {m:6.2} ms {mean:6.2} ms");
    }
    println!("  {:50} {total:6.2} ms {total_mean:6.2} ms", "sum (without the comparison)");

    // Calibration: render a saw-tooth frame, calibrate, compare with the truth.
    let shot = SawToothShot { seed: args.unit, ..Default::default() };
    let (t_frame, frame) = time(2, || shot.render(&unit));
    let (t_cal, cal) = time(2, || calibrate(&frame, &CalibrationOptions::default()));
    let cal = cal?;
    let (px, deg) = compare(&cal.sensor, &unit.sensor);
    println!(
        "saw-tooth frame (800x600, 3x3 samples per pixel) {:.0} ms; calibration {:.0} ms: rms {px:.3} px, {deg:.4} deg",
        t_frame * 1e3,
        t_cal * 1e3
    );
    Ok(())
}

fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("densetact-bench-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}
