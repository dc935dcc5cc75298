//! Model benchmark: median forward and train-step milliseconds, batch 1 and 4, beside PyTorch
//! running the same architecture in the same run: on the CPU (flex) with the same thread count,
//! or on a GPU (`--devices cuda`, or several for the data-parallel train step). On the CPU,
//! ONNX Runtime runs the same network exported by `model::onnx` (forward only).

use std::process::Command;

use anyhow::{Context, Result, bail};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Distribution, Tensor};
use model::{DenseDepthConfig, DepthLossConfig};
use train::data::{DepthBatcher, DepthItem};
use train::parallel::DataParallel;

use crate::timing::time_ms;

#[derive(clap::Args)]
pub struct Args {
    /// Encoder preset (compact, small, medium, tiny, densenet121, densenet161, densenet169, densenet201).
    #[arg(long, default_value = "densenet161")]
    preset: model::Preset,
    #[arg(long, default_value_t = 480)]
    height: usize,
    #[arg(long, default_value_t = 640)]
    width: usize,
    /// Batch sizes, comma separated.
    #[arg(long, default_value = "1,4", value_delimiter = ',')]
    batches: Vec<usize>,
    /// Timed repetitions per measurement (after one warm-up); the median is reported.
    #[arg(long, default_value_t = 3)]
    reps: usize,
    /// Python interpreter with torch and torchvision (and onnxruntime, on the CPU) for the
    /// peers; "none" skips them.
    #[arg(long, default_value = "python3")]
    python: String,
    /// Measure the forward pass only (for profiling).
    #[arg(long)]
    forward_only: bool,
    /// Where Burn runs: flex (default), wgpu, cuda, cuda:N; several, comma-separated, share each
    /// training batch (data parallel; the forward pass runs on the first). With a GPU the peer
    /// runs on PyTorch's first CUDA device.
    #[arg(long, default_value = "flex")]
    devices: String,
}

pub fn run(args: Args) -> Result<()> {
    let encoder = args.preset.config();
    DenseDepthConfig::check_input_hw([args.height, args.width])?;
    let config = DenseDepthConfig::new(encoder.clone());
    let threads = rayon::current_num_threads();
    let (h, w) = (args.height, args.width);
    let devices = model::backend::devices(&args.devices)?;
    let device = devices[0].clone();
    let on_cpu = devices == [model::backend::default_device()];
    let burn_name = if on_cpu { "Burn flex".to_string() } else { format!("Burn {}", args.devices) };
    println!(
        "DenseDepth-{} at {h}x{w} on {}, {threads} threads, median of {} runs",
        args.preset, args.devices, args.reps
    );
    // GPU work is queued: a timed run ends when every device has finished it.
    let sync = || {
        for d in &devices {
            d.sync().expect("device failed");
        }
    };
    let mut rows = Vec::new();
    for &batch in &args.batches {
        // Inference as `infer` runs it: eval mode, no autodiff, BatchNorms folded.
        let net = config.init(&device).folded();
        let images = Tensor::<4>::random([batch, 3, h, w], Distribution::Uniform(0.0, 1.0), &device);
        let forward = time_ms(args.reps, || {
            let out = net.forward(images.clone());
            let _ = out.into_data();
        });
        // Where the forward time goes: the encoder alone (the decoder is the rest).
        let encoder_ms = time_ms(args.reps, || {
            let _ = net.encoder.forward(images.clone()).norm5.into_data();
        });
        println!(
            "batch {batch}: forward {forward:.0} ms, of which encoder {encoder_ms:.0} ms, decoder {:.0} ms",
            forward - encoder_ms
        );

        if args.forward_only {
            rows.push((batch, forward, f64::NAN));
            continue;
        }
        let train_device = device.clone().autodiff();
        let mut net = config.init(&train_device);
        let mut optim = AdamConfig::new().init();
        let loss_config = DepthLossConfig::new();
        let [oh, ow] = config.output_hw([h, w]);
        let step = if devices.len() == 1 {
            let images = Tensor::<4>::random([batch, 3, h, w], Distribution::Uniform(0.0, 1.0), &train_device);
            let target = Tensor::<4>::random([batch, 1, oh, ow], Distribution::Uniform(10.0, 1000.0), &train_device);
            time_ms(args.reps, || {
                let loss = loss_config.forward(net.forward(images.clone()), target.clone()).total;
                let grads = GradientsParams::from_grads(loss.backward(), &net);
                net = optim.step(1e-4, net.clone(), grads);
                sync();
            })
        } else {
            // The training loop's own data parallelism, on a batch of random samples (every
            // pixel useful, so the masked loss is the loss above).
            let batcher = DepthBatcher { input_hw: [h, w], output_hw: [oh, ow] };
            let parallel = DataParallel::new(&devices, batcher, loss_config.clone())?;
            let mut rng = formats::SplitMix64::for_item(7, batch as u64);
            let mask = std::sync::Arc::new(vec![1.0; oh * ow]);
            let items: Vec<DepthItem> = (0..batch)
                .map(|_| DepthItem {
                    image: (0..3 * h * w).map(|_| rng.unit() as f32).collect(),
                    depth: (0..oh * ow).map(|_| 10.0 + 990.0 * rng.unit() as f32).collect(),
                    mask: mask.clone(),
                })
                .collect();
            time_ms(args.reps, || {
                let step = parallel.step(&net, items.clone()).expect("training step");
                net = optim.step(1e-4, net.clone(), step.grads);
                sync();
            })
        };
        println!("batch {batch}: train step {step:.0} ms, {:.1} images/s", batch as f64 * 1e3 / step);
        rows.push((batch, forward, step));
    }

    let mut peer = Vec::new();
    let mut peer_device = String::from("cpu");
    let mut ort = Vec::new();
    if args.python != "none" {
        let [g, i, bn] = [encoder.growth_rate, encoder.num_init_features, encoder.bn_size];
        let blocks = encoder.block_config.map(|x| x.to_string()).join(",");
        let batches = args.batches.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(",");
        let [hs, ws, reps, threads, g, i, bn] = [h, w, args.reps, threads, g, i, bn].map(|v| v.to_string());
        let common = ["--height", &hs, "--width", &ws, "--batches", &batches, "--reps", &reps, "--threads", &threads];
        let device_name = if on_cpu { "cpu" } else { "cuda" };
        let mut torch_args = vec!["--growth", &g, "--blocks", &blocks, "--init", &i, "--bn-size", &bn];
        torch_args.extend(["--device", device_name]);
        torch_args.extend(common);
        let lines = run_peer(&args.python, "densedepth_torch.py", &torch_args)?;
        for line in &lines {
            if let (Some(batch), Some(f), Some(t)) =
                (field(line, "batch="), field(line, "forward_ms="), field(line, "train_ms="))
            {
                peer.push((batch as usize, f, t));
            }
            if let Some(d) = line.split_whitespace().find_map(|w| w.strip_prefix("device=")) {
                peer_device = d.to_string();
            }
        }
        if on_cpu {
            // ONNX Runtime on the same exported network (one model for every batch size: the
            // batch is free in the graph), what a user would run instead of us on a CPU.
            let dir = tempfile::tempdir()?;
            let onnx = dir.path().join("densedepth.onnx");
            let net = config.init(&device);
            let file = model_bundle_file(&config, [h, w]);
            std::fs::write(&onnx, model::onnx::export(&net, &file)?)?;
            let onnx = onnx.display().to_string();
            let mut ort_args = vec!["--model", onnx.as_str()];
            ort_args.extend(common);
            for line in run_peer(&args.python, "onnx_runtime.py", &ort_args)? {
                if let (Some(batch), Some(f)) = (field(&line, "batch="), field(&line, "forward_ms=")) {
                    ort.push((batch as usize, f));
                }
            }
        }
    }

    println!();
    let peer_name = if peer_device == "cpu" { "PyTorch".to_string() } else { format!("PyTorch {peer_device}") };
    let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.0}"));
    let ratio = |a: f64, b: Option<f64>| b.map_or("-".to_string(), |b| format!("{:.2}", a / b));
    println!(
        "| batch | {burn_name} forward ms | {peer_name} forward ms | ratio | ONNX Runtime forward ms | ratio | {burn_name} train step ms | {peer_name} train step ms | ratio |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (batch, f, t) in rows {
        let p = peer.iter().find(|p| p.0 == batch);
        let o = ort.iter().find(|o| o.0 == batch).map(|o| o.1);
        let (pf, pt) = (p.map(|p| p.1), p.map(|p| p.2));
        // `--forward-only` leaves the train step unmeasured (NaN).
        let (t, pt) = if t.is_nan() { (None, None) } else { (Some(t), pt) };
        println!(
            "| {batch} | {f:.0} | {} | {} | {} | {} | {} | {} | {} |",
            ms(pf),
            ratio(f, pf),
            ms(o),
            ratio(f, o),
            ms(t),
            ms(pt),
            t.map_or("-".into(), |t| ratio(t, pt))
        );
    }
    Ok(())
}

/// `key=value` of a peer's output line, as a number.
fn field(line: &str, key: &str) -> Option<f64> {
    line.split_whitespace().find_map(|w| w.strip_prefix(key)).and_then(|v| v.parse::<f64>().ok())
}

/// Runs `peers/SCRIPT` with `python`; its standard output's lines.
fn run_peer(python: &str, script: &str, args: &[&str]) -> Result<Vec<String>> {
    let script = format!("{}/peers/{script}", env!("CARGO_MANIFEST_DIR"));
    let out =
        Command::new(python).arg(&script).args(args).output().with_context(|| format!("running {python} {script}"))?;
    if !out.status.success() {
        bail!("peer {script} failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    Ok(String::from_utf8_lossy(&out.stdout).lines().map(String::from).collect())
}

/// The description the ONNX export's metadata carries, for a benchmark's untrained network.
fn model_bundle_file(config: &DenseDepthConfig, [h, w]: [usize; 2]) -> model::bundle::BundleFile {
    model::bundle::BundleFile::new(config.clone(), [h, w], sensor::Sensor::default(), model::DepthScale::paper(9.4))
}
