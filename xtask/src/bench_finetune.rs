//! Base model study (issue 21, item 4): a model trained on several simulated units at once reads
//! units it never saw, zero-shot and after fine-tuning on 5 and 10 % of their training data,
//! against each unseen unit's own model trained on all of its data. The quickstart's recipe
//! and network throughout; every unit's dataset has the same number of scenes, so the base
//! model sees as many samples as an own model, spread over its units.

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
    /// Scenes of the base model's data, split evenly over its units; each unseen unit's dataset
    /// has as many.
    #[arg(long, default_value_t = 1000)]
    samples: u32,
    /// Epochs of the base and own models (the quickstart's 14).
    #[arg(long, default_value_t = 14)]
    epochs: usize,
    /// Epochs of a fine-tuning run (Adam at a third of the peak rate, 20 warm-up steps).
    #[arg(long, default_value_t = 14)]
    finetune_epochs: usize,
    #[arg(long, default_value = "compact")]
    preset: String,
    /// Network input side (square).
    #[arg(long, default_value_t = 128)]
    input: usize,
    /// Work folder: datasets and runs are kept, and a run that finished is reused.
    #[arg(long, default_value = "target/base-model-study")]
    work: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let device = model::backend::default_device();
    let kit = Kit::procedural(25.0);
    let data_of = |unit: u64, samples: u32| -> Result<PathBuf> {
        let dir = args.work.join(format!("unit-{unit}"));
        // One in ten lifted clear of the sensor, as the quickstart's.
        let params = GeneratorParams { lifted_fraction: 0.1, ..GeneratorParams::new(unit, samples, &kit.source) };
        generate_with_unit(&dir, &kit, unit, 25.0, params)?;
        Ok(dir)
    };
    let per_base = args.samples.div_ceil(args.base_units.len().max(1) as u32);
    let base_dirs: Vec<PathBuf> = args.base_units.iter().map(|&u| data_of(u, per_base)).collect::<Result<_>>()?;
    let model_config = network(&args.preset)?;
    let cfg = |data: &Path| FitConfig { epochs: args.epochs, ..recipe(data, args.input) };
    let fresh = || Start { model_config: model_config.clone(), weights: None };
    let runs = args.work.join("runs");

    let base_cfg = FitConfig { more_data: base_dirs[1..].to_vec(), ..cfg(&base_dirs[0]) };
    let base = fit(&runs.join("base"), &base_cfg, fresh(), &device, true)?;
    let mut rows = Vec::new();
    for &unit in &args.unseen_units {
        let dir = data_of(unit, args.samples)?;
        let mut test = DepthDataset::open(&dir, Some(Split::Test), base_cfg.input_hw)?;
        test.scale = base_cfg.scale(test.sensor.max_depth_mm);
        test.set_model(&model_config)?;
        let batcher = DepthBatcher::for_data(&test);
        let on_test = |net: &DenseDepth| -> Result<Evaluation> {
            validate(net, &test, &batcher, 4, &device, OnBadData::Stop, "test")
        };
        let own = fit(&runs.join(format!("own-{unit}")), &cfg(&dir), fresh(), &device, true)?;
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
            let tuned = fit(&runs.join(format!("tuned-{unit}-{percent}")), &tune, start, &device, true)?;
            rows.push((unit, format!("base model fine-tuned on {percent} %"), on_test(&tuned.net)?, own_eval.clone()));
        }
    }

    println!(
        "\nbase model: units {:?}, {} scenes each; unseen units {:?}, {} scenes each; {} preset at {}x{}, \
         the quickstart's recipe ({} epochs; fine-tuning {} epochs at a third of the rate); errors on each unseen \
         unit's test split at the network's output resolution (contact: true depth above {} mm)",
        args.base_units,
        per_base,
        args.unseen_units,
        args.samples,
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
