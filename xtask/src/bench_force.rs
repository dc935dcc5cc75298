//! The contact model: the closed forms it must meet (Hertz, Boussinesq) and what it costs on the
//! kit's scenes, each beside the same figure on a grid of half the spacing.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use dataset::generate::{build_scene, draw_sample};
use dataset::mechanics::{Dome, GridConfig, Material, force_label, solve};
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
}

pub fn run(args: Args) -> Result<()> {
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
    let dome = Dome::new(&sensor, &rays);
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
