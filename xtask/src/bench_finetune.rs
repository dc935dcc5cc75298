//! Base model study (issue 21, item 4): a model trained on several simulated units at once reads
//! units it never saw, zero-shot and after fine-tuning on 5 and 10 % of their training data,
//! against each unseen unit's own model trained on all of its data. The quickstart's recipe
//! and network throughout. By default every unseen unit's dataset has as many scenes as the
//! base model's, so the base model sees as many samples as an own model, spread over its units;
//! `--unseen-samples` sets them apart (a base model trained on more than one unit's worth).

use std::path::{Path, PathBuf};

use anyhow::Result;
use dataset::generate::generate_with_unit;
use dataset::{Kit, Split};
use formats::dataset::GeneratorParams;
use model::DenseDepth;
use train::data::{DepthBatcher, DepthDataset};
use train::{Evaluation, FitConfig, OnBadData, Start, fit, validate};

use crate::quickstart::{network, recipe};

#[derive(clap::Args)]
pub struct Args {
    /// Units the base model trains on, comma-separated.
    #[arg(long, default_value = "11,12,13,14", value_delimiter = ',')]
    base_units: Vec<u64>,
    /// Units never seen by the base model, comma-separated.
    #[arg(long, default_value = "7", value_delimiter = ',')]
    unseen_units: Vec<u64>,
    /// Scenes of the base model's data, split evenly over its units.
    #[arg(long, default_value_t = 1000)]
    samples: u32,
    /// Scenes of each unseen unit's dataset (its own model trains on all of them); default
    /// --samples.
    #[arg(long)]
    unseen_samples: Option<u32>,
    /// Epochs of the base and own models (the quickstart's 14).
    #[arg(long, default_value_t = 14)]
    epochs: usize,
    /// Epochs of a fine-tuning run (Adam at a third of the peak rate, 20 warm-up steps); 14
    /// stopped short of what the data gives (BENCHMARKS.md).
    #[arg(long, default_value_t = 40)]
    finetune_epochs: usize,
    /// Train the base model with each sample's look varied as units differ (`train fit
    /// --vary-look`).
    #[arg(long)]
    vary_look: bool,
    #[arg(long, default_value = "compact")]
    preset: model::Preset,
    /// Network input side (square).
    #[arg(long, default_value_t = 128)]
    input: usize,
    /// Training seed of every run (weights, data order, augmentation, hold-out and the fine-tuning
    /// subsets): run the study once per seed for the spread. Seed 0's runs keep their old names.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Work folder: datasets and runs are kept under names that say what made them (units,
    /// scenes, epochs), and a run that finished is reused.
    #[arg(long, default_value = "target/base-model-study")]
    work: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let device = model::backend::default_device();
    let kit = Kit::procedural(25.0);
    let data_of = |unit: u64, samples: u32| -> Result<PathBuf> {
        let dir = args.work.join(format!("unit-{unit}-{samples}"));
        // One in ten lifted clear of the sensor, as the quickstart's.
        let params = GeneratorParams { lifted_fraction: 0.1, ..GeneratorParams::new(unit, samples, &kit.source) };
        generate_with_unit(&dir, &kit, unit, 25.0, params)?;
        Ok(dir)
    };
    let unseen_samples = args.unseen_samples.unwrap_or(args.samples);
    let per_base = args.samples.div_ceil(args.base_units.len().max(1) as u32);
    let base_dirs: Vec<PathBuf> = args.base_units.iter().map(|&u| data_of(u, per_base)).collect::<Result<_>>()?;
    let model_config = network(args.preset);
    let cfg = |data: &Path| FitConfig { epochs: args.epochs, seed: args.seed, ..recipe(data, args.input) };
    let seeded = if args.seed == 0 { String::new() } else { format!("-s{}", args.seed) };
    let fresh = || Start { model_config: model_config.clone(), weights: None };
    let runs = args.work.join("runs");

    let base_cfg = FitConfig { more_data: base_dirs[1..].to_vec(), vary_look: args.vary_look, ..cfg(&base_dirs[0]) };
    // A fine-tuned run's settings do not name the weights it started from: the base run's
    // name goes into the fine-tuned runs' names, so that another base model is never mistaken
    // for this one's.
    let units: Vec<String> = args.base_units.iter().map(u64::to_string).collect();
    let look = if args.vary_look { "-look" } else { "" };
    let base_name = format!("base-{}-{per_base}x{}ep{look}{seeded}", units.join("_"), args.epochs);
    let base = fit(&runs.join(&base_name), &base_cfg, fresh(), &device, true)?;
    let mut rows = Vec::new();
    for &unit in &args.unseen_units {
        let dir = data_of(unit, unseen_samples)?;
        let mut test = DepthDataset::open(&dir, Some(Split::Test), base_cfg.input_hw)?;
        test.scale = base_cfg.scale(test.sensor.max_depth_mm);
        test.set_model(&model_config)?;
        let batcher = DepthBatcher::for_data(&test);
        let on_test = |net: &DenseDepth| -> Result<Evaluation> {
            validate(net, &test, &batcher, 4, &device, OnBadData::Stop, "test")
        };
        let own = fit(
            &runs.join(format!("own-{unit}-{unseen_samples}x{}ep{seeded}", args.epochs)),
            &cfg(&dir),
            fresh(),
            &device,
            true,
        )?;
        let own_eval = on_test(&own.net)?;
        rows.push((unit, "own model (all of its training data)".to_string(), own_eval.clone(), own_eval.clone()));
        rows.push((unit, "base model, zero-shot".to_string(), on_test(&base.net)?, own_eval.clone()));
        for percent in [5u32, 10] {
            let tune = FitConfig {
                epochs: args.finetune_epochs,
                lr: base_cfg.lr / 3.0,
                warmup_steps: 20,
                train_fraction: percent as f64 / 100.0,
                ..cfg(&dir)
            };
            let start = Start { model_config: model_config.clone(), weights: Some(base.net.clone()) };
            // The base name carries the seed.
            let name = format!("tuned-{unit}-{unseen_samples}-{percent}pc-{}ep-from-{base_name}", args.finetune_epochs);
            let tuned = fit(&runs.join(name), &tune, start, &device, true)?;
            rows.push((unit, format!("base model fine-tuned on {percent} %"), on_test(&tuned.net)?, own_eval.clone()));
        }
    }

    println!(
        "\nseed {}; base model: units {:?}, {} scenes each{}; unseen units {:?}, {} scenes each; {} preset at {}x{}, \
         the quickstart's recipe ({} epochs; fine-tuning {} epochs at a third of the rate); errors on each unseen \
         unit's test split at the network's output resolution (contact: true depth above {} mm)",
        args.seed,
        args.base_units,
        per_base,
        if args.vary_look { ", looks varied" } else { "" },
        args.unseen_units,
        unseen_samples,
        args.preset,
        args.input,
        args.input,
        args.epochs,
        args.finetune_epochs,
        sensor::CONTACT_THRESHOLD_MM
    );
    println!("| unit | model | test images | contact L1 (mm) | vs own | L1 (mm) | vs own |");
    println!("|---:|---|---:|---:|---:|---:|---:|");
    for (unit, name, e, own) in rows {
        let contact = e.contact_l1_mm.unwrap_or(f64::NAN);
        let own_contact = own.contact_l1_mm.unwrap_or(f64::NAN);
        println!(
            "| {unit} | {name} | {} | {contact:.4} | {:.2}x | {:.4} | {:.2}x |",
            e.images,
            contact / own_contact,
            e.l1_mm,
            e.l1_mm / own.l1_mm
        );
    }
    Ok(())
}
