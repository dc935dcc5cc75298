//! Fisheye calibration from one image of the saw-tooth indicator, as in the paper (a real
//! camera frame or a simulated one). It reads what a real gel shows, not what a renderer draws:
//! every step below works on smoothed, draped, blurred, gamma-encoded, noisy and chroma-
//! subsampled frames, and is tested on frames of an image model written apart from the
//! project's renderer (the `gelcam` crate).
//!
//! 1. The optical centre: the elastomer's rim (90 degrees) is a circle about it. On 720 radial
//!    rays a logistic edge (light times coverage over what lies beyond) places the rim, soft or
//!    sharp; a robust circle through those points gives the centre and radius, and circles
//!    through half the rim say how far a badly lit stretch may have pulled it (`rim`).
//! 2. The radial map, roughly: the one under which the strip's colour profile repeats best
//!    from tooth to tooth (`fold`).
//! 3. Each drop's pulse, to a fraction of a pixel: a pulse shape shared by all teeth, fitted
//!    window by window (`tooth_fit`); a hidden tooth explains nothing and is left out.
//! 4. Each side's pulses registered to the drops: a lens's map is odd in theta, so a side's
//!    constant offset (the lighting's doing) is told apart from the map (`teeth::register`).
//! 5. A Gaussian process maps image radius to theta (or, as the paper writes it, to
//!    `R sin(theta)`), through the centre (0, 0), every drop and the rim, the rim weighted by
//!    its sharpness (`table`).
//!
//! Every stage checks its result and fails with a message rather than return a wrong map, and
//! the result states its uncertainty; a frame that places the map less well than asked is
//! refused with what limits it.

use image::RgbImage;
use sensor::Sensor;

mod fold;
pub mod gp;
mod rim;
pub mod sawtooth;
mod table;
mod teeth;
mod tooth_fit;

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
    /// Refuse a frame that places the map less precisely than this (px, rms over the useful
    /// disk, two standard deviations).
    pub max_uncertainty_px: f64,
}

/// What no estimate here sees (the lens beyond an odd polynomial, shading that changes along the
/// strip), as a standard deviation in pixels: the spread of 40 simulated units' errors about
/// their other terms.
const UNMODELLED_SD_PX: f64 = 0.1;

/// The project's goal for a calibration: 0.5 px rms over the useful disk.
pub const DEFAULT_MAX_UNCERTAINTY_PX: f64 = 0.5;

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            radius_mm: 25.0,
            indicator: SawTooth::default(),
            target: GpTarget::Theta,
            max_uncertainty_px: DEFAULT_MAX_UNCERTAINTY_PX,
        }
    }
}

impl Calibration {
    /// The teeth without an edge as people and `--hide-teeth` name them: `+3` the third from
    /// the apex on the +x side, `-3` on the -x side.
    pub fn missing_teeth(&self) -> Vec<String> {
        self.missing.iter().map(|(s, k)| format!("{}{k}", if *s < 0 { "-" } else { "+" })).collect()
    }
}

impl CalibrationOptions {
    /// Refuses options no frame could satisfy: teeth past the dome's rim, a non-positive radius
    /// or uncertainty.
    pub fn validate(&self) -> Result<(), CalibrationError> {
        let SawTooth { pitch_deg, teeth, .. } = self.indicator;
        if !(pitch_deg > 0.0 && pitch_deg * teeth as f64 <= 90.0) {
            return fail(format!(
                "the indicator's {teeth} teeth {pitch_deg} degrees apart reach past the rim: pitch x teeth must \
                 stay within 90 degrees"
            ));
        }
        if !(self.radius_mm > 0.0 && self.radius_mm.is_finite()) {
            return fail(format!("the dome's radius must be a positive number of mm, got {}", self.radius_mm));
        }
        if !(self.max_uncertainty_px > 0.0) {
            return fail(format!(
                "the largest uncertainty allowed must be a positive number of pixels, got {}",
                self.max_uncertainty_px
            ));
        }
        Ok(())
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
    /// The pulse each drop draws, as the tooth fit found it: its Gaussian and its outward tail
    /// (px; a tail is what a one-sided drape draws).
    pub pulse_sigma_px: f64,
    pub pulse_tail_px: f64,
    /// Width (10 to 90 %) of the rim's fall (px).
    pub rim_width_px: f64,
    /// How far the optical centre from the rim may be off (px): its spread over half-circles.
    pub centre_sd_px: f64,
    /// How far off the map may be (px, rms over the useful disk, two standard deviations of
    /// what moves it): the centre, the teeth's registration, the regression.
    pub uncertainty_px: f64,
}

#[derive(Debug, thiserror::Error)]
#[error("calibration failed: {0}")]
pub struct CalibrationError(pub String);

pub(super) fn fail<T>(why: impl Into<String>) -> Result<T, CalibrationError> {
    Err(CalibrationError(why.into()))
}

/// Least-squares residual of `rhs` on `rows` (each of `K` entries): the sum of squares left and
/// the solution, or `None` where the system is singular.
pub(super) fn least_squares<const K: usize>(rows: &[[f64; K]], rhs: &[f64]) -> Option<(f64, [f64; K])> {
    let mut ata = nalgebra::SMatrix::<f64, K, K>::zeros();
    let mut atb = nalgebra::SVector::<f64, K>::zeros();
    let mut bb = 0.0;
    for (row, &y) in rows.iter().zip(rhs) {
        let r = nalgebra::SVector::<f64, K>::from_row_slice(row);
        ata += r * r.transpose();
        atb += r * y;
        bb += y * y;
    }
    let ridge = 1e-9 * ata.trace() / K as f64;
    for i in 0..K {
        ata[(i, i)] += ridge;
    }
    let x = ata.cholesky()?.solve(&atb);
    Some(((bb - x.dot(&atb)).max(0.0), std::array::from_fn(|i| x[i])))
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
    let ind = &opts.indicator;
    let profile = fold::StripProfile::read(&channels, uc, vc, r_rim)?;
    let map = fold::fold_map(&profile, r_rim, ind.pitch_deg, ind.teeth)?;
    let (edges, pulse_sigma_px, pulse_tail_px, offsets_sd) =
        teeth::locate_teeth(&profile, &map, r_rim, rim.radius_sd_px(), ind)?;

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
    let mean_sd_deg = to_deg(sds.iter().sum::<f64>() / sds.len().max(1) as f64);
    // What can move the map, as standard deviations in pixels: the optical centre, each side's
    // registration of the pulses, and the regression through the drops. Stated at two of them.
    let offset_sd = (0.5 * (offsets_sd[0].powi(2) + offsets_sd[1].powi(2))).sqrt();
    let gp_px = mean_sd_deg * r_rim / 90.0;
    let uncertainty_px =
        2.0 * (rim.centre_sd_px.powi(2) + offset_sd.powi(2) + gp_px.powi(2) + UNMODELLED_SD_PX.powi(2)).sqrt();
    if !(uncertainty_px <= opts.max_uncertainty_px) {
        return fail(format!(
            "the frame places the fisheye only to +-{uncertainty_px:.2} px (two standard deviations; the optical \
             centre from the rim +-{:.2}, the teeth's registration +-{offset_sd:.2}, the map between the teeth \
             +-{gp_px:.2}), more than the {:.2} px asked for: light the rim evenly (its edge is {:.0} px wide), \
             press the indicator flat along the row through the centre, or allow more with --max-uncertainty-px",
            rim.centre_sd_px, opts.max_uncertainty_px, rim.width_px
        ));
    }
    Ok(Calibration {
        sensor,
        rim_radius_px: r_rim,
        rim_rms_px: rim.rms_px,
        edges,
        missing,
        fit_rms_px,
        max_sd_deg: to_deg(sds.iter().copied().fold(0.0, f64::max)),
        mean_sd_deg,
        patched_px,
        pulse_sigma_px,
        pulse_tail_px,
        rim_width_px: rim.width_px,
        centre_sd_px: rim.centre_sd_px,
        uncertainty_px,
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
