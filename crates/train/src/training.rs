//! The training loop: masked DenseDepth loss, Adam, per-epoch validation in millimetres,
//! checkpoints every K steps and at each epoch's end, resumable after a kill at any moment.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::data::dataloader::batcher::Batcher;
use burn::module::Module;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use dataset::Split;
use dataset::progress::Progress;
use dataset::rng::SplitMix64;
use model::{DenseDepth, DenseDepthConfig, DepthLossConfig, DepthScale};
use serde::{Deserialize, Serialize};

use crate::checkpoint::{self, RunState};
use crate::data::{DepthBatcher, DepthDataset, Jitter};
use crate::parallel::DataParallel;

/// What a bad sample does to a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum OnBadData {
    /// Stop with the file's name and the problem.
    Stop,
    /// Leave the sample out, count it and report it.
    Skip,
}

/// Everything that defines a run; a resume must match it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitConfig {
    pub data: PathBuf,
    pub input_hw: [usize; 2],
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    pub seed: u64,
    /// Checkpoint every this many steps (and at every epoch's end).
    pub checkpoint_every: u64,
    pub on_bad_data: OnBadData,
    /// Consecutive non-finite steps after which the run stops.
    pub max_bad_steps: u64,
    pub freeze_encoder: bool,
    /// Train on this fraction of the training split (a seeded subset, at least one sample):
    /// fine-tuning from a little of a new unit's data.
    #[serde(default = "one")]
    pub train_fraction: f64,
    /// Test hook: make the loss of this global step non-finite.
    #[serde(default)]
    pub inject_nan_step: Option<u64>,
    /// Network units of zero and maximum depth: the paper's 10..1000, or 0.01..1, which a
    /// network trained from scratch on a short budget reaches in far fewer steps.
    #[serde(default = "paper_range")]
    pub net_range: [f32; 2],
    /// Learning-rate schedule after the warm-up.
    #[serde(default)]
    pub schedule: Schedule,
    /// Steps over which the learning rate ramps up linearly from zero.
    #[serde(default)]
    pub warmup_steps: u64,
    /// Fraction of the (used) training split held out, seeded, to validate each epoch and pick
    /// the best epoch; the test split is never seen during training.
    #[serde(default)]
    pub val_fraction: f64,
}

fn one() -> f64 {
    1.0
}

fn paper_range() -> [f32; 2] {
    model::PAPER_NET_RANGE
}

/// How the learning rate changes over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// The given rate throughout.
    #[default]
    Constant,
    /// Half a cosine from the given rate down to 1 % of it at the last step.
    Cosine,
}

impl FitConfig {
    /// A run with the CLI's defaults.
    pub fn new(data: PathBuf, input_hw: [usize; 2]) -> Self {
        FitConfig {
            data,
            input_hw,
            epochs: 10,
            batch: 4,
            lr: 1e-4,
            seed: 0,
            checkpoint_every: 50,
            on_bad_data: OnBadData::Stop,
            max_bad_steps: 5,
            freeze_encoder: false,
            train_fraction: 1.0,
            inject_nan_step: None,
            net_range: paper_range(),
            schedule: Schedule::Constant,
            warmup_steps: 0,
            val_fraction: 0.0,
        }
    }

    /// The depth scale of this run for a sensor whose depth is clipped at `max_depth_mm`.
    pub fn scale(&self, max_depth_mm: f64) -> DepthScale {
        DepthScale { max_depth_mm: max_depth_mm as f32, net_min: self.net_range[0], net_max: self.net_range[1] }
    }

    /// The learning rate of (1-based) step `step` of `total` steps.
    pub fn learning_rate(&self, step: u64, total: u64) -> f64 {
        if step <= self.warmup_steps {
            return self.lr * step as f64 / (self.warmup_steps + 1) as f64;
        }
        match self.schedule {
            Schedule::Constant => self.lr,
            Schedule::Cosine => {
                let span = total.saturating_sub(self.warmup_steps).max(1) as f64;
                let t = ((step - self.warmup_steps) as f64 / span).min(1.0);
                let floor = 0.01;
                self.lr * (floor + (1.0 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos()))
            }
        }
    }
}

/// One epoch's numbers (also a row of `metrics.csv`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    pub epoch: usize,
    pub train_loss: f64,
    pub val_l1_mm: f64,
    pub val_loss: f64,
    pub skipped_steps: u64,
    pub bad_samples: usize,
    pub seconds: f64,
}

/// The optimiser every run uses (Adam, Burn's defaults).
pub fn optimizer() -> ModuleOptimizer {
    AdamConfig::new().init()
}

/// Where a run starts when there is no checkpoint: fresh weights or given ones.
pub struct Start {
    pub model_config: DenseDepthConfig,
    pub weights: Option<DenseDepth>,
}

/// A finished run.
pub struct Fitted {
    pub net: DenseDepth,
    pub state: RunState,
}

/// Trains (or resumes) the run in `run_dir` on one device.
pub fn fit(run_dir: &Path, config: &FitConfig, start: Start, device: &Device, resume: bool) -> Result<Fitted> {
    fit_on(run_dir, config, start, std::slice::from_ref(device), resume)
}

/// Trains (or resumes) the run in `run_dir`, each batch shared out over `devices` (the first
/// holds the model, validates and checkpoints; see [`crate::parallel`]). The devices are not part
/// of the run's settings: a run may resume on others.
pub fn fit_on(run_dir: &Path, config: &FitConfig, start: Start, devices: &[Device], resume: bool) -> Result<Fitted> {
    let Some(device) = devices.first() else { bail!("no training device given") };
    std::fs::create_dir_all(run_dir).with_context(|| format!("{}: cannot create", run_dir.display()))?;
    let train_device = device.clone().autodiff();
    let mut train = DepthDataset::open(&config.data, Some(Split::Train), config.input_hw)?;
    if !(config.train_fraction > 0.0 && config.train_fraction <= 1.0) {
        bail!("the training fraction must be in (0, 1], got {}", config.train_fraction);
    }
    if config.train_fraction < 1.0 {
        let keep = ((train.records.len() as f64 * config.train_fraction).ceil() as usize).max(1);
        let chosen = permutation(train.records.len(), config.seed ^ 0x5b5e7, 0);
        let mut ids: Vec<usize> = chosen.into_iter().take(keep).collect();
        ids.sort_unstable();
        train.records = ids.into_iter().map(|i| train.records[i].clone()).collect();
    }
    if !(0.0..1.0).contains(&config.val_fraction) {
        bail!("the validation fraction must be in [0, 1), got {}", config.val_fraction);
    }
    let mut val = DepthDataset::open(&config.data, Some(Split::Test), config.input_hw)?;
    if config.val_fraction > 0.0 {
        // Hold out a seeded part of the training samples; the test split stays unseen.
        let n = train.records.len();
        if n < 2 {
            bail!("{}: a validation hold-out needs at least two training samples", config.data.display());
        }
        let held = ((n as f64 * config.val_fraction).round() as usize).clamp(1, n - 1);
        let order = permutation(n, config.seed ^ 0x7a1d, 0);
        let mut is_val = vec![false; n];
        order.iter().take(held).for_each(|&i| is_val[i] = true);
        let records = std::mem::take(&mut train.records);
        let (v, t): (Vec<_>, Vec<_>) = records.into_iter().enumerate().partition(|(i, _)| is_val[*i]);
        val.records = v.into_iter().map(|(_, r)| r).collect();
        train.records = t.into_iter().map(|(_, r)| r).collect();
    }
    let scale = config.scale(train.sensor.max_depth_mm);
    train.scale = scale;
    val.scale = scale;
    let (mut net, mut optim, mut state) = match checkpoint::latest(run_dir) {
        Some(ckpt) if resume => {
            let state = checkpoint::read_state(&ckpt)?;
            if state.config != *config {
                bail!(
                    "{}: the checkpoint was made with other settings; resume with the same arguments, \
                     or use another --out",
                    ckpt.join("state.json").display()
                );
            }
            let (net, optim) = checkpoint::restore(&ckpt, &state, &train_device)?;
            eprintln!("resuming at epoch {} batch {} (step {})", state.epoch + 1, state.batch, state.global_step);
            (net, optim, state)
        }
        Some(ckpt) => bail!(
            "{}: this run folder already has a checkpoint; pass --resume to continue it, or use another --out",
            ckpt.display()
        ),
        None => {
            // Fresh weights come from the device's generator: seeded, so a run is reproducible.
            train_device.seed(config.seed);
            let net = match start.weights {
                Some(w) => w.fork(&train_device).train(),
                None => start.model_config.init(&train_device),
            };
            let state = RunState {
                config: config.clone(),
                model: start.model_config.clone(),
                epoch: 0,
                batch: 0,
                global_step: 0,
                skipped_steps: 0,
                bad_samples: Vec::new(),
                history: Vec::new(),
                epoch_loss_sum: 0.0,
                epoch_loss_count: 0,
            };
            (net, optimizer(), state)
        }
    };
    if config.freeze_encoder {
        net.encoder = net.encoder.no_grad();
    }
    let loss_config = DepthLossConfig::new().with_dynamic_range(scale.range() as f64);
    let batcher = DepthBatcher { input_hw: config.input_hw, mask: train.mask.clone() };
    let parallel = DataParallel::new(devices, batcher.clone(), loss_config.clone())?;
    let n_batches = train.records.len().div_ceil(config.batch);
    let mut bad_run = 0u64;
    while state.epoch < config.epochs {
        let epoch_start = Instant::now();
        let order = permutation(train.records.len(), config.seed, state.epoch as u64);
        let progress = Progress::new(&format!("epoch {}/{}", state.epoch + 1, config.epochs), n_batches as u64);
        progress.inc(state.batch as u64);
        while state.batch < n_batches {
            let ids = &order[state.batch * config.batch..((state.batch + 1) * config.batch).min(order.len())];
            let mut items = Vec::with_capacity(ids.len());
            for &i in ids {
                match train.load(i, Some(Jitter::draw(config.seed, state.epoch as u64, i as u64))) {
                    Ok(item) => items.push(item),
                    Err(e) if config.on_bad_data == OnBadData::Skip => {
                        let name = e.to_string();
                        if !state.bad_samples.contains(&name) {
                            eprintln!("skipping bad sample: {name}");
                            state.bad_samples.push(name);
                        }
                    }
                    Err(e) => {
                        return Err(e)
                            .context("bad training sample (use --on-bad-data skip to leave such samples out)");
                    }
                }
            }
            state.batch += 1;
            state.global_step += 1;
            if !items.is_empty() {
                let step = parallel.step(&net, items)?;
                let mut value = step.loss;
                if config.inject_nan_step == Some(state.global_step) {
                    value = f64::NAN;
                }
                if value.is_finite() {
                    let grads = step.grads;
                    let lr = config.learning_rate(state.global_step, (n_batches * config.epochs) as u64);
                    net = optim.step(lr, net, grads);
                    state.epoch_loss_sum += value;
                    state.epoch_loss_count += 1;
                    bad_run = 0;
                } else {
                    state.skipped_steps += 1;
                    bad_run += 1;
                    eprintln!("step {}: non-finite loss ({value}); step skipped", state.global_step);
                    if bad_run >= config.max_bad_steps {
                        bail!(
                            "{bad_run} consecutive non-finite steps at step {}: stopping; the last good checkpoint \
                             is in {} (try a lower --lr)",
                            state.global_step,
                            checkpoint::dir(run_dir).display()
                        );
                    }
                }
            }
            progress.inc(1);
            let mean = state.epoch_loss_sum / state.epoch_loss_count.max(1) as f64;
            progress.set_message(&format!("loss {mean:.4}"));
            if state.batch < n_batches && state.global_step % config.checkpoint_every == 0 && bad_run == 0 {
                checkpoint::save(run_dir, &net, &optim, &state)?;
            }
        }
        progress.finish();
        let (val_l1_mm, val_loss) = validate(&net.valid(), &val, &batcher, config.batch, device)?;
        let metrics = EpochMetrics {
            epoch: state.epoch + 1,
            train_loss: state.epoch_loss_sum / state.epoch_loss_count.max(1) as f64,
            val_l1_mm,
            val_loss,
            skipped_steps: state.skipped_steps,
            bad_samples: state.bad_samples.len(),
            seconds: epoch_start.elapsed().as_secs_f64(),
        };
        eprintln!(
            "epoch {}: train loss {:.4}, validation L1 {:.4} mm (loss {:.4}), {:.0} s",
            metrics.epoch, metrics.train_loss, metrics.val_l1_mm, metrics.val_loss, metrics.seconds
        );
        let improved = config.val_fraction > 0.0
            && state.best().is_none_or(|b| metrics.val_l1_mm < b.val_l1_mm)
            && metrics.val_l1_mm.is_finite();
        state.history.push(metrics);
        state.epoch += 1;
        state.batch = 0;
        state.epoch_loss_sum = 0.0;
        state.epoch_loss_count = 0;
        if improved {
            // Written before the checkpoint: a kill in between re-runs the epoch and rewrites it.
            checkpoint::save_best(run_dir, &net, &state)?;
        }
        checkpoint::save(run_dir, &net, &optim, &state)?;
        write_metrics(run_dir, &state.history)?;
    }
    let net = match checkpoint::best(run_dir) {
        Some(best) => checkpoint::restore_model(&best, &state.model, device)?,
        None => net.valid(),
    };
    Ok(Fitted { net, state })
}

/// Mean per-image L1 (mm, useful pixels) and mean loss over a split, in eval mode.
pub fn validate(
    net: &DenseDepth,
    data: &DepthDataset,
    batcher: &DepthBatcher,
    batch: usize,
    device: &Device,
) -> Result<(f64, f64)> {
    if data.records.is_empty() {
        return Ok((f64::NAN, f64::NAN));
    }
    let loss_config = DepthLossConfig::new().with_dynamic_range(data.scale.range() as f64);
    let useful: f32 = batcher.mask.iter().sum::<f32>().max(1.0);
    let (mut l1_sum, mut loss_sum, mut images, mut batches) = (0f64, 0f64, 0usize, 0usize);
    let ids: Vec<usize> = (0..data.records.len()).collect();
    for chunk in ids.chunks(batch) {
        let items: Vec<_> = chunk.iter().filter_map(|&i| data.load(i, None).ok()).collect();
        if items.is_empty() {
            continue;
        }
        let n = items.len();
        let b = batcher.batch(items, device);
        let pred = net.forward(b.images);
        loss_sum += loss_config
            .forward_masked(pred.clone(), b.depths.clone(), Some(b.masks.clone()))
            .total
            .into_scalar::<f32>() as f64;
        let err_mm: Tensor<4> = (data.scale.tensor_to_mm(pred) - data.scale.tensor_to_mm(b.depths)).abs() * b.masks;
        let per_image: Vec<f32> = err_mm.sum_dim(3).sum_dim(2).flatten::<1>(0, 3).into_data().try_to_vec::<f32>()?;
        l1_sum += per_image.iter().map(|&s| (s / useful) as f64).sum::<f64>();
        images += n;
        batches += 1;
    }
    Ok((l1_sum / images.max(1) as f64, loss_sum / batches.max(1) as f64))
}

/// The order of an epoch's samples, from the run's seed and the epoch alone (so a resumed run
/// sees the same order).
pub fn permutation(n: usize, seed: u64, epoch: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n).collect();
    let mut rng = SplitMix64::for_item(seed ^ 0x0e0c, epoch);
    for i in (1..n).rev() {
        order.swap(i, rng.below(i + 1));
    }
    order
}

fn write_metrics(run: &Path, history: &[EpochMetrics]) -> Result<()> {
    dataset::format::write_json(&run.join("metrics.json"), &history)?;
    let mut csv = String::from("epoch,train_loss,val_l1_mm,val_loss,skipped_steps,bad_samples,seconds\n");
    for m in history {
        csv.push_str(&format!(
            "{},{},{},{},{},{},{:.1}\n",
            m.epoch, m.train_loss, m.val_l1_mm, m.val_loss, m.skipped_steps, m.bad_samples, m.seconds
        ));
    }
    sensor::io::write_atomic(&run.join("metrics.csv"), csv.as_bytes())?;
    Ok(())
}

/// Preset names for `--preset`.
pub fn preset(name: &str) -> Result<model::DenseNetConfig> {
    use model::DenseNetConfig as C;
    Ok(match name {
        "tiny" => C::tiny(),
        "compact" => C::compact(),
        "densenet121" => C::densenet121(),
        "densenet161" => C::densenet161(),
        "densenet169" => C::densenet169(),
        "densenet201" => C::densenet201(),
        other => bail!("unknown preset {other:?}: tiny, compact, densenet121, densenet161, densenet169, densenet201"),
    })
}
