//! `dataset`: generate ray-cast ground truth for DenseTact sensors.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use dataset::calibration::{CalibrationOptions, GpTarget, calibrate, compare};
use dataset::generate::{Generator, report_lines};
use dataset::{Kit, Renderer, SawTooth, SawToothShot, SensorUnit, Skipping};
use formats::dataset::GeneratorParams;
use formats::fs::write_atomic;
use formats::write_json;
use sensor::Sensor;
use sensor::frame::encode_png_rgb;

#[derive(Parser)]
#[command(name = "dataset", version, about = "Ground truth for DenseTact sensors")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate a dataset of depth maps, and with --unit the camera images of a simulated unit
    /// (resumable: run the same command again after a kill).
    Generate(GenerateArgs),
    /// Render a simulated unit's image of the saw-tooth calibration indicator, with its truth.
    Sawtooth(SawtoothArgs),
    /// Calibrate the fisheye correspondence from an image of the saw-tooth indicator.
    Calibrate(CalibrateArgs),
}

#[derive(clap::Args)]
struct SawtoothArgs {
    /// Seed of the simulated sensor unit.
    #[arg(long)]
    unit: u64,
    /// Output folder: sawtooth.png, truth.json (true sensor description), unit.json.
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 25.0)]
    radius_mm: f64,
    /// Multiplies the unit's sensor noise.
    #[arg(long, default_value_t = 1.0)]
    noise_scale: f64,
    /// Fraction of pixels replaced by salt-and-pepper specks.
    #[arg(long, default_value_t = 0.0)]
    speckle: f64,
    /// Teeth printed without their edge (1-based from the apex; negative: the -x side).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    hide_teeth: Vec<i32>,
}

#[derive(clap::Args)]
struct CalibrateArgs {
    /// RGB camera frame of the pressed saw-tooth indicator (PNG).
    #[arg(long)]
    image: PathBuf,
    /// Where to write the calibrated sensor description (JSON).
    #[arg(long)]
    out: PathBuf,
    /// A true sensor description to measure the calibration against.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Hemisphere radius of the sensor.
    #[arg(long, default_value_t = 25.0)]
    radius_mm: f64,
    /// Angle between the indicator's teeth.
    #[arg(long, default_value_t = 5.0)]
    pitch_deg: f64,
    /// Teeth on each side of the apex.
    #[arg(long, default_value_t = 17)]
    teeth: u32,
    /// What the Gaussian process regresses on image radius.
    #[arg(long, value_enum, default_value_t = GpTarget::Theta)]
    target: GpTarget,
}

#[derive(clap::Args)]
struct GenerateArgs {
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Number of samples.
    #[arg(long, default_value_t = 100)]
    count: u32,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The DenseTact kit folder (stl/, Index_training.csv, Index_test.csv); default: the
    /// embedded procedural kit.
    #[arg(long)]
    kit: Option<PathBuf>,
    /// Sensor description (JSON); default: the paper's sensor.
    #[arg(long)]
    sensor: Option<PathBuf>,
    /// Range of the CNC's z travel (mm) from the seated pose (negative: raised).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    z_min_mm: f32,
    #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
    z_max_mm: f32,
    /// Chance that a sample's rig is lifted clear of the sensor: frames without contact, which
    /// a network must learn to answer with zeros.
    #[arg(long, default_value_t = 0.0)]
    lifted_fraction: f32,
    /// Chance that a sample is drawn from the test trials.
    #[arg(long, default_value_t = 0.1)]
    test_fraction: f32,
    /// Also write the paper's 8-bit depth encoding (depth_u8/).
    #[arg(long)]
    depth_u8: bool,
    /// Cast every ray against every triangle (slower; the result is identical).
    #[arg(long)]
    no_skip: bool,
    /// Also render camera images of the simulated sensor unit with this seed (its true geometry
    /// becomes the dataset's sensor).
    #[arg(long, conflicts_with = "sensor")]
    unit: Option<u64>,
    /// Hemisphere radius (mm) of the default sensor or the simulated unit.
    #[arg(long, default_value_t = 25.0, conflicts_with = "sensor")]
    radius_mm: f64,
}

fn generate(args: GenerateArgs) -> Result<()> {
    if !(args.z_min_mm.is_finite() && args.z_max_mm.is_finite() && args.z_min_mm <= args.z_max_mm) {
        bail!("--z-min-mm ({}) must not exceed --z-max-mm ({})", args.z_min_mm, args.z_max_mm);
    }
    if !(0.0..=1.0).contains(&args.test_fraction) {
        bail!("--test-fraction must be between 0 and 1, got {}", args.test_fraction);
    }
    if !(0.0..=1.0).contains(&args.lifted_fraction) {
        bail!("--lifted-fraction must be between 0 and 1, got {}", args.lifted_fraction);
    }
    let unit = args.unit.map(|seed| SensorUnit::from_seed(seed, args.radius_mm));
    let sensor = match (&args.sensor, &unit) {
        (Some(path), _) => Sensor::load_json(path)?,
        (None, Some(unit)) => unit.sensor.clone(),
        (None, None) => Sensor::with_radius(args.radius_mm),
    };
    sensor.validate()?;
    let renderer = unit.as_ref().map(Renderer::for_crop);
    let kit = match &args.kit {
        Some(dir) => Kit::load_dir(dir).with_context(|| format!("loading the kit in {}", dir.display()))?,
        None => Kit::procedural(sensor.radius_mm as f32),
    };
    let params = GeneratorParams {
        seed: args.seed,
        count: args.count,
        kit: kit.source.clone(),
        z_travel_mm: [args.z_min_mm, args.z_max_mm],
        b_axis_deg: [0.0, 360.0],
        lifted_fraction: args.lifted_fraction,
        test_fraction: args.test_fraction,
        depth_u8: args.depth_u8,
        unit: args.unit,
    };
    let skipping = if args.no_skip { Skipping::Off } else { Skipping::On };
    let generator =
        Generator { out: args.out.clone(), sensor: &sensor, kit: &kit, params, skipping, renderer: renderer.as_ref() };
    let report = generator.run()?;
    for line in report_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", args.out.join("manifest.json").display());
    Ok(())
}

fn sawtooth(args: SawtoothArgs) -> Result<()> {
    if !(args.noise_scale >= 0.0 && (0.0..=0.5).contains(&args.speckle)) {
        bail!("--noise-scale must be >= 0 and --speckle within 0..0.5");
    }
    let unit = SensorUnit::from_seed(args.unit, args.radius_mm);
    let shot = SawToothShot {
        indicator: SawTooth { missing_teeth: args.hide_teeth, ..Default::default() },
        noise_scale: args.noise_scale,
        speckle_fraction: args.speckle,
        seed: args.unit,
        ..Default::default()
    };
    let img = shot.render(&unit);
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}: cannot create folder", args.out.display()))?;
    write_atomic(&args.out.join("sawtooth.png"), &encode_png_rgb(&img))?;
    write_json(&args.out.join("truth.json"), &unit.sensor)?;
    write_json(&args.out.join("unit.json"), &unit)?;
    println!("wrote {} (unit {}), truth.json and unit.json", args.out.join("sawtooth.png").display(), args.unit);
    Ok(())
}

fn run_calibration(args: CalibrateArgs) -> Result<()> {
    let img =
        image::open(&args.image).with_context(|| format!("{}: not a readable image", args.image.display()))?.to_rgb8();
    let truth = args.truth.as_deref().map(Sensor::load_json).transpose()?;
    if !(args.pitch_deg > 0.0 && args.pitch_deg * args.teeth as f64 <= 90.0) {
        bail!("--pitch-deg x --teeth must stay within 90 degrees");
    }
    let opts = CalibrationOptions {
        radius_mm: args.radius_mm,
        indicator: SawTooth { pitch_deg: args.pitch_deg, teeth: args.teeth, ..Default::default() },
        target: args.target,
    };
    let cal = calibrate(&img, &opts).with_context(|| format!("{}", args.image.display()))?;
    write_json(&args.out, &cal.sensor)?;
    let c = &cal.sensor.correspondence;
    println!(
        "optical centre ({:.3}, {:.3}) px; rim (90 deg) at {:.3} px, circle fit rms {:.3} px",
        c.centre_u_px, c.centre_v_px, cal.rim_radius_px, cal.rim_rms_px
    );
    println!("{} tooth edges matched; residual rms {:.3} px", cal.edges.len(), cal.fit_rms_px);
    if !cal.missing.is_empty() {
        let names: Vec<String> =
            cal.missing.iter().map(|(s, k)| format!("{}{k}", if *s < 0 { "-" } else { "+" })).collect();
        println!("teeth without an edge: {}", names.join(" "));
    }
    println!(
        "predictive sd of theta over the useful disk: mean {:.4} deg, max {:.4} deg",
        cal.mean_sd_deg, cal.max_sd_deg
    );
    if cal.patched_px > 0.0 {
        println!(
            "theta interpolated over the last {:.1} px below the rim (R sin(theta) is flat there)",
            cal.patched_px
        );
    }
    println!("wrote {}", args.out.display());
    if let Some(truth) = truth {
        let (px, deg) = compare(&cal.sensor, &truth);
        println!("rms_px={px:.4} rms_deg={deg:.4}");
    }
    Ok(())
}

fn main() -> ExitCode {
    sensor::alloc::keep_freed_memory();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Generate(args) => generate(args),
        Command::Sawtooth(args) => sawtooth(args),
        Command::Calibrate(args) => run_calibration(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
