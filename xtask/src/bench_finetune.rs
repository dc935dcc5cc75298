//! Fine-tuning study: a model trained on simulated unit A, evaluated on unit B before and after
//! fine-tuning with 5, 10 and 25 % of B's training data, against a model trained on all of B's.

use std::path::PathBuf;

use anyhow::Result;
use dataset::generate::generate_with_unit;
use dataset::{Kit, Split};
use formats::dataset::GeneratorParams;
use model::{DenseDepth, DenseDepthConfig, DenseNetConfig};
use train::data::{DepthBatcher, DepthDataset};
use train::{FitConfig, OnBadData, Schedule, Start, fit, validate};

#[derive(clap::Args)]
pub struct Args {
    /// Samples per unit's dataset.
    #[arg(long, default_value_t = 400)]
    samples: u32,
    #[arg(long, default_value_t = 8)]
    epochs: usize,
    #[arg(long, default_value = "compact")]
    preset: String,
    /// Network input side (square).
    #[arg(long, default_value_t = 128)]
    input: usize,
    #[arg(long, default_value_t = 4)]
    batch: usize,
    /// Peak learning rate (Adam; linear warm-up, then a cosine down to 1 %).
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    #[arg(long, default_value_t = 50)]
    warmup_steps: u64,
    /// Work folder (datasets are kept and reused; runs are redone).
    #[arg(long, default_value = "target/finetune-study")]
    work: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let device = model::backend::default_device();
    let input_hw = [args.input, args.input];
    let kit = Kit::procedural(25.0);
    let mut data = Vec::new();
    for (name, seed) in [("unit-a", 1u64), ("unit-b", 2)] {
        let dir = args.work.join(name);
        generate_with_unit(&dir, &kit, seed, 25.0, GeneratorParams::new(seed, args.samples, &kit.source))?;
        data.push(dir);
    }
    let (a, b) = (&data[0], &data[1]);
    let model_config = DenseDepthConfig::new(DenseNetConfig::by_name(&args.preset).map_err(anyhow::Error::msg)?);
    let cfg = |dir: &PathBuf, fraction: f64| FitConfig {
        epochs: args.epochs,
        batch: args.batch,
        lr: args.lr,
        seed: 7,
        checkpoint_every: 1_000_000,
        train_fraction: fraction,
        net_range: model::UNIT_NET_RANGE,
        schedule: Schedule::Cosine,
        warmup_steps: args.warmup_steps,
        val_fraction: 0.1,
        ..FitConfig::new(dir.clone(), input_hw)
    };
    let mut b_test = DepthDataset::open(b, Some(Split::Test), input_hw)?;
    b_test.scale = cfg(b, 1.0).scale(b_test.sensor.max_depth_mm);
    b_test.set_model(&model_config)?;
    let batcher = DepthBatcher::for_data(&b_test);
    let on_b = |net: &DenseDepth| -> Result<f64> {
        Ok(validate(net, &b_test, &batcher, args.batch, &device, OnBadData::Stop, "test")?.l1_mm)
    };
    let run_dir = |name: &str| {
        let d = args.work.join("runs").join(name);
        std::fs::remove_dir_all(&d).ok();
        d
    };
    let fresh = || Start { model_config: model_config.clone(), weights: None };

    let trained_a = fit(&run_dir("a"), &cfg(a, 1.0), fresh(), &device, false)?;
    let mut a_test = DepthDataset::open(a, Some(Split::Test), input_hw)?;
    a_test.scale = b_test.scale;
    a_test.set_model(&model_config)?;
    let batcher_a = DepthBatcher::for_data(&a_test);
    let a_own = validate(&trained_a.net, &a_test, &batcher_a, args.batch, &device, OnBadData::Stop, "test")?.l1_mm;
    let before = on_b(&trained_a.net)?;
    let mut rows = vec![("A on A's test split".to_string(), a_own), ("A on B, before fine-tuning".to_string(), before)];
    for fraction in [0.05, 0.10, 0.25] {
        let start = Start { model_config: model_config.clone(), weights: Some(trained_a.net.clone()) };
        let tuned =
            fit(&run_dir(&format!("ft{}", (fraction * 100.0) as u32)), &cfg(b, fraction), start, &device, false)?;
        rows.push((format!("A fine-tuned on {:.0} % of B", fraction * 100.0), on_b(&tuned.net)?));
    }
    let full_b = fit(&run_dir("b"), &cfg(b, 1.0), fresh(), &device, false)?;
    let full = on_b(&full_b.net)?;
    rows.push(("trained on all of B".to_string(), full));

    println!(
        "\n{} preset, {}x{} input, {} samples per unit, {} epochs per run (best on 10 % held out), batch {}, lr {} (cosine); test split of unit B ({} images)",
        args.preset,
        args.input,
        args.input,
        args.samples,
        args.epochs,
        args.batch,
        args.lr,
        b_test.records.len()
    );
    println!("| model | mean per-image L1 on B's test split (mm) | vs all of B |");
    println!("|---|---:|---:|");
    for (name, l1) in rows {
        println!("| {name} | {l1:.4} | {:.2}x |", l1 / full);
    }
    Ok(())
}
