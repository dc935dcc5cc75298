//! The contact model: the closed forms it must meet (Hertz, Boussinesq) and what it costs on the
//! kit's scenes, each beside the same figure on a grid of half the spacing.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use dataset::generate::{build_scene, draw_sample};
use dataset::mechanics::{GridConfig, Material, force_label, solve};
use dataset::{Kit, RayBundle, RayCaster, Skipping};
use formats::dataset::GeneratorParams;
use formats::stats::Summary;
use glam::DVec3;
use sensor::Sensor;

#[derive(clap::Args)]
pub struct Args {
    /// The DenseTact kit folder, or `procedural` for the embedded kit (the quickstart's).
    #[arg(long, default_value = "../shared/densetact-kit")]
    kit: PathBuf,
    /// Scenes drawn as `dataset generate` draws them (its default travel and angles).
    #[arg(long, default_value_t = 200)]
    samples: u32,
    /// Skip the halved grid on the kit's scenes (for profiling the default alone).
    #[arg(long)]
    no_halved: bool,
    /// A bundle to read `--data`'s frames with: its force output against the contact solved on
    /// its predicted depth, both against the labels.
    #[arg(long, requires = "data")]
    bundle: Option<PathBuf>,
    /// The dataset (with force labels) whose frames `--bundle` reads.
    #[arg(long, requires = "bundle")]
    data: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    if let (Some(bundle), Some(data)) = (&args.bundle, &args.data) {
        return from_depth(bundle, data);
    }
    let material = Material::PAPER;
    let e_star = material.effective_modulus_mpa();
    println!(
        "elastomer: E = {} MPa, nu = {}, E* = {e_star:.4} MPa; dome R = 25 mm",
        material.youngs_modulus_mpa, material.poisson_ratio
    );
    println!();
    println!("| case | closed form (N) | model (N) | error | halved grid (N) | change |");
    println!("|---|---:|---:|---:|---:|---:|");
    const R: f64 = 25.0;
    let grids = [GridConfig::default(), GridConfig::default().halved()];
    for (r, d) in [(4.0, 0.1), (6.0, 0.3), (10.0, 0.5), (10.0, 1.0)] {
        let centre = DVec3::new(0.0, 0.0, R + r - d);
        let f = move |u: DVec3| {
            let b = u.dot(centre);
            let disc = b * b - centre.length_squared() + r * r;
            if disc < 0.0 { f64::NEG_INFINITY } else { R - (b - disc.sqrt()) }
        };
        let r_eff = r * R / (r + R);
        let known = 4.0 / 3.0 * e_star * r_eff.sqrt() * f64::powf(d, 1.5);
        row(&format!("Hertz: sphere r {r} mm, {d} mm deep"), known, &grids, &f, 1.5 * (2.0 * r_eff * d).sqrt())?;
    }
    for (a, d) in [(2.0, 0.2), (4.0, 0.5), (6.0, 0.5)] {
        let f = move |u: DVec3| if R * u.z.clamp(-1.0, 1.0).acos() <= a { d } else { -1.0 };
        row(&format!("Boussinesq: flat punch a {a} mm, {d} mm deep"), 2.0 * a * e_star * d, &grids, &f, a + 1.0)?;
    }

    // The kit's scenes as the generator draws them.
    let sensor = Sensor::default();
    let kit = if args.kit.as_os_str() == "procedural" {
        Kit::procedural(sensor.radius_mm as f32)
    } else {
        Kit::load_dir(&args.kit).with_context(|| format!("loading {}", args.kit.display()))?
    };
    let rays = RayBundle::new(&sensor);
    let dome = rays.dome(&sensor);
    let params = GeneratorParams::new(1, args.samples, &kit.source);
    let (mut ms, mut ms_fine, mut forces, mut changes, mut nodes, mut steps) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    let mut without = 0;
    for id in 0..args.samples {
        let (trial, pose) = draw_sample(&kit, &params, id);
        let scene = build_scene(&kit, trial, pose)?;
        let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
        let (depth, _) = caster.depth_map(&sensor, &rays);
        let t = Instant::now();
        let label = force_label(&dome, &depth, &material, &grids[0])?;
        let took = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let fine = if args.no_halved { None } else { Some(force_label(&dome, &depth, &material, &grids[1])?) };
        let took_fine = t.elapsed().as_secs_f64() * 1e3;
        let force = label.contact.total_normal_force_n();
        if force == 0.0 {
            without += 1;
            continue;
        }
        ms.push(took);
        ms_fine.push(took_fine);
        forces.push(force);
        if let Some(fine) = fine {
            changes.push((fine.contact.total_normal_force_n() / force - 1.0).abs() * 100.0);
        }
        nodes.push(
            label.contact.patches.iter().map(|p| p.pressure_kpa.iter().filter(|&&k| k > 0.0).count()).sum::<usize>()
                as f64,
        );
        steps.push(label.contact.steps as f64);
    }
    let show = |s: Summary| format!("{:.3} [{:.3}, {:.3}], max {:.3}", s.median, s.q1, s.q3, s.max);
    println!();
    println!(
        "{} scenes of {} (z travel and B as `dataset generate` draws them), {without} without contact; median [quartiles], max:",
        args.samples, kit.source
    );
    println!("- total normal force (N): {}", show(Summary::of(forces)));
    println!("- nodes in contact: {}; pivoting steps: {}", show(Summary::of(nodes)), show(Summary::of(steps)));
    println!("- force labels, ms per scene (one thread): {}", show(Summary::of(ms)));
    if !args.no_halved {
        println!("- on the halved grid, ms per scene: {}", show(Summary::of(ms_fine)));
        println!("- force change on the halved grid (%): {}", show(Summary::of(changes)));
    }
    Ok(())
}

/// One closed-form case on both grids.
fn row(
    name: &str,
    known: f64,
    grids: &[GridConfig; 2],
    f: &(impl Fn(DVec3) -> f64 + Sync),
    reach_mm: f64,
) -> Result<()> {
    const R: f64 = 25.0;
    let steps = (reach_mm / 0.05) as i64;
    let dirs: Vec<DVec3> = (-steps..=steps)
        .flat_map(|j| (-steps..=steps).map(move |i| DVec3::new(i as f64 * 0.05, j as f64 * 0.05, R).normalize()))
        .filter(|&d| f(d) > 0.0)
        .collect();
    let got: Vec<f64> = grids
        .iter()
        .map(|g| solve(R, &Material::PAPER, g, std::slice::from_ref(&dirs), f).map(|c| c.total_normal_force_n()))
        .collect::<Result<_, _>>()?;
    println!(
        "| {name} | {known:.4} | {:.4} | {:+.2} % | {:.4} | {:+.2} % |",
        got[0],
        (got[0] / known - 1.0) * 100.0,
        got[1],
        (got[1] / got[0] - 1.0) * 100.0
    );
    Ok(())
}

/// A bundle's routes to force on `data`'s test frames, in one run: the network's pressure
/// output, the contact solved on the predicted depth with the elastomer fitted to the train
/// split's labels (the bundle's own record, or fitted here for an older bundle), and the
/// network's force head.
fn from_depth(bundle: &std::path::Path, data: &std::path::Path) -> Result<()> {
    use formats::Split;
    use formats::dataset::Manifest;
    let mut predictor = infer::Predictor::load(bundle, &model::backend::default_device())?;
    let manifest = Manifest::load(data)?;
    let elastomer = match predictor.file.elastomer.clone() {
        Some(e) => e,
        None => {
            train::elastomer::fit_elastomer(data, false)?.context("the dataset's train split has no force labels")?
        }
    };
    println!("{}", train::elastomer::report_line(&elastomer));
    predictor.set_elastomer(Some(elastomer))?;
    let has_pressure = predictor.file.model.pressure;
    let has_head = predictor.file.model.force_head.is_some();
    let mut truth_n = vec![];
    let (mut pressure, mut solved, mut head, mut ms, mut ms_off) = (vec![], vec![], vec![], vec![], vec![]);
    for s in manifest.split(Some(Split::Test)) {
        let Some(w) = s.force_label() else { continue };
        let frame = predictor.read_frame(&data.join(s.image.as_ref().context("a sample without an image")?))?;
        truth_n.push(w.force_magnitude_n());
        let errors = |f: &infer::predictor::Force| {
            [(f.wrench.force_magnitude_n() - w.force_magnitude_n()).abs(), f.wrench.force_distance_n(w)]
        };
        // As `infer` runs by default (the solve, and the head where there is one), timed.
        (predictor.solve_force, predictor.head_force) = (true, true);
        let t = Instant::now();
        let p = predictor.predict_all(&frame)?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        let p = p.force.as_ref().context("no force")?;
        if has_head {
            head.push(errors(p));
            predictor.head_force = false;
            solved.push(errors(predictor.predict_all(&frame)?.force.as_ref().context("no solved force")?));
        } else {
            solved.push(errors(p));
        }
        (predictor.solve_force, predictor.head_force) = (false, false);
        let t = Instant::now();
        let p = predictor.predict_all(&frame)?;
        ms_off.push(t.elapsed().as_secs_f64() * 1e3);
        if has_pressure {
            pressure.push(errors(p.force.as_ref().context("no force output")?));
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let m = mean(&truth_n);
    println!("{} test frames with force labels, mean |F| {m:.3} N", truth_n.len());
    println!("| force from | total force error (N) | % of mean | force vector error (N) |");
    println!("|---|---:|---:|---:|");
    for (name, v) in [
        ("the network's pressure output", &pressure),
        ("the contact solved on the predicted depth", &solved),
        ("the network's force head", &head),
    ] {
        if v.is_empty() {
            continue;
        }
        let (total, vector): (Vec<f64>, Vec<f64>) = v.iter().map(|e| (e[0], e[1])).unzip();
        println!("| {name} | {:.3} | {:.2} | {:.3} |", mean(&total), 100.0 * mean(&total) / m, mean(&vector));
    }
    for (name, v) in [("with the solve (and the head)", ms), ("without them", ms_off)] {
        let t = Summary::of(v);
        println!("predict_all {name}, ms per test frame: median {:.2} [{:.2}, {:.2}]", t.median, t.q1, t.q3);
    }
    Ok(())
}
