//! Model benchmark: forward and train-step milliseconds (median and quartiles, to 0.01 ms),
//! batch 1 and 4, of a recipe's network (the paper's, or the quickstart's), beside PyTorch
//! running the same architecture in the same run: on the CPU (flex) with the same thread count,
//! or on a GPU (`--devices cuda`, or several for the data-parallel train step). On the CPU,
//! ONNX Runtime runs the same network exported by `model::onnx` (forward only).

use anyhow::Result;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Distribution, Tensor};
use formats::stats::Summary;
use model::{DenseDepthConfig, DepthLossConfig};
use train::data::{DepthBatcher, DepthItem};
use train::parallel::DataParallel;

use crate::ort_peer::{Frame, OrtPeer, Pacing, difference, interleave};
use crate::peer::field;
use crate::timing::{process_cpu_ms, time_ms, time_ms_apart};

#[derive(clap::Args)]
pub struct Args {
    /// The network and input size of a training recipe: `paper` (DenseNet-161 at 480x640, RGB,
    /// half-resolution output) or `quickstart` (compact at 128x128, RGB and its difference to
    /// the reference, full-resolution output); the flags below change one part of it.
    #[arg(long, value_enum, default_value_t = train::Recipe::Paper)]
    recipe: train::Recipe,
    /// Encoder preset (compact, small, medium, tiny, densenet121, densenet161, densenet169, densenet201).
    #[arg(long)]
    preset: Option<model::Preset>,
    #[arg(long)]
    height: Option<usize>,
    #[arg(long)]
    width: Option<usize>,
    /// What the network reads: rgb, or rgb-difference (6 channels).
    #[arg(long)]
    input: Option<model::InputChannels>,
    /// Output at the input's resolution (a fifth up block), or at half of it.
    #[arg(long, conflicts_with = "half_resolution")]
    full_resolution: bool,
    #[arg(long)]
    half_resolution: bool,
    /// Batch sizes, comma separated.
    #[arg(long, default_value = "1,4", value_delimiter = ',')]
    batches: Vec<usize>,
    /// Timed repetitions per measurement (after one warm-up): the median and quartiles are reported.
    #[arg(long, default_value_t = 3)]
    reps: usize,
    /// Python interpreter for the peers; "none" skips them.
    #[arg(long, default_value = "python3")]
    python: String,
    /// The peers to run: pytorch (needs torch and torchvision), onnxruntime (needs onnxruntime
    /// and numpy; on the CPU only).
    #[arg(long, value_enum, default_value = "pytorch,onnxruntime", value_delimiter = ',')]
    peers: Vec<Peer>,
    /// Also time the inference forward pass and a training step's forward and backward with
    /// and without `model::backend::in_pool`'s hop into rayon's pool, alternately in this run.
    #[arg(long)]
    pool_hop_ab: bool,
    /// Idle this many milliseconds before each timed forward, as between a camera's frames (a
    /// frame every 33 ms at 30 fps): on a machine whose cores sleep when idle, a call after a
    /// pause is slower than one in a busy loop. Default: 50 with ONNX Runtime alternated with
    /// ours (each side's timed forward that long after its previous one), 0 without.
    #[arg(long)]
    pause_ms: Option<u64>,
    /// Keep rayon's workers polling for work this long after each forward, as ONNX Runtime's
    /// spin by default (`model::backend::set_spin`); 0: they sleep.
    #[arg(long, default_value_t = 0)]
    spin_ms: u64,
    /// ONNX Runtime's workers sleep after a run instead of spinning (its
    /// `session.intra_op.allow_spinning` 0).
    #[arg(long)]
    ort_no_spin: bool,
    /// Measure the forward pass only (for profiling).
    #[arg(long)]
    forward_only: bool,
    /// Also time each stage of the inference forward (stem, dense blocks, transitions, decoder
    /// blocks, heads): median and quartiles over the repetitions, to set beside ONNX Runtime's
    /// profile of the same stages (`xtask/peers/onnx_runtime_profile.py`).
    #[arg(long)]
    stages: bool,
    /// Where Burn runs: flex (default), wgpu, cuda, cuda:N; several, comma-separated, share each
    /// training batch (data parallel; the forward pass runs on the first). With a GPU the peer
    /// runs on PyTorch's first CUDA device.
    #[arg(long, default_value = "flex")]
    devices: String,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Peer {
    Pytorch,
    Onnxruntime,
}

impl Args {
    /// The network measured: the recipe's, changed by the flags.
    fn network(&self) -> (DenseDepthConfig, [usize; 2]) {
        let n = self.recipe.network();
        let full = match (self.full_resolution, self.half_resolution) {
            (true, _) => true,
            (_, true) => false,
            _ => n.full_resolution,
        };
        let config = DenseDepthConfig::new(self.preset.unwrap_or(n.preset).config())
            .with_input(self.input.unwrap_or(n.channels))
            .with_full_resolution(full);
        (config, [self.height.unwrap_or(n.input_hw[0]), self.width.unwrap_or(n.input_hw[1])])
    }
}

/// One measurement's times (ms); `None` where it was not taken.
type Times = Option<Summary>;

pub fn run(args: Args) -> Result<()> {
    let spin = std::time::Duration::from_millis(args.spin_ms);
    model::backend::set_spin(spin);
    let (config, [h, w]) = args.network();
    let encoder = config.encoder.clone();
    DenseDepthConfig::check_input_hw([h, w])?;
    let channels = config.input.count();
    let threads = rayon::current_num_threads();
    let devices = model::backend::devices(&args.devices)?;
    let device = devices[0].clone();
    let on_cpu = devices == [model::backend::default_device()];
    let burn_name = if on_cpu { "Burn flex".to_string() } else { format!("Burn {}", args.devices) };
    println!(
        "DenseDepth-{} at {h}x{w} reading {} ({channels} channels), output at {} resolution, on {}, {threads} threads, \
         ms over {} runs: median [quartiles]",
        encoder.preset().map_or("custom", model::Preset::name),
        config.input.name(),
        if config.full_resolution { "full" } else { "half" },
        args.devices,
        args.reps
    );
    // GPU work is queued: a timed run ends when every device has finished it.
    let sync = || {
        for d in &devices {
            d.sync().expect("device failed");
        }
    };
    let run_peers = |p: Peer| args.python != "none" && args.peers.contains(&p);
    // ONNX Runtime on the same exported network (one model for every batch size: the batch is
    // free in the graph), what a user would run instead of us on a CPU, its runs alternated
    // with flex's.
    // One network for both sides, so that their outputs can be compared.
    let untrained = config.init(&device);
    let onnx_dir = tempfile::tempdir()?;
    let mut ort_peer = if on_cpu && run_peers(Peer::Onnxruntime) {
        let onnx = onnx_dir.path().join("densedepth.onnx");
        std::fs::write(&onnx, model::onnx::export(&untrained, &model_bundle_file(&config, [h, w]))?)?;
        let onnx = onnx.display().to_string();
        Some(OrtPeer::start(&args.python, &onnx, channels, [h, w], threads, !args.ort_no_spin)?)
    } else {
        None
    };
    let mut ort: Vec<(usize, Summary)> = Vec::new();
    let mut rows = Vec::new();
    for &batch in &args.batches {
        // Inference as `infer` runs it: eval mode, no autodiff, BatchNorms folded.
        let net = untrained.clone().folded();
        let images = Tensor::<4>::random([batch, channels, h, w], Distribution::Uniform(0.0, 1.0), &device);
        let run = || {
            let out = net.forward(images.clone());
            let _ = out.into_data();
        };
        let forward = match ort_peer.as_mut() {
            Some(peer) => {
                let mut cpu_mark = process_cpu_ms();
                let ours = || {
                    let ms = crate::timing::once(run).0 * 1e3;
                    let now = process_cpu_ms();
                    let frame = Frame { ms, cpu_ms: now - cpu_mark };
                    cpu_mark = now;
                    frame
                };
                let gap = std::time::Duration::from_millis(args.pause_ms.unwrap_or(50));
                let both = interleave(args.reps, Pacing::new(gap, spin), ours, || peer.forward(batch))?;
                // Beside the speed, how far apart the two outputs are on one input.
                let values = |t: Tensor<4>| t.into_data().try_into_vec::<f32>().map_err(|e| anyhow::anyhow!("{e:?}"));
                let ours = values(net.forward(images.clone()))?;
                let theirs = peer.depth(onnx_dir.path(), batch, &values(images.clone())?)?;
                let (abs, rel) = difference(&ours, &theirs)?;
                println!(
                    "batch {batch}: flex and ONNX Runtime {} alternately, each forward {} ms after its \
                     previous one (flex's workers polling {} ms, ONNX Runtime's {}): ratio of each pair {}; \
                     CPU ms per frame (the gap and the forward) flex {}, ONNX Runtime {}; outputs {abs:.2e} \
                     apart at most ({rel:.1e} of ONNX Runtime's largest)",
                    peer.version,
                    gap.as_millis(),
                    args.spin_ms,
                    if args.ort_no_spin { "not" } else { "by default" },
                    both.ratio.median_and_quartiles(),
                    both.ours_cpu.median_and_quartiles(),
                    both.peer_cpu.median_and_quartiles(),
                );
                ort.push((batch, both.peer));
                both.ours
            }
            None => time_ms_apart(args.reps, std::time::Duration::from_millis(args.pause_ms.unwrap_or(0)), run),
        };
        // Where the forward time goes: the encoder alone (the decoder is the rest), called as
        // `DenseDepth::forward` calls it, from inside rayon's pool.
        let encoder_ms = time_ms(args.reps, || {
            model::backend::in_pool(|| {
                let _ = net.encoder.forward(images.clone()).norm5.into_data();
            })
        });
        println!(
            "batch {batch}: forward {}, of which encoder {} (medians: decoder {:.2})",
            forward.median_and_quartiles(),
            encoder_ms.median_and_quartiles(),
            forward.median - encoder_ms.median
        );

        if args.stages {
            print_stages(&net, &images, args.reps);
        }
        if args.forward_only {
            rows.push((batch, forward, None));
            continue;
        }
        let train_device = device.clone().autodiff();
        let mut net = config.init(&train_device);
        let mut optim = AdamConfig::new().init();
        let loss_config = DepthLossConfig::new();
        let [oh, ow] = config.output_hw([h, w]);
        if args.pool_hop_ab && devices.len() == 1 {
            pool_hop_ab(&config, &device, [batch, channels, h, w], args.reps);
        }
        let step = if devices.len() == 1 {
            let images = Tensor::<4>::random([batch, channels, h, w], Distribution::Uniform(0.0, 1.0), &train_device);
            let target = Tensor::<4>::random([batch, 1, oh, ow], Distribution::Uniform(10.0, 1000.0), &train_device);
            // From inside rayon's pool, as `train`'s fit runs its steps.
            time_ms(args.reps, || {
                model::backend::in_pool(|| {
                    let loss = loss_config.forward(net.forward(images.clone()), target.clone()).total;
                    let grads = GradientsParams::from_grads(loss.backward(), &net);
                    net = optim.step(1e-4, net.clone(), grads);
                    sync();
                })
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
                    image: (0..channels * h * w).map(|_| rng.unit() as f32).collect(),
                    depth: (0..oh * ow).map(|_| 10.0 + 990.0 * rng.unit() as f32).collect(),
                    pressure: None,
                    force: None,
                    mask: mask.clone(),
                })
                .collect();
            time_ms(args.reps, || {
                let step = parallel.step(&net, items.clone()).expect("training step");
                net = optim.step(1e-4, net.clone(), step.grads);
                sync();
            })
        };
        let loss_ms = loss_alone(&args.recipe, [batch, oh, ow], &train_device, args.reps);
        println!(
            "batch {batch}: train step {}, {:.1} images/s; the recipe's masked loss alone, forward and backward: {}",
            step.median_and_quartiles(),
            batch as f64 * 1e3 / step.median,
            loss_ms.median_and_quartiles()
        );
        rows.push((batch, forward, Some(step)));
    }

    let mut peer: Vec<(usize, Summary, Times)> = Vec::new();
    let mut peer_device = String::from("cpu");
    let batches = args.batches.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(",");
    let [hs, ws, reps, threads, channels_s] = [h, w, args.reps, threads, channels].map(|v| v.to_string());
    let common = ["--height", &hs, "--width", &ws, "--batches", &batches, "--reps", &reps, "--threads", &threads];
    let common = [&common[..], &["--channels", &channels_s]].concat();
    if run_peers(Peer::Pytorch) {
        let [g, i, bn] = [encoder.growth_rate, encoder.num_init_features, encoder.bn_size].map(|v| v.to_string());
        let blocks = encoder.block_config.map(|x| x.to_string()).join(",");
        let device_name = if on_cpu { "cpu" } else { "cuda" };
        let mut torch_args = vec!["--growth", &g, "--blocks", &blocks, "--init", &i, "--bn-size", &bn];
        torch_args.extend(["--device", device_name]);
        torch_args.extend(&common);
        if config.full_resolution {
            torch_args.push("--full-resolution");
        }
        for line in crate::peer::run(&args.python, "densedepth_torch.py", &torch_args)?.lines() {
            if let (Some(batch), Some(f)) = (field(line, "batch="), times(line, "forward")) {
                peer.push((batch as usize, f, times(line, "train")));
            }
            if let Some(d) = line.split_whitespace().find_map(|w| w.strip_prefix("device=")) {
                peer_device = d.to_string();
            }
        }
    }
    println!();
    let peer_name = if peer_device == "cpu" { "PyTorch".to_string() } else { format!("PyTorch {peer_device}") };
    let ms = |v: Option<&Summary>| v.map_or("-".to_string(), Summary::median_and_quartiles);
    // Ratios of medians.
    let ratio = |a: Option<&Summary>, b: Option<&Summary>| match (a, b) {
        (Some(a), Some(b)) => format!("{:.2}", a.median / b.median),
        _ => "-".to_string(),
    };
    println!(
        "| batch | {burn_name} forward ms | {peer_name} forward ms | ratio | ONNX Runtime forward ms | ratio | {burn_name} train step ms | {peer_name} train step ms | ratio |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (batch, f, t) in &rows {
        let p = peer.iter().find(|p| p.0 == *batch);
        let o = ort.iter().find(|o| o.0 == *batch).map(|o| &o.1);
        let (pf, pt) = (p.map(|p| &p.1), p.and_then(|p| p.2.as_ref()));
        let f = Some(f);
        println!(
            "| {batch} | {} | {} | {} | {} | {} | {} | {} | {} |",
            ms(f),
            ms(pf),
            ratio(f, pf),
            ms(o),
            ratio(f, o),
            ms(t.as_ref()),
            ms(pt),
            ratio(t.as_ref(), pt)
        );
    }
    Ok(())
}

/// A peer's `NAME_ms=MEDIAN NAME_q1_ms=Q1 NAME_q3_ms=Q3` as a summary (median and quartiles).
fn times(line: &str, name: &str) -> Option<Summary> {
    let median = field(line, &format!("{name}_ms="))?;
    let q = |k: &str| field(line, &format!("{name}_{k}_ms=")).unwrap_or(f64::NAN);
    Some(Summary { median, q1: q("q1"), q3: q("q3"), ..Summary::of([median]) })
}

/// The inference forward pass and a training step's forward and backward, from the main thread
/// with and without `in_pool`'s hop into rayon's pool, alternated run by run (this VM moves
/// whole runs by more than the difference); checks that inference gives the same output both
/// ways. The training side hops step by step here; `train`'s fit hops once for its whole epoch
/// loop (batch norm's running statistics are kept per thread, so the steps stay on one worker).
fn pool_hop_ab(config: &DenseDepthConfig, device: &burn::tensor::Device, shape: [usize; 4], reps: usize) {
    let [batch, _, h, w] = shape;
    let net = config.init(device).folded();
    let images = Tensor::<4>::random(shape, Distribution::Uniform(0.0, 1.0), device);
    let train_device = device.clone().autodiff();
    let train_net = config.init(&train_device);
    let train_images = Tensor::<4>::random(shape, Distribution::Uniform(0.0, 1.0), &train_device);
    let [oh, ow] = config.output_hw([h, w]);
    let target = Tensor::<4>::random([batch, 1, oh, ow], Distribution::Uniform(10.0, 1000.0), &train_device);
    let loss_config = DepthLossConfig::new();
    let forward = || net.forward(images.clone()).into_data();
    let step = || {
        model::backend::in_pool(|| {
            let loss = loss_config.forward(train_net.forward(train_images.clone()), target.clone()).total;
            GradientsParams::from_grads(loss.backward(), &train_net).len()
        })
    };
    let mut times = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    let mut outputs = [None, None];
    for rep in 0..=reps {
        for (k, hop) in [false, true].into_iter().enumerate() {
            model::backend::set_pool_hop(hop);
            let t = std::time::Instant::now();
            let out = forward();
            let forward_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = std::time::Instant::now();
            std::hint::black_box(step());
            let step_ms = t.elapsed().as_secs_f64() * 1e3;
            // The first round warms up.
            if rep > 0 {
                times[k][0].push(forward_ms);
                times[k][1].push(step_ms);
            }
            outputs[k] = Some(out);
        }
    }
    model::backend::set_pool_hop(true);
    assert_eq!(outputs[0], outputs[1], "the hop changes no output");
    let m = |v: &Vec<f64>| Summary::of(v.clone()).median_and_quartiles();
    println!(
        "batch {batch}, pool hop off / on, alternated: forward {} / {}, train forward and backward {} / {}",
        m(&times[0][0]),
        m(&times[1][0]),
        m(&times[0][1]),
        m(&times[1][1])
    );
}

/// The recipe's training loss (`FitConfig::loss`, the paper's sensor's depth range) over a
/// disk-shaped mask of useful pixels, with targets up to 3 % of the range, forward and backward on
/// a tracked prediction: the loss's share of a step.
fn loss_alone(
    recipe: &train::Recipe,
    [batch, h, w]: [usize; 3],
    device: &burn::tensor::Device,
    reps: usize,
) -> Summary {
    let config = recipe.fit_config(std::path::PathBuf::new());
    let loss = config.loss(&config.scale(sensor::Sensor::default().max_depth_mm));
    let range = config.net_range[1] - config.net_range[0];
    let (cy, cx, r) = (h as f32 / 2.0, w as f32 / 2.0, h.min(w) as f32 / 2.0);
    let disk: Vec<f32> =
        (0..h * w).map(|i| (((i / w) as f32 + 0.5 - cy).hypot((i % w) as f32 + 0.5 - cx) < r) as u8 as f32).collect();
    let mask = Tensor::<4>::from_data(burn::tensor::TensorData::new(disk.repeat(batch), [batch, 1, h, w]), device);
    let target = Tensor::<4>::random([batch, 1, h, w], Distribution::Uniform(0.0, 0.03 * range as f64), device);
    let pred = Tensor::<4>::random([batch, 1, h, w], Distribution::Uniform(0.0, 0.03 * range as f64), device);
    time_ms(reps, || {
        model::backend::in_pool(|| {
            let pred = pred.clone().require_grad();
            let total = loss.forward_masked(pred.clone(), target.clone(), Some(mask.clone())).total;
            let grads = total.backward();
            let _ = pred.grad(&grads).map(|g| g.into_data());
        })
    })
}

/// The description the ONNX export's metadata carries, for a benchmark's untrained network.
pub(crate) fn model_bundle_file(config: &DenseDepthConfig, [h, w]: [usize; 2]) -> model::bundle::BundleFile {
    model::bundle::BundleFile::new(config.clone(), [h, w], sensor::Sensor::default(), model::DepthScale::paper(9.4))
}

/// Each stage's milliseconds of the inference forward over `reps` runs (after one warm-up).
fn print_stages(net: &model::DenseDepth, images: &Tensor<4>, reps: usize) {
    let _ = net.stage_ms(images.clone());
    let runs: Vec<Vec<(&'static str, f64)>> = (0..reps.max(1)).map(|_| net.stage_ms(images.clone())).collect();
    let total = Summary::of(runs.iter().map(|r| r.iter().map(|s| s.1).sum::<f64>()));
    println!("  stages (ms, median [quartiles]; their sum {}):", total.median_and_quartiles());
    for (k, (name, _)) in runs[0].iter().enumerate() {
        let ms = Summary::of(runs.iter().map(|r| r[k].1));
        println!("    {name:<22} {}", ms.median_and_quartiles());
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use model::InputChannels;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn network(argv: &[&str]) -> (DenseDepthConfig, [usize; 2]) {
        Cli::try_parse_from([&["bench"], argv].concat()).unwrap().args.network()
    }

    #[test]
    fn a_recipe_names_the_network_and_flags_change_one_part_of_it() {
        assert_eq!(network(&[]), (train::Recipe::Paper.model_config().unwrap(), [480, 640]));
        assert_eq!(
            network(&["--recipe", "quickstart"]),
            (train::Recipe::Quickstart.model_config().unwrap(), [128, 128])
        );
        let (c, hw) = network(&["--recipe", "quickstart", "--half-resolution", "--input", "rgb", "--height", "96"]);
        assert_eq!((c.full_resolution, c.input, hw), (false, InputChannels::Rgb, [96, 128]));
        assert_eq!(c.encoder, model::Preset::Compact.config());
        assert!(network(&["--preset", "tiny", "--full-resolution"]).0.full_resolution);
        assert!(Cli::try_parse_from(["bench", "--full-resolution", "--half-resolution"]).is_err());
    }

    #[test]
    fn a_peers_line_gives_its_median_and_quartiles() {
        let t = times("batch=4 forward_ms=8.125 forward_q1_ms=8.1 forward_q3_ms=8.2 version=1.32", "forward").unwrap();
        assert_eq!((t.median, t.q1, t.q3), (8.125, 8.1, 8.2));
        assert_eq!(t.median_and_quartiles(), "8.12 [8.10, 8.20]");
        assert!(times("batch=4 train_ms=1.5", "forward").is_none());
        assert!(times("batch=1 forward_ms=3.5", "forward").unwrap().q1.is_nan(), "a peer without quartiles");
    }
}
