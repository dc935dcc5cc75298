//! `infer`: depth maps, contact and point clouds from camera frames with an exported bundle.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use infer::{PointCloud, Predictor, write_ply};

/// Depth above which a pixel counts as in contact (mm), as in the dataset's statistics.
const CONTACT_THRESHOLD_MM: f32 = 0.02;

#[derive(Parser)]
#[command(name = "infer", version, about = "DenseTact depth, contact and point clouds from camera frames")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Predict one frame: 16-bit micrometre depth PNG, false-colour PNG, PLY point cloud.
    Predict {
        #[arg(long)]
        bundle: PathBuf,
        /// The sensor's RGB crop (PNG), as the dataset stores it.
        #[arg(long)]
        image: PathBuf,
        #[arg(long)]
        depth_out: Option<PathBuf>,
        /// False-colour depth for people.
        #[arg(long)]
        colour_out: Option<PathBuf>,
        /// Point cloud of the contact patch (sensor frame, mm).
        #[arg(long)]
        ply: Option<PathBuf>,
        /// Run the network even when the frame shows no contact.
        #[arg(long)]
        always: bool,
    },
}

fn predict(
    bundle: PathBuf,
    image: PathBuf,
    depth_out: Option<PathBuf>,
    colour_out: Option<PathBuf>,
    ply: Option<PathBuf>,
    always: bool,
) -> Result<()> {
    let device = model::backend::default_device();
    let predictor = Predictor::load(&bundle, &device)?;
    let frame = image::open(&image).with_context(|| format!("{}: not a readable image", image.display()))?.to_rgb8();
    let start = Instant::now();
    let depth = if always {
        predictor.predict_network(std::slice::from_ref(&frame)).map(|mut v| v.remove(0))
    } else {
        predictor.predict(&frame)
    }
    .with_context(|| format!("{}", image.display()))?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let contact = Predictor::contact_mask(&depth, CONTACT_THRESHOLD_MM);
    let pressed = contact.iter().filter(|&&c| c).count();
    println!(
        "{}: {pressed} contact pixels ({:.2} % of the useful disk), max depth {:.3} mm, {ms:.1} ms",
        image.display(),
        100.0 * pressed as f64 / predictor.mask.iter().filter(|&&m| m).count().max(1) as f64,
        depth.max_mm()
    );
    if let Some(path) = depth_out {
        depth.save_png_um(&path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = colour_out {
        let img = infer::colour::false_colour(&depth, &predictor.mask, predictor.file.sensor.max_depth_mm as f32);
        img.save(&path).with_context(|| format!("{}: cannot write", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = ply {
        let cloud = PointCloud::from_depth(&depth, &predictor.file.sensor, Some(CONTACT_THRESHOLD_MM));
        write_ply(&path, &cloud)?;
        println!("wrote {} ({} points)", path.display(), cloud.points_mm.len());
    }
    Ok(())
}

fn main() -> ExitCode {
    let result = match Cli::parse().command {
        Command::Predict { bundle, image, depth_out, colour_out, ply, always } => {
            predict(bundle, image, depth_out, colour_out, ply, always)
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
