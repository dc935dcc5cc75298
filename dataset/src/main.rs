//! `dataset`: generate ray-cast ground truth for DenseTact sensors.

#![deny(unsafe_code)]

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use dataset::calibration::{CalibrationOptions, GpTarget, calibrate, compare};
use dataset::generate::{Generator, report_lines};
use dataset::label::OnBadRow;
use dataset::session::{RendererCamera, SessionWriter};
use dataset::{Kit, Renderer, SawTooth, SawToothShot, SensorUnit, Skipping};
use formats::dataset::{Angles, GeneratorParams};
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
    /// Ground truth for a capture session (captures.csv, frames, reference frame): each frame
    /// cropped around the calibrated optical centre with the depth ray-cast for its logged pose
    /// (resumable: run the same command again after a kill).
    Label(LabelArgs),
    /// Join the shares of a generation or labelling run as a job array (`--shard K/N`) into the
    /// dataset one run would have written, byte for byte.
    Merge(MergeArgs),
}

#[derive(clap::Args)]
struct MergeArgs {
    /// The shares' folders: every share of one run, once each, in any order.
    #[arg(required = true)]
    shards: Vec<PathBuf>,
    /// The dataset folder to write.
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args)]
struct LabelArgs {
    /// The session folder: captures.csv, the frames it names, reference.png or .jpg.
    #[arg(long)]
    session: PathBuf,
    /// The kit the session pressed: its folder (stl/, Index_training.csv, Index_test.csv), or
    /// `procedural` for the embedded kit (simulated sessions).
    #[arg(long, default_value = "procedural")]
    kit: String,
    /// Multiplies the kit's mesh coordinates to make millimetres (25.4 for files in inches).
    #[arg(long, default_value_t = 1.0)]
    kit_scale: f32,
    /// The unit's calibrated sensor description (from `dataset calibrate`).
    #[arg(long)]
    sensor: PathBuf,
    /// The dataset folder to write.
    #[arg(long)]
    out: PathBuf,
    /// What a bad row does: stop at the first (naming its line), or skip it (counted, listed).
    #[arg(long, value_enum, default_value_t = OnBadRow::Stop)]
    on_bad_row: OnBadRow,
    /// What the log's z_mm measures: travel from the kit's seated pose, from first touch (found
    /// per row by ray casting its trial, tilts and B), or a machine coordinate (less the
    /// machine's z at the seated pose: --z-zero-mm, or a z_zero_mm column).
    #[arg(long, value_enum, default_value_t = dataset::touch::ZFrom::Seated)]
    z_from: dataset::touch::ZFrom,
    /// With --z-from machine: the machine's z at the kit's seated pose (mm); a row's z_zero_mm
    /// column overrides it.
    #[arg(long, requires = "z_from")]
    z_zero_mm: Option<f32>,
    /// Label only share K of N of the log's rows (0-based: rows whose position in the log is K
    /// modulo N), one task of a job array; `dataset merge` joins the shares.
    #[arg(long)]
    shard: Option<formats::Shard>,
    /// Estimate the rig's offsets (each trial's z zero, the sensor's x, y and tilts in its
    /// mount, B's zero) from the log's z sweeps and apply them to the labels. Without it, a log
    /// with sweeps still has them estimated, reported and warned about.
    #[arg(long)]
    register: bool,
    /// Depth labels only: no pressure maps or wrenches.
    #[arg(long)]
    no_force_labels: bool,
    /// Young's modulus of the unit's silicone (MPa) for the force labels; default: the paper's
    /// 6.5 Shore A estimate. Measure yours (an indentation test) if force matters.
    #[arg(long, default_value_t = dataset::mechanics::Material::PAPER.youngs_modulus_mpa)]
    youngs_modulus_mpa: f64,
    /// Poisson's ratio of the silicone for the force labels.
    #[arg(long, default_value_t = dataset::mechanics::Material::PAPER.poisson_ratio)]
    poisson_ratio: f64,
}

#[derive(clap::Args)]
struct SawtoothArgs {
    /// Seed of the simulated sensor unit.
    #[arg(long)]
    unit: u64,
    /// Output folder: sawtooth.png, truth.json (true sensor description), unit.json.
    #[arg(long)]
    out: PathBuf,
    /// Hemisphere radius (mm).
    #[arg(long, default_value_t = 25.0)]
    radius_mm: f64,
    /// Multiplies the unit's sensor noise.
    #[arg(long, default_value_t = 1.0)]
    noise_scale: f64,
    /// Shade the contact model's solved membrane, which bridges each tooth's drop, instead of
    /// the indenter's surface (the calibration does not yet read that bridge: README).
    #[arg(long)]
    solved_membrane: bool,
    /// Fraction of pixels replaced by salt-and-pepper specks.
    #[arg(long, default_value_t = 0.0)]
    speckle: f64,
    /// Teeth printed without their edge (1-based from the apex; negative: the -x side).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    hide_teeth: Vec<i32>,
}

#[derive(clap::Args)]
struct CalibrateArgs {
    /// The camera's frame of the pressed saw-tooth indicator (PNG or JPEG, RGB).
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
    /// Refuse a frame that places the map less precisely than this (px, rms over the useful
    /// disk, two standard deviations).
    #[arg(long, default_value_t = dataset::calibration::DEFAULT_MAX_UNCERTAINTY_PX)]
    max_uncertainty_px: f64,
}

#[derive(clap::Args)]
struct GenerateArgs {
    /// Output folder: a dataset.
    #[arg(long, required_unless_present = "session", conflicts_with = "session")]
    out: Option<PathBuf>,
    /// Write a simulated capture session instead of a dataset (needs --unit): the camera's full
    /// frames, captures.csv, reference.png and sawtooth.png, as a lab's rig would produce them.
    #[arg(long, requires = "unit")]
    session: Option<PathBuf>,
    /// With --session: the rig's errors, drawn from this seed, which the frames obey and the
    /// log does not (a z zero per trial within +-0.3 mm, the sensor 0.5 mm and 1 degree off
    /// in its mount, B's zero within +-2 degrees; the truth in .simulation/rig.json).
    #[arg(long, requires = "session")]
    rig_errors: Option<u64>,
    /// With --session: press in z sweeps of this many frames (--count frames in all): each
    /// sweep's trial, tilts and B drawn as a sample's, its z from 1 mm above the logged first
    /// touch down in steps of --sweep-step-mm, as a rig presses a shape; the frames before the
    /// touch are untouched, and where the image first changes tells the rig's z zero.
    #[arg(long, requires = "session", value_parser = clap::value_parser!(u32).range(2..))]
    sweep_frames: Option<u32>,
    /// With --sweep-frames: the z step between a sweep's frames (mm).
    #[arg(long, requires = "sweep_frames", default_value_t = 0.05)]
    sweep_step_mm: f32,
    /// With --session: frames as JPEG of this quality (1..100), as USB cameras stream them.
    #[arg(long, requires = "session", value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: Option<u8>,
    /// Make only share K of N of the samples (0-based: those whose id is K modulo N), one task of
    /// a job array; `dataset merge` joins the shares into the dataset one run writes.
    #[arg(long, conflicts_with = "session")]
    shard: Option<formats::Shard>,
    /// Number of samples.
    #[arg(long, default_value_t = 100)]
    count: u32,
    /// Seed of the draws: the same seed gives the same samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The DenseTact kit folder (stl/, Index_training.csv, Index_test.csv); default: the
    /// embedded procedural kit.
    #[arg(long)]
    kit: Option<PathBuf>,
    /// Multiplies the kit's mesh coordinates to make millimetres (25.4 for files in inches).
    #[arg(long, default_value_t = 1.0)]
    kit_scale: f32,
    /// Sensor description (JSON); default: the paper's sensor.
    #[arg(long)]
    sensor: Option<PathBuf>,
    /// Range of the CNC's z travel (mm) from the seated pose (negative: raised).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    z_min_mm: f32,
    /// Upper end of the z travel range (mm).
    #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
    z_max_mm: f32,
    /// B-axis turns to draw (degrees): a range `0..360`, a list `0,90,180` or one value.
    #[arg(long, default_value = "0..360", allow_hyphen_values = true)]
    b_deg: Angles,
    /// A-axis tilts to draw (degrees, about the sensor frame's x axis): e.g. `0,45` or
    /// `-45..45`; default none.
    #[arg(long, default_value = "0", allow_hyphen_values = true)]
    a_deg: Angles,
    /// C-axis tilts to draw (degrees, about the sensor frame's y axis); default none.
    #[arg(long, default_value = "0", allow_hyphen_values = true)]
    c_deg: Angles,
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
    /// Render each sample under its own random look (lights, colours, coating, gel smoothing,
    /// blur, gamma, exposure, noise, JPEG and its chroma subsampling), with the look's
    /// untouched frame beside it (references/): data for a network that must read units it
    /// never saw. Needs --unit (whose geometry is kept).
    #[arg(long, requires = "unit")]
    random_looks: bool,
    /// Hemisphere radius (mm) of the default sensor or the simulated unit.
    #[arg(long, default_value_t = 25.0, conflicts_with = "sensor")]
    radius_mm: f64,
    /// Depth labels only: no pressure maps or wrenches (by default each sample's contact is
    /// solved with the unit's silicone, or the paper's without --unit).
    #[arg(long)]
    no_force_labels: bool,
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
        Some(dir) => Kit::open_dir(dir, args.kit_scale, "--kit")?,
        None => Kit::procedural(sensor.radius_mm as f32),
    };
    let b_axis_deg = match args.b_deg {
        Angles::Range(range) => range,
        Angles::List(v) if v.len() == 1 => [v[0], v[0]],
        Angles::List(_) => bail!("--b-deg draws from a range (`0..360`) or takes one value, not a list"),
    };
    for (flag, angles) in [("--a-deg", &args.a_deg), ("--c-deg", &args.c_deg)] {
        if angles.max_abs() > dataset::label::MAX_TILT_DEG {
            bail!(
                "{flag}: tilts beyond +-{} degrees turn the indicator's base to the sensor",
                dataset::label::MAX_TILT_DEG
            );
        }
    }
    let params = GeneratorParams {
        seed: args.seed,
        count: args.count,
        kit: kit.source.clone(),
        z_travel_mm: [args.z_min_mm, args.z_max_mm],
        b_axis_deg,
        lifted_fraction: args.lifted_fraction,
        test_fraction: args.test_fraction,
        depth_u8: args.depth_u8,
        unit: args.unit,
        a_axis_deg: args.a_deg,
        c_axis_deg: args.c_deg,
        image_model: formats::dataset::IMAGE_MODEL,
        random_looks: args.random_looks,
        force_labels: !args.no_force_labels,
        shard: args.shard,
    };
    // Travel that presses most contact past the sensor's depth range gives depth maps that say
    // nothing there: refused with the figure, or warned about.
    let clipped = dataset::generate::clipped_fraction(&kit, &params, &sensor, 4)?;
    let figure = format!(
        "with --z-max-mm {}, {:.0} % of the contact pixels of four of the kit's trials pressed over the z range \
         sit at the sensor's {} mm maximum depth (clipped)",
        args.z_max_mm,
        100.0 * clipped,
        sensor.max_depth_mm
    );
    if clipped > 0.5 {
        bail!("{figure}: their depth is lost; lower --z-max-mm");
    }
    if clipped > 0.1 {
        eprintln!("warning: {figure}");
    }
    if let Some(dir) = &args.session {
        let unit = unit.as_ref().context("--session needs --unit")?;
        let camera = RendererCamera::new(unit, args.jpeg_quality);
        let rig = args.rig_errors.map(|seed| dataset::rig::RigOffsets::draw(seed, &kit)).unwrap_or_default();
        if !(args.sweep_step_mm.is_finite() && args.sweep_step_mm > 0.0) {
            bail!("--sweep-step-mm {}: a sweep's step must be a positive number of millimetres", args.sweep_step_mm);
        }
        let sweep = args.sweep_frames.map(|frames| dataset::session::Sweep {
            frames,
            step_mm: args.sweep_step_mm,
            lead_mm: dataset::session::Sweep::DEFAULT_LEAD_MM,
        });
        let writer = SessionWriter { out: dir.clone(), kit: &kit, camera: &camera, params, rig, sweep };
        let report = writer.run()?;
        println!(
            "{} frames ({} new) in {:.1} s; wrote {}",
            report.frames,
            report.made,
            report.seconds,
            dir.join(formats::session::CAPTURES_CSV).display()
        );
        return Ok(());
    }
    let out = args.out.clone().context("--out or --session")?;
    let skipping = if args.no_skip { Skipping::Off } else { Skipping::On };
    let generator =
        Generator { out: out.clone(), sensor: &sensor, kit: &kit, params, skipping, renderer: renderer.as_ref() };
    let report = generator.run()?;
    for line in report_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", out.join("manifest.json").display());
    Ok(())
}

fn label(args: LabelArgs) -> Result<()> {
    let request = dataset::label::LabelRequest {
        session: args.session,
        kit: args.kit,
        kit_scale: args.kit_scale,
        sensor: Sensor::load_json(&args.sensor)?,
        out: args.out.clone(),
        on_bad_row: args.on_bad_row,
        z: dataset::touch::ZReading { from: args.z_from, zero_mm: args.z_zero_mm },
        force: (!args.no_force_labels).then_some(dataset::mechanics::Material {
            youngs_modulus_mpa: args.youngs_modulus_mpa,
            poisson_ratio: args.poisson_ratio,
        }),
        shard: args.shard,
        register: args.register,
        flags: true,
    };
    let report = request.run()?;
    for line in dataset::label::report_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", args.out.join("manifest.json").display());
    Ok(())
}

fn merge(args: MergeArgs) -> Result<()> {
    let report = dataset::merge::merge(&args.shards, &args.out)?;
    println!(
        "{} samples ({} files) from {} shares, as one run writes them ({}); wrote {}",
        report.samples,
        report.files,
        report.shards,
        report.made_by,
        args.out.join("manifest.json").display()
    );
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
        solved_membrane: args.solved_membrane,
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
    let inputs: Vec<&std::path::Path> = std::iter::once(args.image.as_path()).chain(args.truth.as_deref()).collect();
    formats::output::check_file(&args.out, &inputs)?;
    let img = sensor::frame::read(&args.image)?;
    sensor::frame::check_colour(&args.image, &img)?;
    let truth = args.truth.as_deref().map(Sensor::load_json).transpose()?;
    let opts = CalibrationOptions {
        radius_mm: args.radius_mm,
        indicator: SawTooth { pitch_deg: args.pitch_deg, teeth: args.teeth, ..Default::default() },
        target: args.target,
        max_uncertainty_px: args.max_uncertainty_px,
    };
    opts.validate().context("--pitch-deg, --teeth, --radius-mm, --max-uncertainty-px")?;
    let cal = calibrate(&img, &opts).with_context(|| format!("{}", args.image.display()))?;
    write_json(&args.out, &cal.sensor)?;
    let c = &cal.sensor.correspondence;
    println!(
        "optical centre ({:.3}, {:.3}) px; rim (90 deg) at {:.3} px, circle fit rms {:.3} px",
        c.centre_u_px, c.centre_v_px, cal.rim_radius_px, cal.rim_rms_px
    );
    println!("{} tooth edges matched; residual rms {:.3} px", cal.edges.len(), cal.fit_rms_px);
    if !cal.missing.is_empty() {
        println!("teeth without an edge: {}", cal.missing_teeth().join(" "));
    }
    println!(
        "predictive sd of theta over the useful disk: mean {:.4} deg, max {:.4} deg",
        cal.mean_sd_deg, cal.max_sd_deg
    );
    println!(
        "rim edge {:.1} px wide, centre placed to +-{:.2} px; tooth pulses: gaussian {:.1} px, tail {:.1} px",
        cal.rim_width_px, cal.centre_sd_px, cal.pulse_sigma_px, cal.pulse_tail_px
    );
    println!(
        "uncertainty of the map: +-{:.2} px rms over the useful disk (two standard deviations)",
        cal.uncertainty_px
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
        Command::Label(args) => label(args),
        Command::Merge(args) => merge(args),
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
