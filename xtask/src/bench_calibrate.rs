//! `cargo xtask bench calibrate`: the saw-tooth calibration on many units' frames, from the
//! project's renderer (every drape, blur, gamma, noise and JPEG its units draw) or from the
//! independent image model (`gelcam`), against each unit's true fisheye: how many calibrate,
//! how far off they are, whether the stated uncertainty holds, and why the others are refused.

use anyhow::Result;
use dataset::calibration::{CalibrationOptions, calibrate, compare};
use dataset::{SawTooth, SawToothShot, SensorUnit};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ImageModel {
    /// The project's renderer: `SensorUnit::from_seed`, its shot at noise x0.5..x3.
    Own,
    /// The independent image model: `gelcam::GelUnit::from_seed`.
    Gelcam,
}

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, value_enum, default_value_t = ImageModel::Own)]
    model: ImageModel,
    /// Unit seeds, `A..B` (B excluded).
    #[arg(long, default_value = "40..80", value_parser = parse_range)]
    units: std::ops::Range<u64>,
    /// Refuse frames that place the map less precisely than this (px).
    #[arg(long, default_value_t = dataset::calibration::DEFAULT_MAX_UNCERTAINTY_PX)]
    max_uncertainty_px: f64,
    /// Print every unit's line.
    #[arg(long)]
    verbose: bool,
}

fn parse_range(s: &str) -> Result<std::ops::Range<u64>, String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("expected A..B, got {s:?}"))?;
    let (a, b) = (a.parse::<u64>().map_err(|e| e.to_string())?, b.parse::<u64>().map_err(|e| e.to_string())?);
    if a >= b {
        return Err(format!("{s}: empty range"));
    }
    Ok(a..b)
}

/// One unit's outcome.
enum Outcome {
    Calibrated { px: f64, deg: f64, stated_px: f64 },
    Refused(String),
}

pub fn run(args: Args) -> Result<()> {
    let opts = CalibrationOptions { max_uncertainty_px: args.max_uncertainty_px, ..Default::default() };
    let outcomes: Vec<(u64, String, Outcome)> = args
        .units
        .clone()
        .into_par_iter()
        .map(|seed| {
            let (img, truth, what) = match args.model {
                ImageModel::Own => {
                    let unit = SensorUnit::from_seed(seed, 25.0);
                    // Noise x0.5..x3, spread over the units.
                    let noise = 0.5 + 2.5 * ((seed * 7919) % 100) as f64 / 100.0;
                    let c = &unit.camera;
                    let what = format!(
                        "drape {:.2} mm, blur {:.2} px, gamma {:.2}, jpeg {:?}, noise x{noise:.2}",
                        unit.elastomer.drape_mm, c.blur_px, c.gamma, c.jpeg_quality
                    );
                    (SawToothShot { seed, noise_scale: noise, ..Default::default() }.render(&unit), unit.sensor, what)
                }
                ImageModel::Gelcam => {
                    let unit = gelcam::GelUnit::from_seed(seed, 25.0);
                    let l = &unit.look;
                    let what = format!(
                        "membrane {:.2} px, blur {:.2} px, {} lights, rim {:.2} deg soft, jpeg {:?}",
                        l.membrane_sigma_px,
                        l.blur_px,
                        l.lights.len(),
                        l.rim_soft_deg,
                        l.jpeg_quality
                    );
                    (gelcam::sawtooth_frame(&unit, &SawTooth::default(), Some(seed)), unit.sensor, what)
                }
            };
            let outcome = match calibrate(&img, &opts) {
                Ok(cal) => {
                    let (px, deg) = compare(&cal.sensor, &truth);
                    // Where the error comes from: the optical centre, or the map about it.
                    let (c, t) = (&cal.sensor.correspondence, &truth.correspondence);
                    let mut centred = cal.sensor.clone();
                    centred.correspondence.centre_u_px = t.centre_u_px;
                    centred.correspondence.centre_v_px = t.centre_v_px;
                    let what = format!(
                        "{what} | centre off ({:+.2}, {:+.2}) px (stated sd {:.2}); about the true centre {:.3} px",
                        c.centre_u_px - t.centre_u_px,
                        c.centre_v_px - t.centre_v_px,
                        cal.centre_sd_px,
                        compare(&centred, &truth).0
                    );
                    return (seed, what, Outcome::Calibrated { px, deg, stated_px: cal.uncertainty_px });
                }
                Err(e) => Outcome::Refused(e.to_string()),
            };
            (seed, what, outcome)
        })
        .collect();
    let (mut calibrated, mut refused, mut beyond_stated) = (Vec::new(), Vec::new(), 0);
    for (seed, what, o) in &outcomes {
        match o {
            Outcome::Calibrated { px, deg, stated_px } => {
                calibrated.push((*px, *deg));
                beyond_stated += usize::from(px > stated_px);
                if args.verbose {
                    println!("unit {seed}: {px:.3} px, {deg:.4} deg (stated +-{stated_px:.3}) | {what}");
                }
            }
            Outcome::Refused(e) => {
                refused.push(e.clone());
                if args.verbose {
                    println!("unit {seed}: refused: {e} | {what}");
                }
            }
        }
    }
    let worst = |f: fn(&(f64, f64)) -> f64| calibrated.iter().map(f).fold(0.0, f64::max);
    let mean = |f: fn(&(f64, f64)) -> f64| calibrated.iter().map(f).sum::<f64>() / calibrated.len().max(1) as f64;
    println!(
        "{:?} image model, units {}..{}: {} calibrated (rms over the useful disk: mean {:.3} px / {:.4} deg, worst \
         {:.3} px / {:.4} deg; {} off by more than their stated uncertainty), {} refused",
        args.model,
        args.units.start,
        args.units.end,
        calibrated.len(),
        mean(|c| c.0),
        mean(|c| c.1),
        worst(|c| c.0),
        worst(|c| c.1),
        beyond_stated,
        refused.len()
    );
    // The refusals by their reason's opening words.
    let mut reasons: std::collections::BTreeMap<String, usize> = Default::default();
    for e in &refused {
        let key: String =
            e.trim_start_matches("calibration failed: ").split_whitespace().take(6).collect::<Vec<_>>().join(" ");
        *reasons.entry(key).or_default() += 1;
    }
    for (k, n) in reasons {
        println!("  refused {n}x: {k} ...");
    }
    Ok(())
}
