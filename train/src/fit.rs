//! The training loop: masked DenseDepth loss, Adam, per-epoch validation in millimetres,
//! checkpoints every K steps and at each epoch's end, resumable after a kill at any moment.
//!
//! A run is four parts: the samples it trains and validates on ([`select`]), where it starts
//! (fresh, given weights, or its last checkpoint: [`Run::start`]), the steps of an epoch
//! ([`Run::steps`]) and the epoch's end (validation, the best epoch, checkpoint, metrics:
//! [`Run::end_epoch`]).

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::data::dataloader::batcher::Batcher;
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::tensor::{Device, Tensor};
use formats::dataset::Split;
use formats::output::OutputKind;
use formats::training::EpochMetrics;
use formats::{Progress, SplitMix64};
use model::{DenseDepth, DenseDepthConfig, DepthLossConfig};

use crate::checkpoint::{self, RunState};
use crate::config::{FitConfig, OnBadData, optimizer};
use crate::data::{DepthBatcher, DepthDataset};
use crate::force_refit::{ForceRefit, refit_force_head};
use crate::loader::BatchLoader;
use crate::parallel::DataParallel;
use crate::view::RunView;

/// Where a run starts when there is no checkpoint: fresh weights or given ones.
pub struct Start {
    pub model_config: DenseDepthConfig,
    pub weights: Option<DenseDepth>,
}

impl Start {
    /// The network `config` trains: with the pressure output and the force head where its force
    /// weight is above zero (given weights without them get fresh ones).
    fn for_config(self, config: &FitConfig, device: &Device) -> Start {
        if config.force_weight <= 0.0 {
            return self;
        }
        // A head the network has keeps its design; a new one reads transition2 too.
        let skip = self.model_config.force_head.is_none() || self.model_config.force_head_reads_transition2();
        let hidden = self.model_config.force_head.unwrap_or(model::ForceHead::DEFAULT_HIDDEN);
        let model_config = self
            .model_config
            .with_pressure(true)
            .with_force_head(Some(hidden))
            .with_force_head_skip(skip.then_some(true));
        let weights = self.weights.map(|w| w.with_pressure_output(device).with_force_head(hidden, skip, device));
        Start { weights, model_config }
    }
}

/// A finished run.
pub struct Fitted {
    pub net: DenseDepth,
    pub state: RunState,
    /// The force head's linear map refitted on the trained features, where the network has the
    /// head and the run a validation hold-out ([`crate::ForceRefit`]).
    pub force_refit: Option<ForceRefit>,
}

/// How a run is carried out rather than what it computes: nothing here changes the result, so
/// nothing here is part of the run's settings, and a resume may change any of it.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The devices that share each batch; the first holds the model (see [`crate::parallel`]).
    pub devices: Vec<Device>,
    /// Continue from the run folder's last checkpoint.
    pub resume: bool,
    /// Threads that decode batches ahead of the step (0: decode in the step's thread).
    pub loader_workers: usize,
    /// Megabytes of decoded samples kept from one epoch to the next (0: decode every epoch);
    /// the items are the same either way ([`crate::data::DepthDataset::keep_decoded`]).
    pub decoded_cache_mb: usize,
    /// Test hook: the loss of this global step is made non-finite.
    pub inject_nan_step: Option<u64>,
    /// Where the run's live view goes, if anywhere (feature `view`).
    pub view: Option<view::Target>,
}

impl RunOptions {
    /// Megabytes of decoded samples kept between epochs unless told otherwise.
    pub const DEFAULT_DECODED_CACHE_MB: usize = 2048;

    /// One device, no resume, two loader threads, the default cache of decoded samples.
    pub fn on(device: &Device) -> Self {
        RunOptions {
            devices: vec![device.clone()],
            resume: false,
            loader_workers: 2,
            decoded_cache_mb: Self::DEFAULT_DECODED_CACHE_MB,
            inject_nan_step: None,
            view: None,
        }
    }
}

/// Trains (or resumes) the run in `run_dir` on one device.
pub fn fit(run_dir: &Path, config: &FitConfig, start: Start, device: &Device, resume: bool) -> Result<Fitted> {
    fit_with(run_dir, config, start, &RunOptions { resume, ..RunOptions::on(device) })
}

/// Trains (or resumes) the run in `run_dir`, each batch shared out over `devices`. The devices
/// are not part of the run's settings: a run may resume on others.
pub fn fit_on(run_dir: &Path, config: &FitConfig, start: Start, devices: &[Device], resume: bool) -> Result<Fitted> {
    let first = devices.first().context("no training device given")?;
    fit_with(run_dir, config, start, &RunOptions { devices: devices.to_vec(), resume, ..RunOptions::on(first) })
}

/// Trains (or resumes) the run in `run_dir` as `options` say.
pub fn fit_with(run_dir: &Path, config: &FitConfig, start: Start, options: &RunOptions) -> Result<Fitted> {
    config.validate()?;
    let Some(device) = options.devices.first() else { bail!("no training device given") };
    let start = start.for_config(config, device);
    let folders = config.folders();
    let inputs: Vec<&Path> = folders.iter().map(|p| p.as_path()).collect();
    let _claim = formats::output::claim_dir(run_dir, OutputKind::Run, &inputs)?;
    let (mut train, mut val) = select(config)?;
    train.vary_look = config.vary_look;
    train.set_model(&start.model_config)?;
    val.set_model(&start.model_config)?;
    if start.model_config.input.needs_reference() {
        eprintln!("input: {} (the difference's gain fitted to the unit's contact frames)", train.encoding().text());
    }
    // The cache's budget shared by the two splits as their samples are.
    let budget = options.decoded_cache_mb.saturating_mul(1 << 20);
    let train_share = budget as f64 * train.len() as f64 / (train.len() + val.len()).max(1) as f64;
    train.keep_decoded(train_share as usize);
    val.keep_decoded(budget.saturating_sub(train_share as usize));
    let mut run = Run::start(run_dir, config, start, options, train, val)?;
    // The epochs run on one of rayon's workers (`model::backend::in_pool`), so that the kernels'
    // scatters start inside the pool instead of being injected one by one (the quickstart's
    // epochs 1.18-1.35x faster, BENCHMARKS.md "The whole training step"), all on
    // that one thread: Burn keeps batch norm's running statistics per thread, and steps on
    // whichever worker took each would make them follow the schedule. The loop blocks on the
    // loader's threads and the other devices' workers while it holds its worker; neither uses
    // rayon, so a pool of one thread cannot deadlock on them.
    model::backend::in_pool(|| -> Result<()> {
        while run.state.epoch < config.epochs {
            if let Some(why) = run.state.stop_reason() {
                eprintln!("{why}");
                break;
            }
            let epoch_start = Instant::now();
            run.steps()?;
            run.end_epoch(epoch_start)?;
        }
        Ok(())
    })?;
    if let Some(path) = run.view.take().map(RunView::finish).transpose()?.flatten() {
        eprintln!("wrote {} (open it with `rerun {}`)", path.display(), path.display());
    }
    let net = match checkpoint::best(run_dir) {
        Some(best) => checkpoint::restore_model(&best, &run.state.model, device)?,
        None => run.net.valid(),
    };
    let (net, force_refit) = if wants_refit(&net, config) {
        refit_force_head(net, &run.train, &run.val, &run.batcher, device, config)?
    } else {
        (net, None)
    };
    Ok(Fitted { net, state: run.state, force_refit })
}

/// The run's network with its force head's linear map refitted (`crate::ForceRefit`) as `fit`
/// refits it, from the run's state and data: what `train export` writes, the same weights as
/// `fit` returned.
pub(crate) fn refit_run_force_head(
    net: DenseDepth,
    state: &RunState,
    device: &Device,
) -> Result<(DenseDepth, Option<ForceRefit>)> {
    let config = &state.config;
    if !wants_refit(&net, config) {
        return Ok((net, None));
    }
    let (mut train, mut val) = select(config)?;
    train.vary_look = config.vary_look;
    for split in [&mut train, &mut val] {
        split.set_model(&state.model)?;
        // Each frame is read three times: kept decoded between the readings, as a run keeps them.
        split.keep_decoded(RunOptions::DEFAULT_DECODED_CACHE_MB << 20);
    }
    let batcher = DepthBatcher::for_data(&train);
    refit_force_head(net, &train, &val, &batcher, device, config)
}

/// Whether the force head's map is refitted: where the network has the head and the run a
/// validation hold-out to judge the refit on (without one its strength would be chosen on the
/// test split; said).
fn wants_refit(net: &DenseDepth, config: &FitConfig) -> bool {
    if net.has_force_head() && config.val_fraction <= 0.0 {
        eprintln!("force head: kept as trained (no validation hold-out to judge a refitted map on)");
    }
    net.has_force_head() && config.val_fraction > 0.0
}

/// The samples a run trains on and those it validates on: the training split (or the seeded
/// fraction of it that `train_fraction` asks for), less a seeded hold-out of `val_fraction` of
/// it for validation; without a hold-out, the test split validates.
pub fn select(config: &FitConfig) -> Result<(DepthDataset, DepthDataset)> {
    let folders = config.folders();
    let mut train = DepthDataset::open_all(&folders, Some(Split::Train), config.input_hw)?;
    if config.train_fraction < 1.0 {
        let keep = ((train.len() as f64 * config.train_fraction).ceil() as usize).max(1);
        let chosen = permutation(train.len(), config.seed ^ 0x5b5e7, 0);
        let mut ids: Vec<usize> = chosen.into_iter().take(keep).collect();
        ids.sort_unstable();
        train.keep(&ids);
    }
    let mut val = if config.val_fraction > 0.0 {
        // Hold out a seeded part of the training samples; the test split stays unseen.
        let n = train.len();
        if n < 2 {
            bail!("{}: a validation hold-out needs at least two training samples", config.data.display());
        }
        let held = ((n as f64 * config.val_fraction).round() as usize).clamp(1, n - 1);
        let order = permutation(n, config.seed ^ 0x7a1d, 0);
        let mut is_val = vec![false; n];
        order.iter().take(held).for_each(|&i| is_val[i] = true);
        let (v, t): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| is_val[i]);
        let mut val = train.clone();
        val.keep(&v);
        train.keep(&t);
        val
    } else {
        let test = DepthDataset::open_all(&folders, Some(Split::Test), config.input_hw)?;
        if test.is_empty() {
            bail!(
                "{}: the dataset has no test split to validate on; hold out training samples with --val-fraction",
                config.data.display()
            );
        }
        test
    };
    let scale = config.scale(train.sensor.max_depth_mm);
    train.scale = scale;
    val.scale = scale;
    Ok((train, val))
}

/// A run in progress.
struct Run<'a> {
    dir: &'a Path,
    config: &'a FitConfig,
    options: &'a RunOptions,
    train: Arc<DepthDataset>,
    val: DepthDataset,
    batcher: DepthBatcher,
    parallel: DataParallel,
    net: DenseDepth,
    optim: ModuleOptimizer,
    state: RunState,
    /// Consecutive non-finite steps.
    bad_run: u64,
    view: Option<RunView>,
}

impl<'a> Run<'a> {
    /// From the run folder's last checkpoint when resuming, else from `start`'s weights (or
    /// fresh ones, seeded).
    fn start(
        dir: &'a Path,
        config: &'a FitConfig,
        start: Start,
        options: &'a RunOptions,
        train: DepthDataset,
        val: DepthDataset,
    ) -> Result<Self> {
        let device = &options.devices[0];
        let train_device = device.clone().autodiff();
        let (mut net, optim, state) = match checkpoint::latest(dir) {
            Some(ckpt) if options.resume => {
                let state = checkpoint::read_state(&ckpt)?;
                let mut differences =
                    formats::json::differences(&serde_json::to_value(&state.config)?, &serde_json::to_value(config)?);
                if state.model != start.model_config {
                    let name =
                        |c: &DenseDepthConfig| c.encoder.preset().map_or("custom", model::Preset::name).to_string();
                    differences.push(format!(
                        "model: {} before, {} now ({})",
                        name(&state.model),
                        name(&start.model_config),
                        if options.resume { "--preset, or the bundle of --from" } else { "" }
                    ));
                }
                if !differences.is_empty() {
                    bail!(
                        "{}: the checkpoint was made with other settings ({}); resume with the same arguments, \
                         or use another --out",
                        ckpt.join("state.json").display(),
                        differences.join("; ")
                    );
                }
                let now = checkpoint::data_digests(&config.folders())?;
                for (dir, was) in &state.data_sha256 {
                    if now.get(dir) != Some(was) {
                        bail!(
                            "{}: the dataset changed since this run began (its manifest's SHA-256 differs); resume on \
                             the data it began with, or start a new run with another --out",
                            Path::new(dir).join("manifest.json").display()
                        );
                    }
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
                    data_sha256: checkpoint::data_digests(&config.folders())?,
                    ..RunState::new(config.clone(), start.model_config)
                };
                (net, optimizer(), state)
            }
        };
        if config.freeze_encoder {
            // Frozen as PyTorch fine-tuning freezes: no gradients, and its batch norms read
            // their running statistics and leave them as they were.
            net.encoder = net.encoder.freeze();
        }
        let loss = config.loss(&train.scale);
        let batcher = DepthBatcher::for_data(&train);
        let parallel = DataParallel::new(&options.devices, batcher.clone(), loss)?;
        let view = options.view.as_ref().map(|target| RunView::open(target, &val)).transpose()?;
        let train = Arc::new(train);
        Ok(Run { dir, config, options, train, val, batcher, parallel, net, optim, state, bad_run: 0, view })
    }

    fn batches(&self) -> usize {
        self.train.len().div_ceil(self.config.batch)
    }

    /// The rest of the current epoch's steps, each on a batch decoded ahead.
    fn steps(&mut self) -> Result<()> {
        let (config, n_batches) = (self.config, self.batches());
        let epoch = self.state.epoch as u64;
        let order = permutation(self.train.len(), config.seed, epoch);
        let mut loader = BatchLoader::new(
            self.train.clone(),
            order,
            config.batch,
            [config.seed, epoch],
            self.state.batch,
            self.options.loader_workers,
            2,
        );
        let progress = Progress::new(&format!("epoch {}/{}", epoch + 1, config.epochs), n_batches as u64);
        progress.inc(self.state.batch as u64);
        while let Some(decoded) = loader.next_batch() {
            let mut items = Vec::with_capacity(decoded.len());
            for (_, item) in decoded {
                match item {
                    Ok(item) => items.push(item),
                    Err(e) if config.on_bad_data == OnBadData::Skip => {
                        let name = e.to_string();
                        if !self.state.bad_samples.contains(&name) {
                            eprintln!("skipping bad sample: {name}");
                            self.state.bad_samples.push(name);
                        }
                    }
                    Err(e) => {
                        return Err(e)
                            .context("bad training sample (use --on-bad-data skip to leave such samples out)");
                    }
                }
            }
            self.state.batch += 1;
            self.state.global_step += 1;
            if !items.is_empty() {
                self.step(items)?;
            }
            progress.inc(1);
            let mean = self.state.epoch_loss_sum / self.state.epoch_loss_count.max(1) as f64;
            progress.set_message(&format!("loss {mean:.4}"));
            let s = &self.state;
            if s.batch < n_batches && s.global_step.is_multiple_of(config.checkpoint_every) && self.bad_run == 0 {
                // A checkpoint is only ever a good one: weights that diverged stop the run instead.
                self.refuse_divergence(&self.net.valid(), None)?;
                checkpoint::save(self.dir, &self.net, &self.optim, &self.state)?;
            }
        }
        progress.finish();
        Ok(())
    }

    /// One optimiser step on `items`, or a skipped one if the loss is not finite.
    fn step(&mut self, items: Vec<crate::data::DepthItem>) -> Result<()> {
        let step = self.parallel.step(&self.net, items)?;
        let mut value = step.loss;
        if self.options.inject_nan_step == Some(self.state.global_step) {
            value = f64::NAN;
        }
        if value.is_finite() {
            let total = (self.batches() * self.config.epochs) as u64;
            let lr = self.config.learning_rate(self.state.global_step, total);
            self.net = self.optim.step(lr, self.net.clone(), step.grads);
            self.state.epoch_loss_sum += value;
            self.state.epoch_loss_count += 1;
            self.bad_run = 0;
            if let Some(view) = &self.view {
                view.step(self.state.global_step, value, lr)?;
            }
            return Ok(());
        }
        self.state.skipped_steps += 1;
        self.bad_run += 1;
        eprintln!("step {}: non-finite loss ({value}); step skipped", self.state.global_step);
        if self.bad_run >= self.config.max_bad_steps {
            bail!(
                "{} consecutive non-finite steps at step {}: stopping; {}",
                self.bad_run,
                self.state.global_step,
                self.last_checkpoint()
            );
        }
        Ok(())
    }

    /// Stops the run, keeping the last checkpoint (which is good: none is written from
    /// weights that fail this), when the weights hold NaN or infinite values or the validation
    /// loss, where there is one (`None` between epochs), is not finite.
    fn refuse_divergence(&self, net: &DenseDepth, val_loss: Option<f64>) -> Result<()> {
        let what = match (model::bundle::non_finite_tensors(net), val_loss) {
            (Some(names), _) => {
                format!("{} tensor(s) of the weights hold NaN or infinite values ({})", names.len(), names[0])
            }
            (None, Some(loss)) if !loss.is_finite() => format!("the validation loss is {loss}"),
            (None, _) => return Ok(()),
        };
        bail!("training diverged by step {}: {what}; {}", self.state.global_step, self.last_checkpoint())
    }

    /// Where the run can go on from after it stopped: its last checkpoint, which is good (none
    /// is written from weights that diverged), or none.
    fn last_checkpoint(&self) -> String {
        match checkpoint::latest(self.dir).map(|c| checkpoint::read_state(&c)) {
            Some(Ok(s)) => format!(
                "the last good checkpoint ({}, epoch {} batch {}, step {}) is kept: `train export --run {}` \
                 exports it; a new run with a lower --lr may not diverge",
                checkpoint::dir(self.dir).display(),
                s.epoch + 1,
                s.batch,
                s.global_step,
                self.dir.display()
            ),
            _ => "no checkpoint was written before it; start again with a lower --lr".into(),
        }
    }

    /// Validation, the epoch's metrics, the best epoch's model, the checkpoint and the metrics
    /// files.
    fn end_epoch(&mut self, started: Instant) -> Result<()> {
        let device = &self.options.devices[0];
        let net = self.net.valid();
        let split = if self.config.val_fraction > 0.0 { "validation" } else { "test" };
        let val = validate(&net, &self.val, &self.batcher, self.config.batch, device, self.config.on_bad_data, split)?;
        self.refuse_divergence(&net, Some(val.loss))?;
        let state = &mut self.state;
        for name in val.bad {
            if !state.bad_val_samples.contains(&name) {
                eprintln!("skipping bad {split} sample: {name}");
                state.bad_val_samples.push(name);
            }
        }
        let metrics = EpochMetrics {
            epoch: state.epoch + 1,
            train_loss: state.epoch_loss_sum / state.epoch_loss_count.max(1) as f64,
            val_l1_mm: val.l1_mm,
            val_loss: val.loss,
            skipped_steps: state.skipped_steps,
            bad_samples: state.bad_samples.len(),
            bad_val_samples: state.bad_val_samples.len(),
            seconds: started.elapsed().as_secs_f64(),
            val_pressure_l1_kpa: val.pressure_l1_kpa,
        };
        if let Some(view) = &self.view {
            view.epoch(&metrics, state.global_step, &net, &self.val, &self.batcher, device)?;
        }
        let mut pressure = metrics.val_pressure_l1_kpa.map_or(String::new(), |p| format!(", pressure L1 {p:.2} kPa"));
        if let Some(f) = &val.head_force {
            pressure += &format!(", force head {:.3} N ({:.2} % of the mean force)", f.total_n, f.total_percent());
        }
        eprintln!(
            "epoch {}: train loss {:.4}, validation L1 {:.4} mm{pressure} (loss {:.4}), {:.0} s",
            metrics.epoch, metrics.train_loss, metrics.val_l1_mm, metrics.val_loss, metrics.seconds
        );
        let improved = self.config.val_fraction > 0.0
            && state.best().is_none_or(|b| metrics.val_l1_mm < b.val_l1_mm)
            && metrics.val_l1_mm.is_finite();
        state.history.push(metrics);
        state.epoch += 1;
        state.batch = 0;
        state.epoch_loss_sum = 0.0;
        state.epoch_loss_count = 0;
        if improved {
            // Written before the checkpoint: a kill in between re-runs the epoch and rewrites it.
            checkpoint::save_best(self.dir, &self.net, state)?;
        }
        checkpoint::save(self.dir, &self.net, &self.optim, state)?;
        write_metrics(self.dir, &state.history)
    }
}

/// A split's errors, and the samples that could not be read.
#[derive(Clone, Debug, PartialEq)]
pub struct Evaluation {
    /// Mean per-image L1 (mm, useful pixels, network resolution).
    pub l1_mm: f64,
    /// Mean per-image L1 (mm) over the true contact pixels (deeper than
    /// `sensor::CONTACT_THRESHOLD_MM`) of the images that have any; `None` if none has.
    pub contact_l1_mm: Option<f64>,
    /// Mean per-image pressure L1 (kPa, labelled useful pixels) of a network with the pressure
    /// output, over the images that have a pressure map.
    pub pressure_l1_kpa: Option<f64>,
    /// The force head's errors, over the images with a force label, of a network with the head.
    pub head_force: Option<HeadForceErrors>,
    /// Mean loss over the batches.
    pub loss: f64,
    /// Images the means are over.
    pub images: usize,
    /// Samples left out (`skip`), each `file: problem`.
    pub bad: Vec<String>,
}

/// The force head's errors over a split: sums while they are gathered, means once finished.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HeadForceErrors {
    /// Mean ||F_pred| - |F|| (N): the total normal force's error.
    pub total_n: f64,
    /// Mean |F_pred - F| (N).
    pub vector_n: f64,
    /// Mean |F| (N) of the labels.
    pub mean_n: f64,
    /// Images with a force label.
    pub images: usize,
}

impl HeadForceErrors {
    /// `head`: a batch's force head output (`[N, 3]`, loss units); `f`: its targets.
    fn add(&mut self, head: Tensor<2>, f: &model::ForceTargets) -> Result<()> {
        let pred = head.into_data().convert::<f32>().try_into_vec::<f32>()?;
        let truth = f.force_n.clone().into_data().try_into_vec::<f32>()?;
        let has = f.has.clone().into_data().try_into_vec::<f32>()?;
        let wrench = |force_n| sensor::Wrench { force_n, ..Default::default() };
        for (i, _) in has.iter().enumerate().filter(|(_, h)| **h > 0.0) {
            let p = wrench(std::array::from_fn(|k| (pred[3 * i + k] * model::FORCE_N_PER_LOSS_UNIT) as f64));
            let t = wrench(std::array::from_fn(|k| truth[3 * i + k] as f64));
            self.total_n += (p.force_magnitude_n() - t.force_magnitude_n()).abs();
            self.vector_n += p.force_distance_n(&t);
            self.mean_n += t.force_magnitude_n();
            self.images += 1;
        }
        Ok(())
    }

    fn finish(self) -> Option<Self> {
        let n = self.images as f64;
        (self.images > 0).then(|| HeadForceErrors {
            total_n: self.total_n / n,
            vector_n: self.vector_n / n,
            mean_n: self.mean_n / n,
            images: self.images,
        })
    }

    /// The total force error as a percentage of the labels' mean force.
    pub fn total_percent(&self) -> f64 {
        100.0 * self.total_n / self.mean_n
    }
}

/// Mean per-image L1 (mm, useful pixels) and mean loss over `data` (the split named `split` in
/// messages), in eval mode. A bad sample stops it (`Stop`) or is left out and listed (`Skip`);
/// a split with no usable sample is an error, never 0 or NaN.
pub fn validate(
    net: &DenseDepth,
    data: &DepthDataset,
    batcher: &DepthBatcher,
    batch: usize,
    device: &Device,
    on_bad: OnBadData,
    split: &str,
) -> Result<Evaluation> {
    let loss_config = DepthLossConfig::new()
        .with_dynamic_range(data.scale.range() as f64)
        .with_pressure_weight(FitConfig::DEFAULT_FORCE_WEIGHT);
    let (mut pressure_sum, mut pressure_images) = (0f64, 0usize);
    let mut force_errors = HeadForceErrors::default();
    let (mut l1_sum, mut loss_sum, mut images, mut batches) = (0f64, 0f64, 0usize, 0usize);
    let (mut contact_sum, mut contact_images) = (0f64, 0usize);
    let mut bad = Vec::new();
    let ids: Vec<usize> = (0..data.len()).collect();
    for chunk in ids.chunks(batch.max(1)) {
        let mut items = Vec::with_capacity(chunk.len());
        for &i in chunk {
            match data.load(i, None) {
                Ok(item) => items.push(item),
                Err(e) if on_bad == OnBadData::Skip => bad.push(e.to_string()),
                Err(e) => {
                    return Err(e).context(format!(
                        "bad {split} sample (use --on-bad-data skip to leave such samples out, counted)"
                    ));
                }
            }
        }
        if items.is_empty() {
            continue;
        }
        let n = items.len();
        // Useful pixels of each image (its unit's mask).
        let useful: Vec<f32> = items.iter().map(|i| i.mask.iter().sum::<f32>().max(1.0)).collect();
        let b = batcher.batch(items, device);
        let heads = net.forward_heads(b.images);
        let pred = heads.depth.clone();
        if let (Some(head), Some(f)) = (&heads.force, &b.forces) {
            force_errors.add(head.clone(), f)?;
        }
        if let (Some(p), Some((target, kept))) = (&heads.pressure, &b.pressures) {
            let err = (p.clone() - target.clone()).abs() * kept.clone();
            let per_image = |t: Tensor<4>| t.sum_dim(3).sum_dim(2).flatten::<1>(0, 3).into_data().try_to_vec::<f32>();
            for (e, px) in per_image(err)?.into_iter().zip(per_image(kept.clone())?) {
                if px > 0.0 {
                    pressure_sum += (e / px * model::PRESSURE_KPA_PER_UNIT) as f64;
                    pressure_images += 1;
                }
            }
        }
        loss_sum += loss_config
            .forward_heads(heads, b.depths.clone(), b.masks.clone(), b.pressures.clone(), b.forces.clone())
            .total
            .into_scalar::<f32>() as f64;
        let true_mm = data.scale.tensor_to_mm(b.depths);
        let err_mm: Tensor<4> = (data.scale.tensor_to_mm(pred) - true_mm.clone()).abs() * b.masks.clone();
        let contact = true_mm.greater_elem(sensor::CONTACT_THRESHOLD_MM).float() * b.masks;
        let per_image = |t: Tensor<4>| -> Result<Vec<f32>> {
            Ok(t.sum_dim(3).sum_dim(2).flatten::<1>(0, 3).into_data().try_to_vec::<f32>()?)
        };
        let (sums, contact_px) = (per_image(err_mm.clone())?, per_image(contact.clone())?);
        l1_sum += sums.iter().zip(&useful).map(|(&s, &u)| (s / u) as f64).sum::<f64>();
        for (s, px) in per_image(err_mm * contact)?.into_iter().zip(contact_px) {
            if px > 0.0 {
                contact_sum += (s / px) as f64;
                contact_images += 1;
            }
        }
        images += n;
        batches += 1;
    }
    if images == 0 {
        bail!(
            "{}: the {split} split has no usable sample ({} listed, {} unreadable): no error can be measured on it",
            data.dir().display(),
            data.len(),
            bad.len()
        );
    }
    Ok(Evaluation {
        l1_mm: l1_sum / images as f64,
        contact_l1_mm: (contact_images > 0).then(|| contact_sum / contact_images as f64),
        pressure_l1_kpa: (pressure_images > 0).then(|| pressure_sum / pressure_images as f64),
        head_force: force_errors.finish(),
        loss: loss_sum / batches as f64,
        images,
        bad,
    })
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
    formats::write_json(&run.join("metrics.json"), &history)?;
    let mut csv = csv::Writer::from_writer(Vec::new());
    csv.write_record([
        "epoch",
        "train_loss",
        "val_l1_mm",
        "val_loss",
        "skipped_steps",
        "bad_samples",
        "bad_val_samples",
        "val_pressure_l1_kpa",
        "seconds",
    ])?;
    for m in history {
        csv.write_record([
            m.epoch.to_string(),
            m.train_loss.to_string(),
            m.val_l1_mm.to_string(),
            m.val_loss.to_string(),
            m.skipped_steps.to_string(),
            m.bad_samples.to_string(),
            m.bad_val_samples.to_string(),
            m.val_pressure_l1_kpa.map_or(String::new(), |p| p.to_string()),
            format!("{:.1}", m.seconds),
        ])?;
    }
    let csv = csv.into_inner().map_err(|e| anyhow::anyhow!("metrics.csv: {e}"))?;
    formats::fs::write_atomic(&run.join("metrics.csv"), &csv)?;
    Ok(())
}
