//! Fisheye calibration from one image of the saw-tooth indicator, as in the paper (a real
//! camera frame or a simulated one).
//!
//! 1. The optical centre: the elastomer's rim (90 degrees) is a circle about it. Canny finds the
//!    rim roughly; radial profiles refine it to sub-pixel points; a trimmed circle fit gives the
//!    centre and the rim's radius.
//! 2. Tooth edges: the indicator lies along the image row through the centre. Each tooth's drop
//!    is a thin line across that row; Canny (on each colour channel) gates the candidates and a
//!    ridge filter on the row's median profile places them to a fraction of a pixel.
//! 3. Matching: edges are assigned to teeth (multiples of the pitch) by a radial model that is
//!    refitted as edges are accepted, so a hidden tooth leaves a gap and a speck is dropped
//!    instead of shifting every later tooth.
//! 4. A Gaussian process maps image radius to theta (or, as the paper writes it, to
//!    `R sin(theta)`), through the centre (0, 0), every matched edge and the rim.
//!
//! Every stage checks its result and fails with a message rather than return a wrong map.

use image::{GrayImage, RgbImage};
use sensor::Sensor;

pub mod gp;
mod rim;
pub mod sawtooth;
mod table;
mod teeth;

use sawtooth::SawTooth;

/// What the GP regresses on image radius.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GpTarget {
    /// The polar angle itself: well conditioned up to and past the rim.
    Theta,
    /// The paper's `R sin(theta)`: flat at the rim, so theta from it loses precision there.
    RSinTheta,
}

#[derive(Clone, Debug)]
pub struct CalibrationOptions {
    pub radius_mm: f64,
    pub indicator: SawTooth,
    pub target: GpTarget,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions { radius_mm: 25.0, indicator: SawTooth::default(), target: GpTarget::Theta }
    }
}

/// One tooth edge matched to its angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchedEdge {
    /// -1 left of the centre, +1 right.
    pub side: i8,
    pub tooth: u32,
    pub radius_px: f64,
    pub theta_rad: f64,
    /// Edge minus fitted map, in pixels of radius.
    pub residual_px: f64,
}

/// The calibration and the numbers that say how far to trust it.
#[derive(Clone, Debug)]
pub struct Calibration {
    pub sensor: Sensor,
    pub rim_radius_px: f64,
    pub rim_rms_px: f64,
    pub edges: Vec<MatchedEdge>,
    /// Teeth (per side, 1-based) with no edge found.
    pub missing: Vec<(i8, u32)>,
    pub fit_rms_px: f64,
    /// Largest and mean predictive standard deviation of theta over the useful disk (degrees).
    pub max_sd_deg: f64,
    pub mean_sd_deg: f64,
    /// Pixels of radius below the rim where theta was interpolated, not taken from the GP
    /// (only with the `R sin(theta)` target, where its inverse stops rising).
    pub patched_px: f64,
}

#[derive(Debug, thiserror::Error)]
#[error("calibration failed: {0}")]
pub struct CalibrationError(pub String);

pub(super) fn fail<T>(why: impl Into<String>) -> Result<T, CalibrationError> {
    Err(CalibrationError(why.into()))
}

/// One colour channel as floats, with bilinear sampling.
pub(super) struct Plane {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) v: Vec<f32>,
}

impl Plane {
    pub(super) fn of(img: &RgbImage, channel: Option<usize>) -> Self {
        let v = img
            .pixels()
            .map(|p| match channel {
                Some(c) => p.0[c] as f32,
                None => (p.0[0] as f32 + p.0[1] as f32 + p.0[2] as f32) / 3.0,
            })
            .collect();
        Plane { w: img.width() as usize, h: img.height() as usize, v }
    }

    pub(super) fn at(&self, u: f64, v: f64) -> f32 {
        let (u, v) = (u.clamp(0.0, (self.w - 1) as f64), v.clamp(0.0, (self.h - 1) as f64));
        let (x0, y0) = ((u.floor() as usize).min(self.w - 2), (v.floor() as usize).min(self.h - 2));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let p = |x: usize, y: usize| self.v[y * self.w + x];
        let top = p(x0, y0) * (1.0 - fx) + p(x0 + 1, y0) * fx;
        let bottom = p(x0, y0 + 1) * (1.0 - fx) + p(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    pub(super) fn gray(&self) -> GrayImage {
        let px = self.v.iter().map(|&x| x.round().clamp(0.0, 255.0) as u8).collect();
        GrayImage::from_raw(self.w as u32, self.h as u32, px).expect("plane size")
    }
}

/// Calibrates from an RGB camera frame of the pressed saw-tooth indicator.
pub fn calibrate(img: &RgbImage, opts: &CalibrationOptions) -> Result<Calibration, CalibrationError> {
    if img.width() < 64 || img.height() < 64 {
        return fail(format!("image of {}x{} px is too small for a sensor frame", img.width(), img.height()));
    }
    let gray = Plane::of(img, None);
    let channels: Vec<Plane> = (0..3).map(|c| Plane::of(img, Some(c))).collect();
    let rim = rim::find_rim(&gray)?;
    let (uc, vc, r_rim) = rim.circle;
    let candidates = teeth::find_tooth_edges(&channels, uc, vc, r_rim, &opts.indicator)?;
    let pitch = opts.indicator.pitch_deg.to_radians();
    let edges = teeth::match_edges(&candidates, r_rim, pitch, opts.indicator.teeth)?;

    let table::Fit { sensor, edges, fit_rms_px, sds, patched_px } =
        table::fit(edges, &rim, opts, (img.width(), img.height()))?;
    let mut missing = Vec::new();
    for side in [-1i8, 1] {
        for k in 1..=opts.indicator.teeth {
            if !edges.iter().any(|e| e.side == side && e.tooth == k) {
                missing.push((side, k));
            }
        }
    }
    let to_deg = |v: f64| v.to_degrees();
    Ok(Calibration {
        sensor,
        rim_radius_px: r_rim,
        rim_rms_px: rim.rms_px,
        edges,
        missing,
        fit_rms_px,
        max_sd_deg: to_deg(sds.iter().copied().fold(0.0, f64::max)),
        mean_sd_deg: to_deg(sds.iter().sum::<f64>() / sds.len().max(1) as f64),
        patched_px,
    })
}

/// RMS error of a calibrated sensor against the truth over the truth's useful disk:
/// reprojection error (px) of each pixel's true ray, and error of its polar angle (degrees).
pub fn compare(calibrated: &Sensor, truth: &Sensor) -> (f64, f64) {
    let (mut n, mut sum_px, mut sum_deg) = (0f64, 0f64, 0f64);
    for v in (0..truth.frame_height_px).step_by(2) {
        for u in (0..truth.frame_width_px).step_by(2) {
            let (u, v) = (u as f64, v as f64);
            let Some((dir, theta)) = truth.correspondence.direction(u, v) else { continue };
            if theta > truth.max_theta_rad {
                continue;
            }
            let (pu, pv) = calibrated.correspondence.pixel(dir).unwrap_or((f64::INFINITY, f64::INFINITY));
            let t = calibrated.correspondence.angles(u, v).map_or(f64::INFINITY, |a| a.0);
            sum_px += (pu - u).powi(2) + (pv - v).powi(2);
            sum_deg += (t - theta).to_degrees().powi(2);
            n += 1.0;
        }
    }
    ((sum_px / n).sqrt(), (sum_deg / n).sqrt())
}
