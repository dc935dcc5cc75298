//! `cargo xtask bench looks`: does training on random looks (`dataset generate --random-looks`)
//! make a network read cameras it never saw? One renderer unit's scenes, trained three ways with
//! the quickstart's recipe (the unit's own look; a random look per sample; the unit's own look
//! with `train fit --vary-look`'s image-space jitter), each read zero-shot by sessions filmed
//! with the independent image model (`gelcam`), which no run trains on, and by the unit's own
//! test frames.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use dataset::generate::generate_with_unit;
use dataset::label::{Labeller, OnBadRow};
use dataset::session::SessionWriter;
use dataset::{Kit, Split};
use formats::dataset::GeneratorParams;
use model::{DenseDepth, DenseDepthConfig};
use train::data::{DepthBatcher, DepthDataset};
use train::{FitConfig, OnBadData, Recipe, Start, fit, validate};

#[derive(clap::Args)]
pub struct Args {
    /// The renderer's unit whose geometry every training set keeps.
    #[arg(long, default_value_t = 7)]
    own_unit: u64,
    /// Scenes of each training set (one in ten lifted clear), the same scenes for every arm.
    #[arg(long, default_value_t = 1000)]
    samples: u32,
    /// Independent image model units whose sessions are read zero-shot, comma-separated.
    #[arg(long, default_value = "40,41,42,43,44", value_delimiter = ',')]
    gelcam_units: Vec<u64>,
    /// Scenes of each gelcam session (other scenes than the training sets': seed 1).
    #[arg(long, default_value_t = 200)]
    gelcam_samples: u32,
    /// Work folder (resumable: datasets, sessions and finished runs are reused).
    #[arg(long, default_value = "out/bench-looks")]
    out: PathBuf,
}

/// One way of training.
struct Arm {
    name: &'static str,
    random_looks: bool,
    vary_look: bool,
}

const ARMS: [Arm; 3] = [
    Arm { name: "own look", random_looks: false, vary_look: false },
    Arm { name: "random looks (generator)", random_looks: true, vary_look: false },
    Arm { name: "own look + image jitter (--vary-look)", random_looks: false, vary_look: true },
];

pub fn run(args: Args) -> Result<()> {
    let device = model::backend::default_device();
    let kit = Kit::procedural(25.0);
    let recipe = Recipe::Quickstart;
    let model_config = recipe.model_config()?;
    let params = |seed: u64, count: u32| GeneratorParams {
        lifted_fraction: 0.1,
        ..GeneratorParams::new(seed, count, &kit.source)
    };

    // The sets read: the unit's own test frames, then each gelcam unit's whole session.
    let own_dir = args.out.join(format!("own-{}-{}", args.own_unit, args.samples));
    generate_with_unit(&own_dir, &kit, args.own_unit, 25.0, params(0, args.samples))?;
    let mut sets = vec![(format!("renderer unit {} test split", args.own_unit), own_dir.clone(), Some(Split::Test))];
    for &g in &args.gelcam_units {
        let unit = gelcam::GelUnit::from_seed(g, 25.0);
        let camera = gelcam::GelSession::new(&unit);
        let dir = args.out.join(format!("gelcam-{g}-{}", args.gelcam_samples));
        let session = dir.join("session");
        SessionWriter {
            out: session.clone(),
            kit: &kit,
            camera: &camera,
            params: params(1, args.gelcam_samples),
            rig: Default::default(),
            sweep: None,
        }
        .run()?;
        // Labelled through the unit's true geometry: the figure is the look's, not a
        // calibration's (`bench foreign` measures the two together).
        let data = dir.join("data");
        Labeller {
            session,
            out: data.clone(),
            sensor: &unit.sensor,
            kit: &kit,
            on_bad_row: OnBadRow::Stop,
            z: Default::default(),
            force: None,
            shard: None,
            register: false,
        }
        .run()?;
        sets.push((format!("gelcam unit {g} (membrane {:.2} px)", unit.look.membrane_sigma_px), data, None));
    }

    let mut results = Vec::new();
    for arm in &ARMS {
        let data = if arm.random_looks {
            let dir = args.out.join(format!("random-{}-{}", args.own_unit, args.samples));
            let p = GeneratorParams { random_looks: true, ..params(0, args.samples) };
            generate_with_unit(&dir, &kit, args.own_unit, 25.0, p)?;
            dir
        } else {
            own_dir.clone()
        };
        let config = FitConfig { vary_look: arm.vary_look, ..recipe.fit_config(data) };
        let run_name = format!(
            "run-{}-{}{}{}",
            args.own_unit,
            args.samples,
            if arm.random_looks { "-random" } else { "" },
            if arm.vary_look { "-jitter" } else { "" }
        );
        println!("[{}] training ({run_name})", arm.name);
        let start = Start { model_config: model_config.clone(), weights: None };
        let fitted = fit(&args.out.join(run_name), &config, start, &device, true).context("training (run again)")?;
        let mut row = Vec::new();
        for (_, dir, split) in &sets {
            row.push(read_set(&fitted.net, &config, &model_config, dir, *split, &device)?);
        }
        results.push(row);
    }

    println!(
        "\nrenderer unit {} ({} scenes, quickstart recipe); contact L1 (mm) of each set, the zero predictor's beside it",
        args.own_unit, args.samples
    );
    let mut header = String::from("| set | images | zeros |");
    let mut rule = String::from("|---|---:|---:|");
    for arm in &ARMS {
        header += &format!(" {} |", arm.name);
        rule += "---:|";
    }
    println!("{header}\n{rule}");
    for (k, (name, _, _)) in sets.iter().enumerate() {
        let first = &results[0][k];
        let mut line = format!("| {name} | {} | {:.4} |", first.images, first.zeros_contact_l1_mm);
        for row in &results {
            line += &format!(" {:.4} |", row[k].contact_l1_mm);
        }
        println!("{line}");
    }
    let gel = |arm: usize| -> f64 {
        let row = &results[arm][1..];
        row.iter().map(|r| r.contact_l1_mm).sum::<f64>() / row.len().max(1) as f64
    };
    if sets.len() > 1 {
        println!(
            "mean over the gelcam units: {}",
            (0..ARMS.len()).map(|a| format!("{} {:.4} mm", ARMS[a].name, gel(a))).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(())
}

/// What a network reads on one set.
struct Reading {
    images: usize,
    contact_l1_mm: f64,
    zeros_contact_l1_mm: f64,
}

/// Contact L1 of `net` on `dir` (`split`, or all of it), at the network's output resolution,
/// with the zero predictor's on the same images.
fn read_set(
    net: &DenseDepth,
    config: &FitConfig,
    model_config: &DenseDepthConfig,
    dir: &Path,
    split: Option<Split>,
    device: &burn::tensor::Device,
) -> Result<Reading> {
    let mut data = DepthDataset::open(dir, split, config.input_hw)?;
    data.scale = config.scale(data.sensor.max_depth_mm);
    data.set_model(model_config)?;
    let batcher = DepthBatcher::for_data(&data);
    let eval = validate(net, &data, &batcher, 4, device, OnBadData::Stop, "read")?;
    // The zero predictor: each image's mean true depth over its contact pixels.
    let (mut sum, mut count) = (0.0, 0usize);
    for i in 0..data.len() {
        let item = data.load(i, None)?;
        let depths: Vec<f32> = item
            .depth
            .iter()
            .zip(item.mask.iter())
            .filter(|&(_, &m)| m > 0.5)
            .map(|(&d, _)| data.scale.to_mm(d))
            .filter(|&d| d > sensor::CONTACT_THRESHOLD_MM)
            .collect();
        if !depths.is_empty() {
            sum += depths.iter().map(|&d| d as f64).sum::<f64>() / depths.len() as f64;
            count += 1;
        }
    }
    Ok(Reading {
        images: eval.images,
        contact_l1_mm: eval.contact_l1_mm.unwrap_or(f64::NAN),
        zeros_contact_l1_mm: sum / count.max(1) as f64,
    })
}
