//! Data loading against the training step: decoded samples/s (PNG decode, resize, augmentation)
//! with 0, 1 and 2 loader threads, beside train-step samples/s on the same device, and a whole
//! epoch's wall time without and with batches decoded ahead.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use dataset::generate::generate_with_unit;
use dataset::{Kit, Split};
use formats::dataset::GeneratorParams;
use model::DenseDepthConfig;
use train::data::DepthDataset;
use train::{BatchLoader, FitConfig, RunOptions, Start, fit_with, permutation};

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, default_value = "compact")]
    preset: model::Preset,
    /// Network input, HxW.
    #[arg(long, default_value = "128x128")]
    input: String,
    #[arg(long, default_value_t = 4)]
    batch: usize,
    /// Samples in the (generated, kept) dataset.
    #[arg(long, default_value_t = 96)]
    samples: u32,
    /// Training steps timed per setting.
    #[arg(long, default_value_t = 12)]
    steps: usize,
    /// Where the train step runs: flex, wgpu, cuda.
    #[arg(long, default_value = "flex")]
    device: String,
    #[arg(long, default_value = "target/bench-loader")]
    work: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let (h, w) = args.input.split_once('x').context("--input is HxW")?;
    let input_hw: [usize; 2] = [h.parse()?, w.parse()?];
    let device = model::backend::working_device(&args.device)?;
    let kit = Kit::procedural(25.0);
    let data_dir = args.work.join(format!("data-{}", args.samples));
    generate_with_unit(&data_dir, &kit, 7, 25.0, GeneratorParams::new(0, args.samples, &kit.source))?;
    let data = Arc::new(DepthDataset::open(&data_dir, Some(Split::Train), input_hw)?);
    let n = data.len();
    println!(
        "{} at {}x{}, batch {}, {} training samples, {} rayon threads, train step on {}",
        args.preset,
        input_hw[0],
        input_hw[1],
        args.batch,
        n,
        rayon::current_num_threads(),
        args.device
    );

    // Decoding alone: every batch of an epoch pulled through the loader.
    let mut decode = Vec::new();
    for workers in [0, 1, 2] {
        let start = Instant::now();
        let mut loader = BatchLoader::new(data.clone(), permutation(n, 0, 0), args.batch, [0, 0], 0, workers, 2);
        let mut items = 0;
        while let Some(batch) = loader.next_batch() {
            items += batch.into_iter().filter(|(_, r)| r.is_ok()).count();
        }
        let rate = items as f64 / start.elapsed().as_secs_f64();
        println!("decode, {workers} loader threads: {rate:.1} samples/s");
        decode.push((workers, rate));
    }

    // The train step alone, on batches decoded beforehand.
    let batcher = train::data::DepthBatcher::for_data(&data);
    let loss = model::DepthLossConfig::new().with_dynamic_range(data.scale.range() as f64);
    let parallel = train::parallel::DataParallel::new(std::slice::from_ref(&device), batcher, loss)?;
    let model_config = DenseDepthConfig::new(args.preset.config());
    let mut net = model_config.init(&device.clone().autodiff());
    let mut optim = train::optimizer();
    let batches: Vec<Vec<train::data::DepthItem>> = (0..args.steps.min(n / args.batch).max(1) + 1)
        .map(|b| (0..args.batch).map(|k| data.load((b * args.batch + k) % n, None)).collect::<Result<_, _>>())
        .collect::<Result<_, _>>()?;
    let mut step_times = Vec::new();
    for (k, items) in batches.into_iter().enumerate() {
        let start = Instant::now();
        let step = parallel.step(&net, items)?;
        net = optim.step(1e-4, net, step.grads);
        device.sync().map_err(|e| anyhow::anyhow!("{e:?}"))?;
        if k > 0 {
            step_times.push(start.elapsed().as_secs_f64());
        }
    }
    let step_s = formats::stats::median(step_times.clone());
    let step_rate = args.batch as f64 / step_s;
    println!(
        "train step alone: median {:.1} ms over {} steps, {step_rate:.2} samples/s",
        step_s * 1e3,
        step_times.len()
    );

    // Training: a run of `steps` steps (one epoch of that many batches), batches decoded in the
    // step's thread, then ahead on two loader threads.
    let subset = (args.steps * args.batch) as f64 / n as f64;
    let config = FitConfig {
        epochs: 1,
        batch: args.batch,
        lr: 1e-4,
        checkpoint_every: 1_000_000,
        train_fraction: subset.min(1.0),
        val_fraction: 0.0,
        ..FitConfig::new(data_dir.clone(), input_hw)
    };
    let mut epoch = Vec::new();
    for workers in [0, 2] {
        let run = args.work.join(format!("run-{workers}"));
        let _ = std::fs::remove_dir_all(&run);
        let options = RunOptions { loader_workers: workers, ..RunOptions::on(&device) };
        let start = Start { model_config: model_config.clone(), weights: None };
        let fitted = fit_with(&run, &config, start, &options)?;
        // The epoch's time as the run records it: its steps and one validation pass.
        let seconds = fitted.state.history[0].seconds;
        let steps = fitted.state.global_step;
        let rate = (steps as usize * args.batch) as f64 / seconds;
        println!(
            "train epoch ({steps} steps, with validation), {workers} loader threads: {seconds:.2} s, {rate:.2} samples/s"
        );
        epoch.push((workers, seconds, rate));
    }
    println!();
    println!("| setting | samples/s |");
    println!("|---|---:|");
    for (workers, rate) in &decode {
        println!("| decode only, {workers} loader threads | {rate:.1} |");
    }
    println!("| train step alone (decoded beforehand) | {step_rate:.2} |");
    for (workers, seconds, rate) in &epoch {
        println!("| train epoch with validation, {workers} loader threads ({seconds:.1} s) | {rate:.2} |");
    }
    Ok(())
}
