//! `infer`: depth maps, contact and point clouds from camera frames with an exported bundle.

#![deny(unsafe_code)]

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use infer::Predictor;
use infer::cloud::ply_bytes;
use infer::eval::CONTACT_THRESHOLD_MM;
use infer::stream::{FolderSink, FolderSource, GlobSource, ReferencePolicy, Sink, Source, StreamLimits};

#[derive(Parser)]
#[command(name = "infer", version, about = "DenseTact depth, contact and point clouds from camera frames")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Predict one frame: 16-bit micrometre depth PNG, false-colour PNG, PLY point cloud, and
    /// with a force bundle the contact pressure and wrench.
    Predict(PredictArgs),
    /// Per-image errors in mm over a dataset's split(s): stats.json, errors.csv, violin.svg.
    Eval {
        /// The bundle folder (`train export`).
        #[arg(long)]
        bundle: PathBuf,
        /// A dataset folder with images (`dataset generate --unit SEED`).
        #[arg(long)]
        data: PathBuf,
        /// train, test or all.
        #[arg(long, default_value = "all")]
        split: String,
        /// Output folder: stats.json, errors.csv, violin.svg.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        loading: Loading,
    },
    /// Frames as they come: depth, contact and point clouds per frame, stale frames dropped
    /// when the network falls behind, throughput and latency percentiles at the end (Ctrl-C
    /// ends a live stream and still writes them).
    Stream(StreamArgs),
    /// Milliseconds per frame, median and quartiles to 0.01 ms (network alone, end to end, a
    /// frame without contact), beside the bundle's recorded test error.
    Bench {
        /// The bundle folder (`train export`).
        #[arg(long)]
        bundle: PathBuf,
        /// A frame with contact (PNG crop); default: the bundle's reference image.
        #[arg(long)]
        image: Option<PathBuf>,
        /// flex (CPU) or wgpu.
        #[arg(long, default_value = "flex")]
        device: String,
        /// Timed repetitions (after warm-up).
        #[arg(long, default_value_t = 20)]
        repeats: usize,
    },
}

fn bench(bundle: PathBuf, image: Option<PathBuf>, device: String, repeats: usize) -> Result<()> {
    let dev = model::backend::working_device(&device)?;
    let predictor = Predictor::load(&bundle, &dev)?;
    let reference = predictor.reference.as_ref().map(sensor::frame::encode_png_rgb);
    let frame = match &image {
        Some(path) => std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?,
        None => reference.clone().context("the bundle has no reference image: give a frame with --image")?,
    };
    let no_contact = reference.as_ref().unwrap_or(&frame);
    let t = infer::bench::time_frames(&predictor, &frame, no_contact, repeats)
        .with_context(|| format!("{}", image.as_deref().unwrap_or(bundle.as_path()).display()))?;
    let f = &predictor.file;
    let test =
        infer::bench::recorded_test_l1_mm(&predictor).map_or("not recorded".to_string(), |v| format!("{v:.4} mm"));
    println!(
        "bundle {}: {} DenseNet (growth {}, blocks {:?}), input {}x{}, device {device}",
        bundle.display(),
        f.model.encoder.preset().map_or("custom", model::Preset::name),
        f.model.encoder.growth_rate,
        f.model.encoder.block_config,
        f.input_height_px,
        f.input_width_px
    );
    println!("ms per frame over {} frames, median [quartiles]:", t.repeats);
    println!("  network only                      {}", t.network_ms.median_and_quartiles());
    println!("  end to end (decode, depth, cloud) {}", t.end_to_end_ms.median_and_quartiles());
    println!("  as `predict` (checks, mask too)   {}", t.as_predict_ms.median_and_quartiles());
    match reference {
        Some(_) => println!("  frame without contact (gated)     {}", t.gated_no_contact_ms.median_and_quartiles()),
        None => println!("  frame without contact             no reference image in the bundle: no gate"),
    }
    println!("test L1 recorded by training (mean per image, useful pixels, network resolution): {test}");
    println!("paper: 18.17 ms per frame, DenseNet-161 at 640x480 on a GPU; test L1 0.281 mm");
    Ok(())
}

/// How `predict`, `stream` and `eval` take their bundle.
#[derive(clap::Args)]
struct Loading {
    /// Keep the network's own reading of the reference frame (by default subtracted).
    #[arg(long)]
    no_tare: bool,
    /// Solve each predicted contact for force with this elastomer, E / (1 - nu^2) in MPa (from
    /// an indentation test or a force-torque sensor, say), instead of the one the bundle
    /// records; a depth-only bundle then reports force too.
    #[arg(long, value_name = "MPA", allow_negative_numbers = true)]
    effective_modulus_mpa: Option<f64>,
}

/// Loads a bundle, tared on its reference image unless `--no-tare`, with the elastomer
/// `--effective-modulus-mpa` names.
fn load(bundle: &std::path::Path, device: &burn::tensor::Device, loading: &Loading) -> Result<Predictor> {
    let mut predictor = Predictor::load(bundle, device)?;
    if loading.no_tare {
        predictor.set_tare(None)?;
    }
    if let Some(e) = loading.effective_modulus_mpa {
        predictor.set_elastomer(Some(model::bundle::ElastomerRecord::given(e))).context("--effective-modulus-mpa")?;
    }
    Ok(predictor)
}

fn eval(bundle: PathBuf, data: PathBuf, split: String, out: PathBuf, loading: Loading) -> Result<()> {
    use formats::Split;
    let splits: Vec<Split> = match split.as_str() {
        "all" => vec![Split::Train, Split::Test],
        "train" => vec![Split::Train],
        "test" => vec![Split::Test],
        other => anyhow::bail!("--split must be train, test or all, got {other:?}"),
    };
    let predictor = load(&bundle, &model::backend::default_device(), &loading)?;
    infer::eval::evaluate_dataset(&predictor, &data, &splits, &out)?;
    println!("wrote {}/stats.json, errors.csv, violin.svg", out.display());
    Ok(())
}

fn predict(args: PredictArgs) -> Result<()> {
    let PredictArgs { bundle, image, depth_out, depth_npy, colour_out, ply, pressure_out, always, loading } = args;
    // Outputs are checked before any work: none may be an input, none named twice.
    let outputs: Vec<&std::path::Path> =
        [&depth_out, &depth_npy, &colour_out, &ply, &pressure_out].into_iter().flatten().map(|p| p.as_path()).collect();
    let inputs = [image.as_path(), bundle.as_path()];
    for out in &outputs {
        formats::output::check_file(out, &inputs)?;
    }
    formats::output::check_distinct(&outputs)?;
    let predictor = load(&bundle, &model::backend::default_device(), &loading)?;
    if pressure_out.is_some() && !predictor.has_force() {
        anyhow::bail!(
            "{}: this bundle has no force output, so there is no pressure to write (it records no elastomer to \
             solve the contact with, and its network has no pressure output: export it from data with force \
             labels, or train with --force-weight)",
            bundle.display()
        );
    }
    let frame = predictor.read_frame(&image)?;
    let start = Instant::now();
    let prediction = if always {
        predictor.predict_network_all(std::slice::from_ref(&frame)).map(|mut v| v.remove(0))
    } else {
        predictor.predict_all(&frame)
    }
    .with_context(|| format!("{}", image.display()))?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let depth = prediction.depth;
    let contact = Predictor::contact_mask(&depth, CONTACT_THRESHOLD_MM);
    let pressed = contact.iter().filter(|&&c| c).count();
    println!(
        "{}: {pressed} contact pixels ({:.2} % of the useful disk), max depth {:.3} mm, {ms:.1} ms",
        image.display(),
        100.0 * pressed as f64 / predictor.mask.iter().filter(|&&m| m).count().max(1) as f64,
        depth.max_mm()
    );
    if let Some(force) = &prediction.force {
        println!("{}", infer::predictor::force_line(force));
    }
    // Every output is made first, then all are written together: a failure leaves none.
    let mut files: Vec<(&std::path::Path, Vec<u8>)> = Vec::new();
    if let (Some(path), Some(force)) = (&pressure_out, &prediction.force) {
        files.push((path, force.pressure.to_png()));
    }
    if let Some(path) = &depth_out {
        files.push((path, depth.to_png_um()));
    }
    if let Some(path) = &depth_npy {
        files.push((path, depth.to_npy()));
    }
    if let Some(path) = &colour_out {
        let img = infer::colour::false_colour(&depth, &predictor.mask, predictor.file.sensor.max_depth_mm as f32);
        files.push((path, sensor::frame::encode_png_rgb(&img)));
    }
    let cloud = ply.as_ref().map(|_| predictor.point_cloud(&depth, CONTACT_THRESHOLD_MM));
    if let (Some(path), Some(cloud)) = (&ply, &cloud) {
        files.push((path, ply_bytes(cloud)));
    }
    let refs: Vec<(&std::path::Path, &[u8])> = files.iter().map(|(p, b)| (*p, b.as_slice())).collect();
    formats::fs::write_files_atomic(&refs)?;
    for (path, _) in &files {
        println!("wrote {}", path.display());
    }
    if let Some(cloud) = cloud {
        println!("the point cloud has {} points", cloud.points_mm.len());
    }
    Ok(())
}

/// What `infer predict` is told.
#[derive(clap::Args)]
struct PredictArgs {
    /// The bundle folder (`train export`).
    #[arg(long)]
    bundle: PathBuf,
    /// A camera frame (PNG or JPEG): the camera's full frame, cut around the bundle's
    /// calibrated optical centre, or the sensor's crop as the dataset stores it.
    #[arg(long)]
    image: PathBuf,
    /// Depth map to write: 16-bit PNG, micrometres, on the sensor's crop.
    #[arg(long)]
    depth_out: Option<PathBuf>,
    /// Depth map to write exactly: float32 millimetres on the sensor's crop, NumPy's `.npy`
    /// (`numpy.load`).
    #[arg(long)]
    depth_npy: Option<PathBuf>,
    /// False-colour depth for people.
    #[arg(long)]
    colour_out: Option<PathBuf>,
    /// Point cloud of the contact patch (sensor frame, mm).
    #[arg(long)]
    ply: Option<PathBuf>,
    /// Contact pressure to write (a bundle with the force output): 16-bit PNG, 0.1 kPa a
    /// step, on the sensor's crop (the dataset's pressure format).
    #[arg(long)]
    pressure_out: Option<PathBuf>,
    /// Run the network even when the frame shows no contact.
    #[arg(long)]
    always: bool,
    #[command(flatten)]
    loading: Loading,
}

/// What `infer stream` is told.
#[derive(clap::Args)]
struct StreamArgs {
    /// The bundle folder (`train export`).
    #[arg(long)]
    bundle: PathBuf,
    /// A folder (its new frames, each once, in name order, as they appear), a glob of
    /// existing frames (quote it: 'frames/*.png'), or a V4L2 camera (/dev/videoN, with the
    /// `v4l2` feature).
    #[arg(long)]
    source: String,
    /// Per frame depth/NAME.png (16-bit, micrometres) and cloud/NAME.ply (contact frames);
    /// stream.json and frames.csv at the end.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Release a glob's frames at this rate, as a camera would (stale ones dropped);
    /// without it every frame is processed, in order, as fast as the network goes.
    #[arg(long)]
    fps: Option<f64>,
    /// Stop after this many processed frames (at least 1).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    max_frames: Option<u64>,
    /// Folder source: stop after this many seconds without a new frame (default: run
    /// until Ctrl-C).
    #[arg(long)]
    idle_exit_s: Option<f64>,
    /// Folder source: how often to look for new frames.
    #[arg(long, default_value_t = 5)]
    poll_ms: u64,
    /// flex (CPU) or wgpu.
    #[arg(long, default_value = "flex")]
    device: String,
    /// On the CPU, keep all but one of the network's worker threads polling for work this long
    /// after each frame instead of sleeping, as ONNX Runtime's do by default (about 60 ms): a
    /// frame then need not wait for a sleeping core to wake (the quickstart's network at 20
    /// fps on a 2-vCPU VM: 4.4 ms a frame against 5.9), for the price of a core kept busy
    /// between frames (58 ms of CPU per 50 ms frame against 6). A frame period or a little
    /// more (40 at 30 fps) keeps them polling while frames come; 0, the default, lets them sleep.
    #[arg(long, default_value_t = 0)]
    spin_ms: u64,
    #[command(flatten)]
    loading: Loading,
    /// Keep the bundle's reference frame for the whole stream. By default it follows the
    /// camera, slowly, from frames with no contact (2 s after the last contact, averaged over
    /// 5 s, a quarter of the way each time; a contact never enters it); each frame's global
    /// drift is taken out either way (BENCHMARKS.md, "A drifting camera").
    #[arg(long)]
    fixed_reference: bool,
    /// The default since following was measured better; accepted for scripts that name it.
    #[arg(long, hide = true, conflicts_with = "fixed_reference")]
    follow_reference: bool,
    /// ROS 2 output.
    #[command(flatten)]
    ros2: Ros2Args,
    /// The live view: each frame, its contact mask, its depth in false colour, the contact
    /// patch's points (with a force bundle the pressure and the force) and the rates.
    #[command(flatten)]
    view: view::ViewArgs,
    /// With a view: the pictures (the frame, its mask, depth, cloud and pressure) of every Nth
    /// frame only, from the first; the time series and the force of every frame.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    view_every: u32,
    /// With a view: the frames as JPEG of this quality (1..100) instead of raw RGB, for smaller
    /// recordings at the cost of encoding each frame; the depth is 16-bit micrometres either way.
    #[arg(long, value_name = "QUALITY", value_parser = clap::value_parser!(u8).range(1..=100))]
    view_jpeg_quality: Option<u8>,
}

/// The source a `--source` names: a camera device, a folder, or a glob (a single file too).
fn stream_source(
    source: &str,
    fps: Option<f64>,
    poll_ms: u64,
    idle_exit_s: Option<f64>,
    sensor: &sensor::Sensor,
) -> Result<Box<dyn Source>> {
    if source.starts_with("/dev/video") {
        return camera(source, fps, sensor);
    }
    let path = std::path::Path::new(source);
    if path.is_dir() {
        if fps.is_some() {
            anyhow::bail!("--fps paces a glob of existing frames; a folder's frames come at their own rate");
        }
        let idle = match idle_exit_s {
            Some(s) if !(s.is_finite() && s > 0.0) => anyhow::bail!("--idle-exit-s must be positive, got {s}"),
            s => s.map(std::time::Duration::from_secs_f64),
        };
        let (folder, already) = FolderSource::new(path, std::time::Duration::from_millis(poll_ms.max(1)), idle)
            .with_context(|| format!("{source}: cannot watch the folder"))?;
        if already > 0 {
            eprintln!(
                "{source}: {already} frames already there are not read (a glob reads them: --source '{source}/*.png')"
            );
        }
        return Ok(Box::new(folder));
    }
    Ok(Box::new(GlobSource::new(source, fps)?))
}

#[cfg(feature = "v4l2")]
fn camera(device: &str, fps: Option<f64>, sensor: &sensor::Sensor) -> Result<Box<dyn Source>> {
    let camera = infer::stream::CameraSource::open(device, sensor.frame_width_px, sensor.frame_height_px, fps)
        .with_context(|| format!("{device}: cannot stream"))?;
    Ok(Box::new(camera))
}

#[cfg(not(feature = "v4l2"))]
fn camera(device: &str, _fps: Option<f64>, _sensor: &sensor::Sensor) -> Result<Box<dyn Source>> {
    anyhow::bail!("{device}: this infer was built without V4L2 cameras; build it with `--features v4l2`")
}

#[derive(clap::Args)]
struct Ros2Args {
    /// Publish on ROS 2 (build with `--features ros2`): NAMESPACE/points (PointCloud2,
    /// metres, sensor frame), NAMESPACE/depth (Image 32FC1, metres), NAMESPACE/contact
    /// (String, JSON summary).
    #[arg(long)]
    ros2: bool,
    /// ROS 2 namespace of the published topics.
    #[arg(long, default_value = "/densetact")]
    ros2_namespace: String,
    /// The DDS domain (default: $ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    ros2_domain: Option<u16>,
    /// The messages' frame_id: the sensor frame's name in the robot's TF tree.
    #[arg(long, default_value = "densetact")]
    frame_id: String,
}

impl Ros2Args {
    /// The domain asked for, else ROS 2's environment variable, else 0; ROS 2 allows 0..=232.
    #[cfg(feature = "ros2")]
    fn domain(&self) -> Result<u16> {
        let domain = match (self.ros2_domain, std::env::var("ROS_DOMAIN_ID")) {
            (Some(d), _) => d,
            (None, Ok(v)) if !v.trim().is_empty() => {
                v.trim().parse().with_context(|| format!("ROS_DOMAIN_ID={v:?} is not a domain number"))?
            }
            _ => 0,
        };
        anyhow::ensure!(domain <= 232, "ROS 2 domain {domain}: ROS 2 domains are 0 to 232");
        Ok(domain)
    }

    #[cfg(feature = "ros2")]
    fn sink(&self) -> Result<Option<Box<dyn Sink>>> {
        if !self.ros2 {
            return Ok(None);
        }
        let sink = infer::stream::Ros2Sink::new(&self.ros2_namespace, &self.frame_id, self.domain()?);
        Ok(Some(Box::new(sink?)))
    }

    #[cfg(not(feature = "ros2"))]
    fn sink(&self) -> Result<Option<Box<dyn Sink>>> {
        anyhow::ensure!(!self.ros2, "--ros2: this infer was built without ROS 2; build it with `--features ros2`");
        Ok(None)
    }
}

fn stream(args: StreamArgs) -> Result<()> {
    let StreamArgs {
        bundle,
        source,
        out,
        fps,
        max_frames,
        idle_exit_s,
        poll_ms,
        device,
        spin_ms,
        loading,
        fixed_reference,
        follow_reference: _,
        ros2,
        view,
        view_every,
        view_jpeg_quality,
    } = args;
    let mut ros2 = ros2.sink()?;
    let view = view.target().map_err(anyhow::Error::msg)?;
    let source_path = std::path::Path::new(&source);
    if let Some(out) = &out {
        let watched = if source_path.is_dir() { Some(source_path) } else { None };
        let inputs: Vec<&std::path::Path> = [Some(bundle.as_path()), watched].into_iter().flatten().collect();
        formats::output::check_dir(out, formats::output::OutputKind::Stream, &inputs)?;
    }
    let dev = model::backend::working_device(&device)?;
    model::backend::set_spin(std::time::Duration::from_millis(spin_ms));
    let predictor = load(&bundle, &dev, &loading)?;
    let source = stream_source(&source, fps, poll_ms, idle_exit_s, &predictor.file.sensor)?;
    let mut folder = out.as_deref().map(FolderSink::new).transpose()?;
    #[cfg(feature = "view")]
    let mut view = view
        .as_ref()
        .map(|t| infer::stream::ViewSink::open(t, view_every, view_jpeg_quality, predictor.has_force()))
        .transpose()?;
    // Without the feature, `target` refused any view already.
    #[cfg(not(feature = "view"))]
    let _ = (view, view_every, view_jpeg_quality);
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, std::sync::atomic::Ordering::Relaxed))
            .context("cannot install the Ctrl-C handler")?;
    }
    eprintln!("streaming {}; Ctrl-C ends it", source.describe());
    let mut sinks: Vec<&mut dyn Sink> = Vec::new();
    if let Some(folder) = folder.as_mut() {
        sinks.push(folder);
    }
    if let Some(ros2) = ros2.as_mut() {
        sinks.push(ros2.as_mut());
    }
    #[cfg(feature = "view")]
    if let Some(view) = view.as_mut() {
        sinks.push(view);
    }
    let reference = if fixed_reference { ReferencePolicy::Fixed } else { ReferencePolicy::default() };
    let limits = StreamLimits { max_frames, progress_every: Some(std::time::Duration::from_secs(5)), reference };
    let report = infer::stream::run(&predictor, source, &mut sinks, &limits, &stop)?;
    println!("{}", report.summary());
    for line in sinks.iter().filter_map(|s| s.summary()) {
        println!("{line}");
    }
    let test = infer::bench::recorded_test_l1_mm(&predictor).map_or("not recorded".into(), |v| format!("{v:.4} mm"));
    println!("the bundle's test L1 recorded by training (useful pixels): {test}");
    if let (Some(folder), Some(out)) = (&folder, &out) {
        folder.finish(&report)?;
        println!("wrote {}/stream.json, frames.csv, depth/, cloud/", out.display());
    }
    #[cfg(feature = "view")]
    if let Some(path) = view.map(infer::stream::ViewSink::finish).transpose()?.flatten() {
        println!("wrote {} (open it with `rerun {}`)", path.display(), path.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    model::backend::cpu_unless_asked();
    sensor::alloc::keep_freed_memory();
    let result = match Cli::parse().command {
        Command::Predict(args) => predict(args),
        Command::Eval { bundle, data, split, out, loading } => eval(bundle, data, split, out, loading),
        Command::Stream(args) => stream(args),
        Command::Bench { bundle, image, device, repeats } => bench(bundle, image, device, repeats),
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
