//! `dataset`: generate ray-cast ground truth for DenseTact sensors.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use dataset::format::GeneratorParams;
use dataset::generate::{Generator, report_lines};
use dataset::{Kit, Skipping};
use sensor::Sensor;

#[derive(Parser)]
#[command(name = "dataset", version, about = "Ground truth for DenseTact sensors")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate a dataset of depth maps (resumable: run the same command again after a kill).
    Generate(GenerateArgs),
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
    /// Range of the CNC's z travel (mm) from the seated pose.
    #[arg(long, default_value_t = 0.0)]
    z_min_mm: f32,
    #[arg(long, default_value_t = 2.5)]
    z_max_mm: f32,
    /// Chance that a sample is drawn from the test trials.
    #[arg(long, default_value_t = 0.1)]
    test_fraction: f32,
    /// Also write the paper's 8-bit depth encoding (depth_u8/).
    #[arg(long)]
    depth_u8: bool,
    /// Cast every ray against every triangle (slower; the result is identical).
    #[arg(long)]
    no_skip: bool,
}

fn generate(args: GenerateArgs) -> Result<()> {
    if !(args.z_min_mm.is_finite() && args.z_max_mm.is_finite() && args.z_min_mm <= args.z_max_mm) {
        bail!("--z-min-mm ({}) must not exceed --z-max-mm ({})", args.z_min_mm, args.z_max_mm);
    }
    if !(0.0..=1.0).contains(&args.test_fraction) {
        bail!("--test-fraction must be between 0 and 1, got {}", args.test_fraction);
    }
    let sensor = match &args.sensor {
        Some(path) => Sensor::load_json(path)?,
        None => Sensor::default(),
    };
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
        test_fraction: args.test_fraction,
        depth_u8: args.depth_u8,
    };
    let skipping = if args.no_skip { Skipping::Off } else { Skipping::On };
    let generator = Generator { out: args.out.clone(), sensor: &sensor, kit: &kit, params, skipping };
    let report = generator.run()?;
    for line in report_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", args.out.join("manifest.json").display());
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Generate(args) => generate(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
