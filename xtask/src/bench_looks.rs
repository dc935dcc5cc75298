//! `cargo xtask bench looks`: does training on random looks (`dataset generate --random-looks`)
//! make a network read cameras it never saw? One renderer unit's scenes, trained three ways with
//! the quickstart's recipe (the unit's own look; a random look per sample; the unit's own look
//! with `train fit --vary-look`'s image-space jitter), each read zero-shot by sessions filmed
//! with the independent image model (`gelcam`), which no run trains on, and by the unit's own
//! test frames. With `--finetune-fractions`, each arm's model is also exported and read by
//! `infer`'s evaluation on each gelcam session's test split (as a lab would deploy it), then
//! fine-tuned on a few of the session's frames as `train finetune` does, beside a model trained
//! on the same frames from scratch: does a start on random looks need fewer of a new gel's
//! labelled frames?

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use dataset::generate::generate_with_unit;
use dataset::label::{Labeller, OnBadRow};
use dataset::session::SessionWriter;
use dataset::{Kit, Split};
use formats::dataset::GeneratorParams;
use infer::Predictor;
use infer::eval::SplitStats;
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
    /// The ways of training to run, comma-separated (each run is reused once finished).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "own,random,jitter")]
    arms: Vec<ArmKind>,
    /// Also fine-tune each arm's model, and train one from scratch, on these fractions of each
    /// gelcam session's train split (comma-separated; none by default), and read every gelcam
    /// session's test split as `infer eval` reads it (the bundle's gain, tare and gate): each
    /// arm zero-shot, then each fine-tuned and from-scratch model.
    #[arg(long, value_delimiter = ',')]
    finetune_fractions: Vec<f64>,
    /// Epochs of each fine-tuning and from-scratch run (`train finetune`'s settings otherwise).
    #[arg(long, default_value_t = 40)]
    finetune_epochs: usize,
    /// Seed of the fine-tuning and from-scratch runs: their subset of the frames, data order and
    /// fresh weights (run once per seed for the spread).
    #[arg(long, default_value_t = 0)]
    finetune_seed: u64,
}

/// `--arms`' names for the ways of training.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum ArmKind {
    Own,
    Random,
    Jitter,
}

/// One way of training.
struct Arm {
    kind: ArmKind,
    name: &'static str,
    random_looks: bool,
    vary_look: bool,
}

const ARMS: [Arm; 3] = [
    Arm { kind: ArmKind::Own, name: "own look", random_looks: false, vary_look: false },
    Arm { kind: ArmKind::Random, name: "random looks (generator)", random_looks: true, vary_look: false },
    Arm { kind: ArmKind::Jitter, name: "own look + image jitter (--vary-look)", random_looks: false, vary_look: true },
];

pub fn run(args: Args) -> Result<()> {
    // Checked here, before any dataset is made, and named as the bench's option (the training
    // settings' own check would name `train`'s `--train-fraction`).
    if let Some(bad) = args.finetune_fractions.iter().find(|f| !(**f > 0.0 && **f <= 1.0)) {
        anyhow::bail!("--finetune-fractions: each fraction must be in (0, 1], got {bad}");
    }
    anyhow::ensure!(args.finetune_epochs > 0, "--finetune-epochs: at least 1, got 0");
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
        // calibration's (`bench foreign` measures the two together). With force labels, as
        // `dataset label` makes them, so that a bundle of any arm (the quickstart's network has
        // the pressure output) can be fine-tuned on the session (`train finetune`).
        let data = dir.join("data");
        Labeller {
            session,
            out: data.clone(),
            sensor: &unit.sensor,
            kit: &kit,
            on_bad_row: OnBadRow::Stop,
            z: Default::default(),
            force: Some(dataset::mechanics::Material::PAPER),
            shard: None,
            register: false,
        }
        .run()?;
        sets.push((format!("gelcam unit {g} (membrane {:.2} px)", unit.look.membrane_sigma_px), data, None));
    }

    let arms: Vec<&Arm> = ARMS.iter().filter(|a| args.arms.contains(&a.kind)).collect();
    anyhow::ensure!(!arms.is_empty(), "--arms: name at least one of own, random, jitter");
    // Each gelcam unit's number, name and labelled session.
    let gel_sets: Vec<(u64, String, PathBuf)> =
        args.gelcam_units.iter().zip(&sets[1..]).map(|(&g, (name, dir, _))| (g, name.clone(), dir.clone())).collect();
    let mut deployed: Vec<(String, String, SplitStats)> = Vec::new();
    let mut results = Vec::new();
    for arm in &arms {
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
        let run_dir = args.out.join(&run_name);
        let fitted = fit(&run_dir, &config, start, &device, true).context("training (run again)")?;
        if !args.finetune_fractions.is_empty() {
            for (g, name, dir) in &gel_sets {
                let tag = format!("{run_name}-gel{g}-{}", args.gelcam_samples);
                let stats = read_deployed(&fitted, &run_dir, dir, &args.out.join(format!("read-{tag}")), &device)?;
                deployed.push((name.clone(), format!("{}, zero-shot", arm.name), stats));
                for &fraction in &args.finetune_fractions {
                    let tune = FitConfig {
                        epochs: args.finetune_epochs,
                        train_fraction: fraction,
                        seed: args.finetune_seed,
                        net_range: config.net_range,
                        ..FitConfig::finetune(dir.clone(), config.input_hw, &fitted.state.model)
                    };
                    let run = args
                        .out
                        .join(format!("tune-{tag}-{fraction}-{}ep-s{}", args.finetune_epochs, args.finetune_seed));
                    let start = Start { model_config: fitted.state.model.clone(), weights: Some(fitted.net.clone()) };
                    let tuned = fit(&run, &tune, start, &device, true).context("fine-tuning (run again)")?;
                    let stats = read_deployed(&tuned, &run, dir, &run, &device)?;
                    deployed.push((name.clone(), format!("{}, fine-tuned on {fraction}", arm.name), stats));
                }
            }
        }
        let mut row = Vec::new();
        for (_, dir, split) in &sets {
            row.push(read_set(&fitted.net, &config, &model_config, dir, *split, &device)?);
        }
        results.push(row);
    }

    // The same frames from scratch: the quickstart's recipe on the fine-tuning's subsets.
    for (g, name, dir) in &gel_sets {
        for &fraction in &args.finetune_fractions {
            let cfg = FitConfig {
                epochs: args.finetune_epochs,
                train_fraction: fraction,
                seed: args.finetune_seed,
                ..recipe.fit_config(dir.clone())
            };
            let run = args.out.join(format!(
                "scratch-gel{g}-{}-{fraction}-{}ep-s{}",
                args.gelcam_samples, args.finetune_epochs, args.finetune_seed
            ));
            let start = Start { model_config: model_config.clone(), weights: None };
            let fitted = fit(&run, &cfg, start, &device, true).context("training (run again)")?;
            let stats = read_deployed(&fitted, &run, dir, &run, &device)?;
            deployed.push((name.clone(), format!("from scratch on {fraction}"), stats));
        }
    }

    println!(
        "\nrenderer unit {} ({} scenes, quickstart recipe); contact L1 (mm) of each set, the zero predictor's beside it",
        args.own_unit, args.samples
    );
    let mut header = String::from("| set | images | zeros |");
    let mut rule = String::from("|---|---:|---:|");
    for arm in &arms {
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
            arms.iter()
                .enumerate()
                .map(|(a, arm)| format!("{} {:.4} mm", arm.name, gel(a)))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if !deployed.is_empty() {
        println!(
            "\neach gelcam session's test split read as `infer eval` reads it (fine-tuning: {} epochs, seed {})",
            args.finetune_epochs, args.finetune_seed
        );
        println!("| set | model | test frames with contact | contact L1 (mm) | of zeros' | of them gated |");
        println!("|---|---|---:|---:|---:|---:|");
        for (set, model, s) in &deployed {
            println!(
                "| {set} | {model} | {} | {:.4} | {:.2} | {} |",
                s.contact_l1_mm.n,
                s.contact_l1_mm.mean,
                s.contact_ratio(),
                s.gated_contact_frames
            );
        }
    }
    Ok(())
}

/// A run's model exported as the bundle `{prefix}-bundle` and read by `infer`'s evaluation on
/// `data`'s test split (written to `{prefix}-eval`): what a lab deploying it would see.
fn read_deployed(
    fitted: &train::Fitted,
    run: &Path,
    data: &Path,
    prefix: &Path,
    device: &burn::tensor::Device,
) -> Result<SplitStats> {
    let beside = |what: &str| PathBuf::from(format!("{}-{what}", prefix.display()));
    let bundle = beside("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[run])?;
    let predictor = Predictor::load(&bundle, device)?;
    let stats = infer::eval::evaluate_dataset(&predictor, data, &[Split::Test], &beside("eval"))?;
    stats.get(&Split::Test).cloned().with_context(|| format!("{}: no test split", data.display()))
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
