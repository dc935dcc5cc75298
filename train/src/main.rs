//! `train`: fit, resume, fine-tune and export DenseTact depth models.

#![deny(unsafe_code)]

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use train::data::DepthDataset;
use train::{FitConfig, OnBadData, Recipe, RunOptions, Schedule, Start, fit_with};

#[derive(Parser)]
#[command(name = "train", version, about = "Train DenseDepth for DenseTact sensors")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a model on a generated dataset (with images); resumable with --resume.
    Fit(FitArgs),
    /// Fine-tune a bundle's model on a new unit's (small) dataset.
    Finetune(FinetuneArgs),
    /// Write the bundle of a run's latest checkpoint.
    Export {
        /// The run folder (`fit --out`) whose latest checkpoint (its best epoch, if it keeps one) is exported.
        #[arg(long)]
        run: PathBuf,
        /// The bundle folder to write.
        #[arg(long)]
        out: PathBuf,
        /// Name weights.safetensors' tensors as the reference PyTorch DenseDepth's state_dict
        /// (`load_state_dict(load_file(...), strict=True)` loads it); default: Burn's paths.
        #[arg(long)]
        torch_names: bool,
    },
    /// Record the SHA-256 of every file a bundle names in its bundle.json, after its files
    /// were edited on purpose (or for a bundle older than the digests): every bundle is checked
    /// whole when read, and one without them is refused.
    Sign {
        /// The bundle folder.
        #[arg(long)]
        bundle: PathBuf,
    },
    /// A bundle as an ONNX model (opset 17, weights embedded): by default the whole predictor
    /// (the crop as uint8 RGB in, depth in mm on the crop out, as `infer predict` gives it);
    /// with `--network-only`, the network alone (batch, height and width free). The metadata
    /// holds the input encoding, depth scale, model, sensor and crop rule.
    Onnx {
        /// The bundle folder to read.
        #[arg(long)]
        bundle: PathBuf,
        /// The .onnx file to write.
        #[arg(long)]
        out: PathBuf,
        /// The network alone: its input encoding and depth scale left to the caller.
        #[arg(long)]
        network_only: bool,
    },
    /// Make a bundle from a PyTorch DenseDepth state_dict: a `torch.save` file or safetensors
    /// (`safetensors.torch.save_file`, or a bundle's weights.safetensors with PyTorch's names).
    Import {
        /// The PyTorch state_dict: a `torch.save` file or safetensors.
        #[arg(long)]
        pth: PathBuf,
        /// The sensor description (JSON) the bundle is for, as `dataset calibrate` writes it.
        #[arg(long)]
        sensor: PathBuf,
        /// Network input, HxW (each side at least 29).
        #[arg(long, default_value = "480x640", value_parser = parse_hw)]
        input: [usize; 2],
        /// The bundle folder to write.
        #[arg(long)]
        out: PathBuf,
        /// Name weights.safetensors' tensors as the reference PyTorch model's state_dict.
        #[arg(long)]
        torch_names: bool,
    },
}

/// The key names `--torch-names` asks for.
fn keys(torch_names: bool) -> model::bundle::SafetensorsKeys {
    if torch_names { model::bundle::SafetensorsKeys::Pytorch } else { model::bundle::SafetensorsKeys::Burn }
}

#[derive(clap::Args)]
struct Common {
    /// Dataset folder (from `dataset generate --unit SEED`); its unit is the one the bundle
    /// describes.
    #[arg(long)]
    data: PathBuf,
    /// Another unit's dataset folder to train on together with --data (repeat for more): a
    /// base model for new units. Each sample is read with its own unit's geometry and reference.
    #[arg(long)]
    more_data: Vec<PathBuf>,
    /// Run folder: checkpoints, metrics.csv, metrics.json.
    #[arg(long)]
    out: PathBuf,
    /// Epochs (default: the recipe's; fine-tuning: 10).
    #[arg(long)]
    epochs: Option<usize>,
    /// Batch size (default: the recipe's; fine-tuning: 4).
    #[arg(long)]
    batch: Option<usize>,
    /// Peak learning rate (default: the recipe's; fine-tuning: 1e-4).
    #[arg(long)]
    lr: Option<f64>,
    /// Seed of the weights, the data order, the augmentation and the hold-out.
    #[arg(long, default_value_t = FitConfig::DEFAULT_SEED)]
    seed: u64,
    /// flex (the CPU), wgpu (the default adapter), wgpu:N (the N-th discrete GPU), cuda or
    /// cuda:N (builds with --features model/cuda).
    #[arg(long, default_value = "flex")]
    device: String,
    /// Several devices that share every batch (data parallel), comma-separated, e.g.
    /// cuda:0,cuda:1 or wgpu:0,wgpu:1; the first holds the model. Instead of --device.
    #[arg(long, conflicts_with = "device")]
    devices: Option<String>,
    /// Checkpoint every this many steps (and at every epoch's end).
    #[arg(long, default_value_t = FitConfig::DEFAULT_CHECKPOINT_EVERY)]
    checkpoint_every: u64,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    resume: bool,
    /// What a missing or corrupt sample does: stop (default) or skip (counted, reported).
    #[arg(long, value_enum, default_value_t = FitConfig::DEFAULT_ON_BAD_DATA)]
    on_bad_data: OnBadData,
    /// Consecutive non-finite steps (each skipped) after which the run stops.
    #[arg(long, default_value_t = FitConfig::DEFAULT_MAX_BAD_STEPS)]
    max_bad_steps: u64,
    /// Train on this fraction of the training split (a seeded subset).
    #[arg(long, default_value_t = FitConfig::DEFAULT_TRAIN_FRACTION)]
    train_fraction: f64,
    /// Learning-rate schedule after the warm-up: constant or cosine (down to 1 % at the end)
    /// (default: the recipe's; fine-tuning: constant).
    #[arg(long, value_enum)]
    schedule: Option<Schedule>,
    /// Steps over which the learning rate ramps up from zero (default: the recipe's;
    /// fine-tuning: 0).
    #[arg(long)]
    warmup_steps: Option<u64>,
    /// Fraction of the training samples held out to validate each epoch and keep the best
    /// epoch's model (0: validate on the test split, keep the last epoch; default 0.1).
    #[arg(long)]
    val_fraction: Option<f64>,
    /// Weight of an extra L1 term over contact pixels in the training loss (0: DenseDepth's
    /// loss; default: the recipe's; fine-tuning: 0).
    #[arg(long)]
    contact_weight: Option<f64>,
    /// Weight of the force outputs' terms in the training loss; above 0 the network gets a
    /// pressure output (trained on the samples' pressure maps and wrenches) and a force head
    /// (trained on their force), whose force the bundle reports; at 0 the bundle's force is the
    /// contact solved on the predicted depth. Default: the recipe's (quickstart 1, paper 0);
    /// fine-tuning: 1 where the bundle has the pressure output, else 0.
    #[arg(long)]
    force_weight: Option<f64>,
    /// Vary each training sample's look as units differ (colour gains, a tone exponent; frame
    /// and reference alike): for a base model trained with --more-data.
    #[arg(long)]
    vary_look: bool,
    /// Stop when the validation L1 (held-out samples) has not improved for this many epochs.
    #[arg(long)]
    patience: Option<usize>,
    /// Stop after the first epoch that ends with this many minutes of training behind the run.
    #[arg(long)]
    max_minutes: Option<f64>,
    /// Threads that decode batches ahead of the training step (0: none).
    #[arg(long, default_value_t = 2)]
    loader_workers: usize,
    /// Megabytes of decoded samples (frames resized to the input, depth maps) kept from one
    /// epoch to the next, so that later epochs do not decode them again (0: decode every epoch;
    /// the results are the same either way).
    #[arg(long, default_value_t = RunOptions::DEFAULT_DECODED_CACHE_MB)]
    decoded_cache_mb: usize,
    /// Test hook: the loss of this step is made non-finite.
    #[arg(long, hide = true)]
    inject_nan_step: Option<u64>,
    /// The live view: each step's loss, each epoch's validation figures and the network's
    /// reading of a few held-out samples.
    #[command(flatten)]
    view: view::ViewArgs,
}

#[derive(clap::Args)]
struct FitArgs {
    /// Settings shared with `finetune`.
    #[command(flatten)]
    common: Common,
    /// What every setting not given defaults to: `quickstart` (the best measured: the compact
    /// preset at 128x128 reading RGB and its reference difference, full-resolution output, unit
    /// depth units, lr 1e-3 cosine with 100 warm-up steps, 14 epochs, contact weight 5) or
    /// `paper` (DenseNet-161 at 480x640 on RGB, half-resolution output, the paper's units and
    /// loss, lr 1e-4, 16 epochs).
    #[arg(long, value_enum, default_value_t = Recipe::Quickstart)]
    recipe: Recipe,
    /// The network's DenseNet (default: the recipe's).
    #[arg(long, value_parser = preset_parser())]
    preset: Option<model::Preset>,
    /// Network input, HxW (each side at least 29, any size); the square crop is resized to it
    /// (default: the recipe's).
    #[arg(long, value_parser = parse_hw)]
    input: Option<[usize; 2]>,
    /// What the network reads: `rgb` (the paper's) or `rgb-difference` (RGB and its difference to
    /// the dataset's `unit/reference.png`, which a bundle then carries) (default: the recipe's).
    #[arg(long, value_parser = named::<model::InputChannels>(model::InputChannels::ALL.map(model::InputChannels::name)))]
    channels: Option<model::InputChannels>,
    /// Output at the input's resolution (a fifth decoder block whose skip is the input).
    #[arg(long, conflicts_with = "half_resolution")]
    full_resolution: bool,
    /// Output at half the input's resolution (DenseDepth's).
    #[arg(long)]
    half_resolution: bool,
    /// Depth in network units: `paper` (0..max depth -> 10..1000, as the paper trained) or
    /// `unit` (0.01..1, reached in far fewer steps when training from scratch) (default: the
    /// recipe's).
    #[arg(long, value_enum)]
    depth_units: Option<DepthUnits>,
    /// A torchvision DenseNet checkpoint (ImageNet) to start the encoder from.
    #[arg(long)]
    encoder_weights: Option<PathBuf>,
    /// Bundle folder to write at the end.
    #[arg(long)]
    bundle: Option<PathBuf>,
    /// Print the settings and network the run would use (JSON) and stop.
    #[arg(long)]
    dry_run: bool,
}

#[derive(clap::Args)]
struct FinetuneArgs {
    /// Settings shared with `fit`.
    #[command(flatten)]
    common: Common,
    /// The bundle to start from.
    #[arg(long)]
    from: PathBuf,
    /// Train the decoder only: the encoder's weights and its batch norms' running statistics
    /// stay as they are (its batch norms normalise with them, as a frozen PyTorch encoder does).
    #[arg(long)]
    freeze_encoder: bool,
    /// Bundle folder to write at the end.
    #[arg(long)]
    bundle: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
enum DepthUnits {
    Paper,
    Unit,
}

impl DepthUnits {
    fn net_range(self) -> [f32; 2] {
        match self {
            DepthUnits::Paper => model::PAPER_NET_RANGE,
            DepthUnits::Unit => model::UNIT_NET_RANGE,
        }
    }
}

/// A value named by one of `names` (each listed in the help), parsed by its `FromStr`.
fn named<T>(names: impl IntoIterator<Item = &'static str>) -> impl clap::builder::TypedValueParser<Value = T>
where
    T: std::str::FromStr + Clone + Send + Sync + 'static,
    T::Err: std::fmt::Debug,
{
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(names).map(|name| name.parse::<T>().expect("a listed name parses"))
}

/// `--preset`: every preset.
fn preset_parser() -> impl clap::builder::TypedValueParser<Value = model::Preset> {
    named(model::Preset::ALL.map(model::Preset::name))
}

fn parse_hw(s: &str) -> Result<[usize; 2], String> {
    let (h, w) = s.split_once('x').ok_or_else(|| format!("expected HxW, got {s:?}"))?;
    let parse = |v: &str| v.trim().parse::<usize>().map_err(|e| format!("{v:?}: {e}"));
    let hw = [parse(h)?, parse(w)?];
    model::DenseDepthConfig::check_input_hw(hw).map_err(|e| e.to_string())?;
    Ok(hw)
}

/// More loader threads than this only queue on the cores (and thousands cannot be started).
const MAX_LOADER_WORKERS: usize = 256;

/// How the run is carried out: `--devices` when given, else `--device`; resume, loader threads.
fn options(c: &Common) -> Result<RunOptions> {
    let devices = match &c.devices {
        Some(list) => model::backend::devices(list),
        None => model::backend::working_device(&c.device).map(|d| vec![d]),
    }?;
    Ok(RunOptions {
        devices,
        resume: c.resume,
        loader_workers: c.loader_workers,
        decoded_cache_mb: c.decoded_cache_mb,
        inject_nan_step: c.inject_nan_step,
        view: c.view.target().map_err(anyhow::Error::msg)?,
    })
}

/// The run's settings: `base` (a recipe's, or fine-tuning's) with every flag given over it,
/// checked before any work.
fn config(
    c: &Common,
    base: FitConfig,
    input_hw: [usize; 2],
    net_range: [f32; 2],
    freeze_encoder: bool,
) -> Result<FitConfig> {
    if c.loader_workers > MAX_LOADER_WORKERS {
        bail!("--loader-workers {}: at most {MAX_LOADER_WORKERS} threads decode samples", c.loader_workers);
    }
    // Recorded as absolute paths, so that the run exports and resumes from any folder.
    let absolute = |p: &PathBuf| {
        std::fs::canonicalize(p).with_context(|| format!("{}: cannot open the dataset folder", p.display()))
    };
    let data = absolute(&c.data)?;
    let mut more_data = Vec::new();
    for dir in &c.more_data {
        let dir = absolute(dir)?;
        if dir == data || more_data.contains(&dir) {
            bail!("--more-data {}: this folder is already among the data (each is read once)", dir.display());
        }
        more_data.push(dir);
    }
    let config = FitConfig {
        data,
        input_hw,
        net_range,
        schedule: c.schedule.unwrap_or(base.schedule),
        warmup_steps: c.warmup_steps.unwrap_or(base.warmup_steps),
        val_fraction: c.val_fraction.unwrap_or(base.val_fraction),
        epochs: c.epochs.unwrap_or(base.epochs),
        batch: c.batch.unwrap_or(base.batch),
        lr: c.lr.unwrap_or(base.lr),
        seed: c.seed,
        checkpoint_every: c.checkpoint_every,
        on_bad_data: c.on_bad_data,
        max_bad_steps: c.max_bad_steps,
        freeze_encoder,
        train_fraction: c.train_fraction,
        contact_weight: c.contact_weight.unwrap_or(base.contact_weight),
        patience: c.patience,
        max_minutes: c.max_minutes,
        more_data,
        vary_look: c.vary_look,
        force_weight: c.force_weight.unwrap_or(base.force_weight),
    };
    config.validate()?;
    Ok(config)
}

/// A bundle folder is checked before any training: never the data, the run or the start.
fn check_bundle(bundle: &Option<PathBuf>, inputs: &[&std::path::Path]) -> Result<()> {
    if let Some(b) = bundle {
        formats::output::check_dir(b, formats::output::OutputKind::Bundle, inputs)?;
    }
    Ok(())
}

/// `train fit`'s settings and network: its recipe's, with every flag given over them.
fn fit_settings(args: &FitArgs) -> Result<(FitConfig, model::DenseDepthConfig)> {
    let recipe = args.recipe.network();
    let base = args.recipe.fit_config(args.common.data.clone());
    let input = args.input.unwrap_or(recipe.input_hw);
    let net_range = args.depth_units.map_or(base.net_range, DepthUnits::net_range);
    let cfg = config(&args.common, base, input, net_range, false)?;
    let preset = args.preset.unwrap_or(recipe.preset);
    let full_resolution = match (args.full_resolution, args.half_resolution) {
        (true, _) => true,
        (_, true) => false,
        _ => recipe.full_resolution,
    };
    let model_config = model::DenseDepthConfig::new(preset.config())
        .with_input(args.channels.unwrap_or(recipe.channels))
        .with_full_resolution(full_resolution);
    Ok((cfg, model_config))
}

fn run_fit(args: FitArgs) -> Result<()> {
    if args.dry_run {
        let (cfg, model) = fit_settings(&args)?;
        println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "fit": cfg, "model": model }))?);
        return Ok(());
    }
    let mut inputs: Vec<&std::path::Path> = vec![&args.common.data, &args.common.out];
    inputs.extend(args.common.more_data.iter().map(|p| p.as_path()));
    check_bundle(&args.bundle, &inputs)?;
    // The devices first: a device that cannot run is named before the data is looked at.
    let options = options(&args.common)?;
    let (cfg, model_config) = fit_settings(&args)?;
    let preset = args.preset.unwrap_or(args.recipe.network().preset);
    let channels = model_config.input;
    let dev = options.devices[0].clone();
    let weights = match &args.encoder_weights {
        Some(path) => {
            let imported = model::import::load_pytorch(path, &dev)?;
            if imported.config.encoder != model_config.encoder {
                bail!("{}: its DenseNet is not the {preset} preset", path.display());
            }
            let mut net = model_config.init(&dev);
            // Extra input channels start at zero weight: the network begins as the RGB one.
            net.encoder = imported.model.encoder.with_input_channels(channels.count());
            Some(net)
        }
        None => None,
    };
    let fitted = fit_with(&args.common.out, &cfg, Start { model_config, weights }, &options)?;
    report(&fitted.state);
    if let Some(bundle) = &args.bundle {
        train::export::export_net(&fitted.net, &fitted.state, bundle, &[&args.common.out])?;
        println!("wrote bundle {}", bundle.display());
    }
    Ok(())
}

fn run_finetune(args: FinetuneArgs) -> Result<()> {
    check_bundle(&args.bundle, &[&args.common.data, &args.common.out, &args.from])?;
    let options = options(&args.common)?;
    let dev = options.devices[0].clone();
    let (net, file) = model::bundle::load_bundle(&args.from, &dev)?;
    let input = [file.input_height_px, file.input_width_px];
    // The bundle's depth units: the network's output layer was trained to them.
    let net_range = [file.depth_scale.net_min, file.depth_scale.net_max];
    let base = FitConfig::finetune(args.common.data.clone(), input, &file.model);
    let cfg = config(&args.common, base, input, net_range, args.freeze_encoder)?;
    let data = DepthDataset::open(&cfg.data, None, input)?;
    if (data.sensor.radius_mm - file.sensor.radius_mm).abs() > 1e-9 {
        bail!("{}: the dataset's sensor radius differs from the bundle's", cfg.data.display());
    }
    let start = Start { model_config: file.model.clone(), weights: Some(net) };
    let fitted = fit_with(&args.common.out, &cfg, start, &options)?;
    report(&fitted.state);
    if let Some(bundle) = &args.bundle {
        train::export::export_net(&fitted.net, &fitted.state, bundle, &[&args.common.out, &args.from])?;
        println!("wrote bundle {}", bundle.display());
    }
    Ok(())
}

fn report(state: &train::checkpoint::RunState) {
    for m in &state.history {
        println!(
            "epoch {:3}: train loss {:.4}  validation L1 {:.4} mm  ({:.0} s)",
            m.epoch, m.train_loss, m.val_l1_mm, m.seconds
        );
    }
    if state.skipped_steps > 0 {
        println!("{} steps skipped for a non-finite loss", state.skipped_steps);
    }
    for (split, bad) in [("training", &state.bad_samples), ("validation", &state.bad_val_samples)] {
        if !bad.is_empty() {
            println!("{} bad {split} samples skipped:", bad.len());
            for s in bad {
                println!("  {s}");
            }
        }
    }
}

fn main() -> ExitCode {
    model::backend::cpu_unless_asked();
    sensor::alloc::keep_freed_memory();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Fit(args) => run_fit(args),
        Command::Finetune(args) => run_finetune(args),
        Command::Export { run, out, torch_names } => {
            train::export::export_run(&run, &out, &model::backend::default_device(), keys(torch_names))
                .map(|()| println!("wrote bundle {}", out.display()))
        }
        Command::Sign { bundle } => model::bundle::sign_bundle(&bundle, &model::backend::default_device())
            .map_err(anyhow::Error::from)
            .map(|()| println!("signed {}: every file it names has its SHA-256 in bundle.json", bundle.display())),
        Command::Onnx { bundle, out, network_only } => {
            let device = model::backend::default_device();
            train::export::export_onnx(&bundle, &out, &device, !network_only)
                .map(|bytes| println!("wrote {} ({:.1} MB)", out.display(), bytes as f64 / 1e6))
        }
        Command::Import { pth, sensor, input, out, torch_names } => {
            train::export::import_pth(&pth, &sensor, input, &out, &model::backend::default_device(), keys(torch_names))
                .with_context(|| format!("importing {}", pth.display()))
                .map(|()| println!("wrote bundle {}", out.display()))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
#[test]
fn every_flag_says_what_it_does() {
    dataset::cli::assert_documented(&<Cli as clap::CommandFactory>::command());
}
