//! `cargo xtask quickstart`: the whole pipeline on the embedded kit, on the CPU, in one folder.
//!
//! Generate a dataset with a simulated unit's images, train the compact preset, export the
//! bundle, evaluate both splits, write example triplets and a point cloud, print a summary.
//! Every stage resumes: run the same command again after an interruption.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use dataset::generate::{generate_with_unit, report_lines};
use dataset::{Kit, Renderer, SensorUnit, Split};
use formats::dataset::{GeneratorParams, Manifest};
use infer::eval::{CONTACT_THRESHOLD_MM, SplitStats};
use infer::{Predictor, write_ply};
use model::DenseDepthConfig;
use train::{FitConfig, Recipe, Start, fit};

#[derive(clap::Args)]
pub struct Args {
    /// Output folder (dataset, run, bundle, evaluation, examples).
    #[arg(long, default_value = "out/quickstart")]
    out: PathBuf,
    /// Tiny sizes (CI): 16 samples, the tiny preset at 64x64, one epoch.
    #[arg(long)]
    smoke: bool,
    /// Samples to generate (default 1000; smoke 16).
    #[arg(long)]
    samples: Option<u32>,
    /// Training epochs (default 14; smoke 1).
    #[arg(long)]
    epochs: Option<usize>,
    /// The simulated sensor unit.
    #[arg(long, default_value_t = 7)]
    unit: u64,
    /// What the network reads: `rgb-difference` (RGB and its difference to the unit's
    /// reference frame) or `rgb` (the paper's).
    #[arg(long, default_value = "rgb-difference")]
    channels: model::InputChannels,
    /// Output at half the input's resolution (DenseDepth's) instead of at the input's.
    #[arg(long)]
    half_resolution: bool,
    /// Weight of the training loss's extra L1 term over contact pixels (0: DenseDepth's loss).
    #[arg(long, default_value_t = 5.0)]
    contact_weight: f64,
    /// Weight of the force outputs' terms (0: depth alone, the reported force then the contact
    /// solved on the predicted depth; above 0 the network gains the pressure output and the
    /// force head, whose force is reported).
    #[arg(long, default_value_t = train::FitConfig::DEFAULT_FORCE_WEIGHT)]
    force_weight: f64,
    /// Training seeds: the first trains the bundle the examples come from; each further one
    /// trains again (run, bundle, test evaluation under `seeds/N/`), and the summary gives
    /// every headline figure as mean and spread over all of them.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=16))]
    seeds: u64,
}

/// What a run is made of; the smoke run shrinks every size.
struct Plan {
    samples: u32,
    epochs: usize,
    preset: model::Preset,
    input: usize,
    batch: usize,
    examples: usize,
}

/// The paper's test error (mean per-image L1, useful pixels, mm).
const PAPER_TEST_L1_MM: f64 = 0.281;
/// The force goal: the test split's mean total-force error at most this share (%) of its mean
/// total force.
const FORCE_GOAL_PCT: f64 = 3.0;
/// What a user needs where the sensor is pressed: contact depth to a fifth of a millimetre.
const CONTACT_GOAL_MM: f64 = 0.20;
/// And over all useful pixels.
const USEFUL_GOAL_MM: f64 = 0.08;

pub fn run(args: Args) -> Result<()> {
    let started = Instant::now();
    let plan = if args.smoke {
        Plan { samples: 16, epochs: 1, preset: model::Preset::Tiny, input: 64, batch: 2, examples: 2 }
    } else {
        let (net, fit) = (Recipe::Quickstart.network(), Recipe::Quickstart.fit_config(Default::default()));
        Plan {
            samples: 1000,
            epochs: fit.epochs,
            preset: net.preset,
            input: net.input_hw[0],
            batch: fit.batch,
            examples: 4,
        }
    };
    let plan =
        Plan { samples: args.samples.unwrap_or(plan.samples), epochs: args.epochs.unwrap_or(plan.epochs), ..plan };
    let out = &args.out;
    let (data, run_dir, bundle, eval_dir, examples) =
        (out.join("dataset"), out.join("run"), out.join("bundle"), out.join("eval"), out.join("examples"));

    println!("[1/5] dataset: {} scenes from the embedded kit, simulated unit {}", plan.samples, args.unit);
    let kit = Kit::procedural(25.0);
    // One scene in ten with the rig lifted clear: the network must learn to answer zeros where
    // nothing touches, as the contact gate does.
    let params = GeneratorParams { lifted_fraction: 0.1, ..GeneratorParams::new(0, plan.samples, &kit.source) };
    let report = generate_with_unit(&data, &kit, args.unit, 25.0, params)
        .with_context(|| format!("generating {}", data.display()))?;
    let scene_lines = report_lines(&report);

    println!("[2/5] training: {} preset at {2}x{2}, {} epochs, flex on the CPU", plan.preset, plan.epochs, plan.input);
    let device = model::backend::default_device();
    let fitted = train_seed(&args, &plan, &data, &run_dir, 0, &device)?;

    println!("[3/5] bundle: {}", bundle.display());
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[&run_dir])?;

    println!("[4/5] evaluation of both splits: {}", eval_dir.display());
    let mut predictor = Predictor::load(&bundle, &device)?;
    let stats = infer::eval::evaluate_dataset(&predictor, &data, &[Split::Train, Split::Test], &eval_dir)?;

    println!("[5/5] examples: {}", examples.display());
    let manifest = Manifest::load(&data)?;
    write_examples(&predictor, &data, &manifest, &examples, plan.examples)?;
    let frame_ms = time_one_frame(&predictor, &data, &manifest)?;
    let renderer = Renderer::for_crop(&SensorUnit::from_seed(args.unit, 25.0));
    let untouched = untouched_frames(&mut predictor, &renderer, if args.smoke { 2 } else { 20 })?;

    let mut test_stats: Vec<SplitStats> = stats.get(&Split::Test).cloned().into_iter().collect();
    for seed in 1..args.seeds {
        let dir = out.join("seeds").join(seed.to_string());
        println!("[seed {seed}] training, bundle and test evaluation: {}", dir.display());
        let fitted = train_seed(&args, &plan, &data, &dir.join("run"), seed, &device)?;
        let bundle = dir.join("bundle");
        train::export::export_net(&fitted.net, &fitted.state, &bundle, &[&dir.join("run")])?;
        let predictor = Predictor::load(&bundle, &device)?;
        let stats = infer::eval::evaluate_dataset(&predictor, &data, &[Split::Test], &dir.join("eval"))?;
        test_stats.extend(stats.get(&Split::Test).cloned());
    }

    check_outputs(out)?;
    let force_source = predictor.force_source().unwrap_or("none");
    print_summary(&stats, &scene_lines, frame_ms, &fitted.state, started.elapsed().as_secs_f64(), out, force_source);
    print_seed_spread(&test_stats);
    println!("{untouched}");
    Ok(())
}

/// Trains (or resumes) the quickstart's recipe with `seed` in `run_dir`.
fn train_seed(
    args: &Args,
    plan: &Plan,
    data: &Path,
    run_dir: &Path,
    seed: u64,
    device: &burn::tensor::Device,
) -> Result<train::Fitted> {
    let config = FitConfig {
        epochs: plan.epochs,
        batch: plan.batch,
        seed,
        warmup_steps: if args.smoke { 0 } else { 100 },
        contact_weight: args.contact_weight,
        force_weight: args.force_weight,
        ..recipe(data, plan.input)
    };
    let start = Start {
        model_config: network(plan.preset).with_input(args.channels).with_full_resolution(!args.half_resolution),
        weights: None,
    };
    fit(run_dir, &config, start, device, true).context("training (run again to resume)")
}

/// The quickstart's training recipe on `data` at `input` px square: `train fit`'s default
/// recipe (`train::Recipe::Quickstart`), the same settings whatever the input size.
pub fn recipe(data: &Path, input: usize) -> FitConfig {
    FitConfig { input_hw: [input, input], ..Recipe::Quickstart.fit_config(data.to_path_buf()) }
}

/// The quickstart's network: `preset` reading RGB and its difference to the unit's reference,
/// output at the input's resolution.
pub fn network(preset: model::Preset) -> DenseDepthConfig {
    DenseDepthConfig::new(preset.config()).with_input(model::InputChannels::RgbDifference).with_full_resolution(true)
}

/// The test split's headline figures over the seeds: mean, sample standard deviation, range.
fn print_seed_spread(test: &[SplitStats]) {
    if test.len() < 2 {
        return;
    }
    println!(
        "
test split over {} training seeds (mean ± sd [min, max] of the per-seed means, mm):",
        test.len()
    );
    type Figure = fn(&SplitStats) -> f64;
    let figures: [(&str, Figure); 3] = [
        ("contact L1", |s| s.contact_l1_mm.mean),
        ("L1", |s| s.l1_mm.mean),
        ("boundary L1", |s| s.boundary_l1_mm.mean),
    ];
    for (name, f) in figures {
        let spread = infer::eval::Summary::of(test.iter().map(f));
        println!("  {name:12} {:.4} ± {:.4} [{:.4}, {:.4}]", spread.mean, spread.sd, spread.min, spread.max);
    }
    let forces: Vec<&infer::eval::ForceStats> = test.iter().filter_map(|s| s.force.as_ref()).collect();
    if !forces.is_empty() {
        let error = infer::eval::Summary::of(forces.iter().map(|f| f.force_magnitude_error_n.mean));
        let pct = infer::eval::Summary::of(forces.iter().map(|f| f.force_magnitude_error_pct));
        let unsolved: usize = forces.iter().map(|f| f.unsolved_frames).sum();
        println!(
            "  total force error {:.4} ± {:.4} N [{:.4}, {:.4}], {:.2} ± {:.2} % of the mean force; {unsolved} \
             test frames unsolved",
            error.mean, error.sd, error.min, error.max, pct.mean, pct.sd
        );
        println!(
            "goal (mean of seeds): total force error at most {FORCE_GOAL_PCT} % of the mean force, every frame \
             solved: {}",
            if pct.mean <= FORCE_GOAL_PCT && unsolved == 0 { "met" } else { "NOT met" }
        );
    }
    let contact = infer::eval::Summary::of(test.iter().map(|s| s.contact_l1_mm.mean)).mean;
    let l1 = infer::eval::Summary::of(test.iter().map(|s| s.l1_mm.mean)).mean;
    let verdict = |ok: bool| if ok { "met" } else { "NOT met" };
    println!(
        "goals (mean of seeds): contact L1 {contact:.4} mm at most {CONTACT_GOAL_MM} mm: {}; L1 {l1:.4} mm at most {USEFUL_GOAL_MM} mm: {}",
        verdict(contact <= CONTACT_GOAL_MM),
        verdict(l1 <= USEFUL_GOAL_MM)
    );
}

/// Test images with contact: camera image, true and predicted depth in false colour; the
/// first one's predicted contact patch as a PLY.
fn write_examples(predictor: &Predictor, data: &Path, manifest: &Manifest, dir: &Path, count: usize) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let max = predictor.file.sensor.max_depth_mm as f32;
    let mut chosen: Vec<_> = manifest.samples.iter().filter(|s| s.split == Split::Test).collect();
    // Pressed frames first, a spread of contact sizes among them.
    chosen.sort_by(|a, b| b.stats.contact_fraction.total_cmp(&a.stats.contact_fraction));
    let step = (chosen.len() / count.max(1)).max(1);
    const TILE_PX: u32 = 285;
    let mut rows = Vec::new();
    for (k, s) in chosen.into_iter().step_by(step).take(count).enumerate() {
        let image_path = data.join(s.image.as_ref().context("the dataset has no images")?);
        let frame = sensor::frame::read(&image_path)?;
        let truth = sensor::DepthMap::load_png_um(&data.join(&s.depth))?;
        let pred = predictor.predict(&frame)?;
        let name = format!("{:06}", s.id);
        let true_colour = infer::colour::false_colour(&truth, &predictor.mask, max);
        let pred_colour = infer::colour::false_colour(&pred, &predictor.mask, max);
        save_png(&dir.join(format!("{name}_image.png")), &frame)?;
        save_png(&dir.join(format!("{name}_true.png")), &true_colour)?;
        save_png(&dir.join(format!("{name}_pred.png")), &pred_colour)?;
        rows.push([frame, true_colour, pred_colour]);
        if k == 0 {
            write_ply(&dir.join(format!("{name}_pred.ply")), &predictor.point_cloud(&pred, CONTACT_THRESHOLD_MM))?;
        }
    }
    // One picture for people: a row per example, camera image | true depth | predicted depth.
    let mut sheet = image::RgbImage::new(3 * TILE_PX, TILE_PX * rows.len().max(1) as u32);
    for (r, row) in rows.iter().enumerate() {
        for (c, img) in row.iter().enumerate() {
            let tile = image::imageops::resize(img, TILE_PX, TILE_PX, image::imageops::FilterType::Triangle);
            image::imageops::replace(&mut sheet, &tile, (c as u32 * TILE_PX) as i64, (r as u32 * TILE_PX) as i64);
        }
    }
    save_png(&dir.join("triplets.png"), &sheet)?;
    Ok(())
}

fn save_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    Ok(formats::fs::write_atomic(path, &sensor::frame::encode_png_rgb(img))?)
}

/// Median network-only milliseconds per frame on the first test image.
fn time_one_frame(predictor: &Predictor, data: &Path, manifest: &Manifest) -> Result<f64> {
    let sample = manifest.samples.iter().find(|s| s.split == Split::Test).context("no test samples")?;
    let path = data.join(sample.image.as_ref().context("the dataset has no images")?);
    let png = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(infer::bench::time_frames(predictor, &png, &png, 5)?.network_ms.median)
}

/// Frames without contact (the unit's reference with fresh noise): how often the gate skips
/// the network, what the network would have said (tared, as `predict` runs it, and untared), and
/// the time saved.
fn untouched_frames(predictor: &mut Predictor, renderer: &Renderer, count: u64) -> Result<String> {
    let zeros = vec![0f32; renderer.grid().len()];
    let frames: Vec<_> = (0..count).map(|seed| renderer.render(&zeros, Some(1_000_000 + seed))).collect();
    let (mut skipped, mut gate_s) = (0, 0f64);
    for frame in &frames {
        let t = Instant::now();
        let (_, ran) = predictor.predict_gated(frame)?;
        if !ran {
            skipped += 1;
            gate_s += t.elapsed().as_secs_f64();
        }
    }
    let t = Instant::now();
    let tared = NetworkOnQuiet::of(predictor, &frames)?;
    let net_ms = 1e3 * t.elapsed().as_secs_f64() / count.max(1) as f64;
    let reference = predictor.reference.clone();
    predictor.set_tare(None)?;
    let untared = NetworkOnQuiet::of(predictor, &frames)?;
    predictor.set_tare(reference.as_ref())?;
    let agree = if tared.max_mm <= CONTACT_THRESHOLD_MM { "equal within" } else { "NOT equal within" };
    Ok(format!(
        "frames without contact ({count}, rendered with noise): the gate skipped {skipped}, in {:.2} ms each against \
         {net_ms:.1} ms for the network, whose depth on them (tared on the reference image) peaks at {:.4} mm with \
         {:.3} % of useful pixels above the {CONTACT_THRESHOLD_MM} mm contact threshold (untared: {:.4} mm, {:.3} %): \
         gate and network {agree} the threshold",
        1e3 * gate_s / skipped.max(1) as f64,
        tared.max_mm,
        tared.above_percent,
        untared.max_mm,
        untared.above_percent,
    ))
}

/// The network's depth on frames without contact: its peak, and the share of useful pixels it
/// would call contact.
struct NetworkOnQuiet {
    max_mm: f32,
    above_percent: f64,
}

impl NetworkOnQuiet {
    fn of(predictor: &Predictor, frames: &[image::RgbImage]) -> Result<Self> {
        let useful = predictor.mask.iter().filter(|&&m| m).count().max(1);
        let (mut max_mm, mut above) = (0f32, 0usize);
        for frame in frames {
            let net = predictor.predict_network(std::slice::from_ref(frame))?.remove(0);
            max_mm = max_mm.max(net.max_mm());
            above += net.depth_mm.iter().filter(|&&d| d > CONTACT_THRESHOLD_MM).count();
        }
        Ok(NetworkOnQuiet { max_mm, above_percent: 100.0 * above as f64 / (useful * frames.len()).max(1) as f64 })
    }
}

/// The outputs a user is pointed to exist and parse.
fn check_outputs(out: &Path) -> Result<()> {
    let stats_path = out.join("eval/stats.json");
    let stats: std::collections::BTreeMap<Split, infer::eval::SplitStats> = serde_json::from_str(
        &std::fs::read_to_string(&stats_path).with_context(|| format!("{}: missing", stats_path.display()))?,
    )
    .with_context(|| format!("{}: not the evaluation's figures", stats_path.display()))?;
    for split in [Split::Train, Split::Test] {
        let figures = stats.get(&split).with_context(|| format!("{}: no {split} split", stats_path.display()))?;
        for (key, summary) in figures.summaries() {
            ensure!(!summary.mean.is_nan(), "{}: no {split}.{key}.mean", stats_path.display());
        }
    }
    let svg_path = out.join("eval/violin.svg");
    let svg = std::fs::read_to_string(&svg_path).with_context(|| format!("{}: missing", svg_path.display()))?;
    ensure!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{}: not an SVG", svg_path.display());
    let dir = out.join("examples");
    let mut pngs = 0;
    let mut plys = 0;
    for entry in std::fs::read_dir(&dir).with_context(|| format!("{}: missing", dir.display()))? {
        let path = entry?.path();
        match path.extension().and_then(|e| e.to_str()) {
            Some("png") => {
                image::open(&path).with_context(|| format!("{}: not a readable PNG", path.display()))?;
                pngs += 1;
            }
            Some("ply") => {
                infer::cloud::read_ply(&path)?;
                plys += 1;
            }
            _ => {}
        }
    }
    if pngs < 3 || plys == 0 {
        bail!("{}: expected example PNGs and a PLY, found {pngs} PNGs and {plys} PLY files", dir.display());
    }
    Ok(())
}

fn print_summary(
    stats: &std::collections::BTreeMap<Split, SplitStats>,
    scene_lines: &[String],
    frame_ms: f64,
    state: &train::checkpoint::RunState,
    seconds: f64,
    out: &Path,
    force_source: &str,
) {
    println!("\nscenes (contact statistics, so the errors can be read against them):");
    for line in scene_lines {
        println!("{line}");
    }
    println!(
        "\nmean per-image errors (mm): true contact pixels, useful pixels (the paper's), and within {} px of a contact edge:",
        infer::eval::BOUNDARY_PX
    );
    println!(
        "| split | images | contact L1 | zeros contact L1 | ratio | L1 | zeros L1 | boundary L1 | zeros boundary L1 | L2 (mm^2) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, s) in stats {
        println!(
            "| {name} | {} | {:.4} | {:.4} | {:.2} | {:.4} | {:.4} | {:.4} | {:.4} | {:.5} |",
            s.l1_mm.n,
            s.contact_l1_mm.mean,
            s.zero_contact_l1_mm.mean,
            s.contact_ratio(),
            s.l1_mm.mean,
            s.zero_l1_mm.mean,
            s.boundary_l1_mm.mean,
            s.zero_boundary_l1_mm.mean,
            s.l2_mm.mean
        );
    }
    if let Some(test) = stats.get(&Split::Test) {
        let verdict = |ok: bool| if ok { "met" } else { "NOT met" };
        println!(
            "goals: test contact L1 {:.4} mm at most {CONTACT_GOAL_MM} mm: {}; test L1 {:.4} mm below the paper's {PAPER_TEST_L1_MM} mm: {}",
            test.contact_l1_mm.mean,
            verdict(test.contact_l1_mm.mean <= CONTACT_GOAL_MM),
            test.l1_mm.mean,
            verdict(test.l1_mm.mean < PAPER_TEST_L1_MM),
        );
    }
    if stats.values().any(|s| s.force.is_some()) {
        println!("\ncontact force (from {force_source}; truth: the labels' elastic contact, N):");
        println!(
            "| split | images | mean force | total force error | % of mean | force vector error | pressure L1 (kPa) |"
        );
        println!("|---|---:|---:|---:|---:|---:|---:|");
        for (name, f) in stats.iter().filter_map(|(n, s)| s.force.as_ref().map(|f| (n, f))) {
            println!(
                "| {name} | {} | {:.3} | {:.4} | {:.2} | {:.4} | {:.3} |",
                f.force_n.n,
                f.force_n.mean,
                f.force_magnitude_error_n.mean,
                f.force_magnitude_error_pct,
                f.force_error_n.mean,
                f.pressure_l1_kpa.mean
            );
        }
        if let Some(f) = stats.get(&Split::Test).and_then(|s| s.force.as_ref()) {
            println!(
                "goal: test total force error {:.2} % of the mean force ({} frames unsolved), at most \
                 {FORCE_GOAL_PCT} % with none unsolved: {}; {:.3} N beside DenseTact 2.0's {} N",
                f.force_magnitude_error_pct,
                f.unsolved_frames,
                if f.force_magnitude_error_pct <= FORCE_GOAL_PCT && f.unsolved_frames == 0 { "met" } else { "NOT met" },
                f.force_magnitude_error_n.mean,
                infer::plot::DENSETACT2_FORCE_ERROR_N
            );
        }
    }
    if let Some(best) = state.selected() {
        println!("model: epoch {} of {} (best on held-out training samples)", best.epoch, state.history.len());
    }
    println!("network: {frame_ms:.1} ms per frame on the CPU (flex)");
    println!("took {:.1} min; everything is in {}", seconds / 60.0, out.display());
    println!(
        "  eval/stats.json, eval/errors.csv, eval/violin.svg, examples/triplets.png (image, true, predicted), examples/*.ply, bundle/"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quickstart trains `train fit`'s default recipe: the same settings (at its input
    /// size) and, with its default flags, the same network.
    #[test]
    fn the_quickstart_trains_the_clis_default_recipe() {
        let data = Path::new("d");
        let cli = Recipe::Quickstart;
        assert_eq!(recipe(data, cli.network().input_hw[0]), cli.fit_config(data.to_path_buf()));
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: Args,
        }
        let args = <Cli as clap::Parser>::try_parse_from(["quickstart"]).unwrap().args;
        let quickstart =
            network(cli.network().preset).with_input(args.channels).with_full_resolution(!args.half_resolution);
        assert_eq!(quickstart, cli.model_config().unwrap());
        assert_eq!(args.contact_weight, cli.fit_config(data.to_path_buf()).contact_weight);
        assert_eq!(args.force_weight, cli.fit_config(data.to_path_buf()).force_weight);
    }

    /// `cargo xtask quickstart --smoke` end to end; `run` itself checks that its outputs exist
    /// and parse. A second run resumes every stage and gives the same statistics.
    #[test]
    fn smoke_quickstart_runs_end_to_end_and_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("qs");
        let args = || Args {
            out: out.clone(),
            smoke: true,
            samples: None,
            epochs: None,
            unit: 7,
            channels: model::InputChannels::RgbDifference,
            half_resolution: false,
            contact_weight: 5.0,
            force_weight: train::FitConfig::DEFAULT_FORCE_WEIGHT,
            seeds: 2,
        };
        run(args()).unwrap();
        let first = std::fs::read_to_string(out.join("eval/stats.json")).unwrap();
        run(args()).unwrap();
        assert_eq!(std::fs::read_to_string(out.join("eval/stats.json")).unwrap(), first);
        let bundle: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("bundle/bundle.json")).unwrap()).unwrap();
        // The test error with the count of images it is the mean of, all of the test split's.
        let test = &bundle["training"]["test"];
        assert!(test["l1_mm"].as_f64().is_some_and(|v| v.is_finite() && v > 0.0), "{test}");
        let manifest = Manifest::load(&out.join("dataset")).unwrap();
        let test_images = manifest.split(Some(Split::Test)).count() as u64;
        assert_eq!(test["images"].as_u64(), Some(test_images), "{test}");
        // A damaged output is caught.
        std::fs::write(out.join("eval/stats.json"), "{").unwrap();
        assert!(check_outputs(&out).is_err());
    }
}
