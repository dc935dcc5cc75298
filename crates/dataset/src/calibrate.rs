//! Fisheye calibration from one image of the saw-tooth indicator, as in the paper.
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
use imageproc::edges::canny;
use sensor::{Correspondence, RadialMap, Sensor};

use crate::gp::Gp;
use crate::sawtooth::SawTooth;

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

fn fail<T>(why: impl Into<String>) -> Result<T, CalibrationError> {
    Err(CalibrationError(why.into()))
}

/// One colour channel as floats, with bilinear sampling.
struct Plane {
    w: usize,
    h: usize,
    v: Vec<f32>,
}

impl Plane {
    fn of(img: &RgbImage, channel: Option<usize>) -> Self {
        let v = img
            .pixels()
            .map(|p| match channel {
                Some(c) => p.0[c] as f32,
                None => (p.0[0] as f32 + p.0[1] as f32 + p.0[2] as f32) / 3.0,
            })
            .collect();
        Plane { w: img.width() as usize, h: img.height() as usize, v }
    }

    fn at(&self, u: f64, v: f64) -> f32 {
        let (u, v) = (u.clamp(0.0, (self.w - 1) as f64), v.clamp(0.0, (self.h - 1) as f64));
        let (x0, y0) = ((u.floor() as usize).min(self.w - 2), (v.floor() as usize).min(self.h - 2));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let p = |x: usize, y: usize| self.v[y * self.w + x];
        let top = p(x0, y0) * (1.0 - fx) + p(x0 + 1, y0) * fx;
        let bottom = p(x0, y0 + 1) * (1.0 - fx) + p(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    fn gray(&self) -> GrayImage {
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
    let rim = find_rim(&gray)?;
    let (uc, vc, r_rim) = rim.circle;
    let candidates = find_tooth_edges(&channels, uc, vc, r_rim, &opts.indicator)?;
    let pitch = opts.indicator.pitch_deg.to_radians();
    let edges = match_edges(&candidates, r_rim, pitch, opts.indicator.teeth)?;

    let mut xs = vec![0.0];
    let mut thetas = vec![0.0];
    for e in &edges {
        xs.push(e.radius_px);
        thetas.push(e.theta_rad);
    }
    xs.push(r_rim);
    thetas.push(std::f64::consts::FRAC_PI_2);
    let radius_mm = opts.radius_mm;
    let ys: Vec<f64> = match opts.target {
        GpTarget::Theta => thetas.clone(),
        GpTarget::RSinTheta => thetas.iter().map(|t| radius_mm * t.sin()).collect(),
    };
    let gp = Gp::fit(&xs, &ys, 1e-6).map_err(|e| CalibrationError(format!("regression: {e}")))?;
    let theta_at = |r: f64| -> (f64, f64) {
        let (m, sd) = gp.predict(r);
        match opts.target {
            GpTarget::Theta => (m, sd),
            GpTarget::RSinTheta => {
                let s = (m / radius_mm).clamp(-1.0, 1.0);
                let slope = 1.0 / (radius_mm * (1.0 - s * s).sqrt().max(1e-3));
                (s.asin(), sd * slope)
            }
        }
    };

    // Table out to the frame's far corner. Inside the rim: the GP. Where `R sin(theta)` is the
    // target it flattens at the rim and its inverse loses precision; from where the inverse stops
    // rising, theta is interpolated to the rim's 90 degrees. Past the rim (not useful pixels)
    // theta continues along the map's slope at the rim.
    let mut sensor = Sensor::with_radius(radius_mm);
    sensor.frame_width_px = img.width();
    sensor.frame_height_px = img.height();
    let r_end = (img.width() as f64).hypot(img.height() as f64);
    let (mut radius_px, mut theta_rad) = (vec![0.0], vec![0.0]);
    let mut sds = Vec::new();
    let rim_theta = match opts.target {
        GpTarget::Theta => theta_at(r_rim).0,
        GpTarget::RSinTheta => std::f64::consts::FRAC_PI_2,
    };
    let mut r = 1.0;
    while r < r_rim {
        let (t, sd) = theta_at(r);
        let rising = t > *theta_rad.last().unwrap() && (t < rim_theta || opts.target == GpTarget::Theta);
        if !rising {
            if opts.target == GpTarget::Theta {
                return fail(format!(
                    "the fitted map is not increasing at radius {r:.0} px (theta {:.2} deg): \
                     the tooth edges found do not describe a fisheye",
                    t.to_degrees()
                ));
            }
            break;
        }
        radius_px.push(r);
        theta_rad.push(t);
        sds.push(sd);
        r += 1.0;
    }
    let (r0, t0) = (*radius_px.last().unwrap(), *theta_rad.last().unwrap());
    let patched_px = (r_rim - r0 - 1.0).max(0.0);
    while r < r_rim {
        radius_px.push(r);
        theta_rad.push(t0 + (rim_theta - t0) * (r - r0) / (r_rim - r0));
        r += 1.0;
    }
    let n = radius_px.len();
    let rim_slope = (rim_theta - theta_rad[n - 4]) / (r_rim - radius_px[n - 4]);
    while r <= r_end + 1.0 {
        radius_px.push(r);
        theta_rad.push(rim_theta + (r - r_rim) * rim_slope);
        r += 1.0;
    }
    sensor.correspondence =
        Correspondence { centre_u_px: uc, centre_v_px: vc, radial: RadialMap::Tabulated { radius_px, theta_rad } };
    sensor.validate().map_err(|e| CalibrationError(format!("the result is not a valid sensor: {e}")))?;

    // Residuals in pixels: theta residual over the local slope of the map.
    let mut edges = edges;
    let mut sum2 = 0.0;
    for e in &mut edges {
        let (t, _) = theta_at(e.radius_px);
        let slope = (theta_at(e.radius_px + 0.5).0 - theta_at(e.radius_px - 0.5).0).max(1e-9);
        e.residual_px = (t - e.theta_rad) / slope;
        sum2 += e.residual_px * e.residual_px;
    }
    let fit_rms_px = (sum2 / edges.len() as f64).sqrt();
    if fit_rms_px > 1.0 {
        return fail(format!(
            "matched edges lie {fit_rms_px:.2} px (rms) from a smooth map: the image is too noisy or \
             the indicator is not pressed along the row through the centre"
        ));
    }
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

struct Rim {
    circle: (f64, f64, f64),
    rms_px: f64,
}

/// The elastomer's rim: rough disk from a threshold, Canny edge points near its boundary,
/// then sub-pixel points on radial profiles and a trimmed circle fit.
fn find_rim(gray: &Plane) -> Result<Rim, CalibrationError> {
    let g8 = gray.gray();
    let level = imageproc::contrast::otsu_level(&g8) as f32;
    let (mut n, mut su, mut sv) = (0f64, 0f64, 0f64);
    let (mut bright, mut dark) = ((0f64, 0f64), (0f64, 0f64));
    for (i, &v) in gray.v.iter().enumerate() {
        if v > level {
            n += 1.0;
            su += (i % gray.w) as f64;
            sv += (i / gray.w) as f64;
            bright = (bright.0 + v as f64, bright.1 + 1.0);
        } else {
            dark = (dark.0 + v as f64, dark.1 + 1.0);
        }
    }
    let contrast = bright.0 / bright.1.max(1.0) - dark.0 / dark.1.max(1.0);
    if n < 1000.0 || !(contrast > 8.0) {
        return fail("no bright disk in the image: is this a frame of the sensor with its LEDs on?");
    }
    let (mut uc, mut vc, mut r) = (su / n, sv / n, (n / std::f64::consts::PI).sqrt());
    let edges = canny(&g8, (contrast * 0.4) as f32, (contrast * 0.9) as f32);
    let mut pts: Vec<(f64, f64)> = edges
        .enumerate_pixels()
        .filter(|p| p.2.0[0] > 0)
        .map(|(x, y, _)| (x as f64, y as f64))
        .filter(|&(x, y)| ((x - uc).hypot(y - vc) - r).abs() < 0.08 * r + 6.0)
        .collect();
    for band in [8.0, 3.0] {
        if pts.len() < 50 {
            return fail(format!("found only {} edge points near the elastomer's rim", pts.len()));
        }
        (uc, vc, r) =
            fit_circle(&pts).ok_or_else(|| CalibrationError("the rim's edge points are degenerate".into()))?;
        pts.retain(|&(x, y)| ((x - uc).hypot(y - vc) - r).abs() < band);
    }
    // Sub-pixel: the steepest fall of brightness along each radial profile.
    let mut fine = Vec::new();
    for i in 0..1440 {
        let a = i as f64 * std::f64::consts::TAU / 1440.0;
        let (ca, sa) = (a.cos(), a.sin());
        let prof: Vec<f32> = (0..=48)
            .map(|k| gray.at(uc + (r - 6.0 + 0.25 * k as f64) * ca, vc + (r - 6.0 + 0.25 * k as f64) * sa))
            .collect();
        let d: Vec<f32> = (1..prof.len() - 1).map(|k| prof[k + 1] - prof[k - 1]).collect();
        let (k, &best) = d.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).unwrap();
        if !(-best > contrast as f32 * 0.1) || k == 0 || k + 1 == d.len() {
            continue;
        }
        let (l, c, rr) = (d[k - 1] as f64, d[k] as f64, d[k + 1] as f64);
        let denom = l - 2.0 * c + rr;
        let off = if denom.abs() > 1e-9 { 0.5 * (l - rr) / denom } else { 0.0 };
        let rad = r - 6.0 + 0.25 * (k as f64 + 1.0 + off.clamp(-1.0, 1.0));
        fine.push((uc + rad * ca, vc + rad * sa));
    }
    if fine.len() < 200 {
        return fail(format!("the elastomer's rim is visible in only {} of 1440 directions", fine.len()));
    }
    let mut circle = fit_circle(&fine).unwrap();
    for _ in 0..3 {
        let res: Vec<f64> = fine.iter().map(|&(x, y)| (x - circle.0).hypot(y - circle.1) - circle.2).collect();
        let rms = (res.iter().map(|e| e * e).sum::<f64>() / res.len() as f64).sqrt();
        let keep: Vec<(f64, f64)> =
            fine.iter().zip(&res).filter(|(_, e)| e.abs() <= (3.0 * rms).max(0.05)).map(|(p, _)| *p).collect();
        fine = keep;
        circle = fit_circle(&fine).unwrap();
    }
    let rms = (fine.iter().map(|&(x, y)| ((x - circle.0).hypot(y - circle.1) - circle.2).powi(2)).sum::<f64>()
        / fine.len() as f64)
        .sqrt();
    if rms > 1.5 {
        return fail(format!("the elastomer's rim is not a circle (rms {rms:.2} px)"));
    }
    Ok(Rim { circle, rms_px: rms })
}

/// Algebraic (Kasa) circle fit, then Gauss-Newton on the geometric distances.
fn fit_circle(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let (mut suu, mut svv, mut suv, mut suuu, mut svvv, mut suvv, mut svuu) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x, y) in pts {
        let (u, v) = (x - mx, y - my);
        suu += u * u;
        svv += v * v;
        suv += u * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    let det = suu * svv - suv * suv;
    if !(det.abs() > 1e-12) {
        return None;
    }
    let (b1, b2) = (0.5 * (suuu + suvv), 0.5 * (svvv + svuu));
    let (mut a, mut b) = ((b1 * svv - b2 * suv) / det, (b2 * suu - b1 * suv) / det);
    let mut r = (a * a + b * b + (suu + svv) / n).sqrt();
    for _ in 0..10 {
        let (mut jtj, mut jtr) = (nalgebra::Matrix3::<f64>::zeros(), nalgebra::Vector3::<f64>::zeros());
        for &(x, y) in pts {
            let (dx, dy) = (x - mx - a, y - my - b);
            let d = dx.hypot(dy).max(1e-12);
            let j = nalgebra::Vector3::new(-dx / d, -dy / d, -1.0);
            jtj += j * j.transpose();
            jtr += j * (d - r);
        }
        let step = jtj.try_inverse()? * jtr;
        a -= step[0];
        b -= step[1];
        r -= step[2];
        if step.norm() < 1e-10 {
            break;
        }
    }
    (r.is_finite() && r > 0.0).then_some((a + mx, b + my, r))
}

/// A tooth-edge candidate on the centre row: signed distance from the centre (px) and strength.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    offset_px: f64,
    strength: f64,
}

/// Thin lines across the centre row, gated by Canny edges near them.
fn find_tooth_edges(
    channels: &[Plane],
    uc: f64,
    vc: f64,
    r_rim: f64,
    indicator: &SawTooth,
) -> Result<Vec<Candidate>, CalibrationError> {
    let (w, h) = (channels[0].w, channels[0].h);
    let row = vc.round() as i64;
    if row < 4 || row + 4 >= h as i64 {
        return fail("the optical centre's row is too close to the image's border");
    }
    // Canny on each channel, any channel's edge counts.
    let mut edge_cols = vec![false; w];
    for p in channels {
        let g = p.gray();
        let e = canny(&g, 6.0, 15.0);
        for y in (row - 4)..=(row + 4) {
            for (x, col) in edge_cols.iter_mut().enumerate() {
                *col |= e.get_pixel(x as u32, y as u32).0[0] > 0;
            }
        }
    }
    // Median over the rows about the centre: robust to specks, keeps lines that cross the row.
    let rows: Vec<f64> = (-3..=3).map(|k| vc + k as f64).collect();
    let profile = |p: &Plane, u: f64| -> f32 {
        let mut v: Vec<f32> = rows.iter().map(|&y| p.at(u, y)).collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let lo = (uc - r_rim).ceil().max(2.0) as i64;
    let hi = (uc + r_rim).floor().min(w as f64 - 3.0) as i64;
    let n = (hi - lo + 1).max(0) as usize;
    let prof: Vec<[f32; 3]> =
        (0..n).map(|i| std::array::from_fn(|c| profile(&channels[c], (lo + i as i64) as f64))).collect();
    // Ridge response: a sample against the mean of its neighbours two pixels away.
    let mut s = vec![0f64; n];
    for i in 2..n.saturating_sub(2) {
        s[i] = (0..3).map(|c| (prof[i][c] - 0.5 * (prof[i - 2][c] + prof[i + 2][c])).abs() as f64).sum();
    }
    let mut sorted = s.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[n / 2];
    let mad = {
        let mut d: Vec<f64> = s.iter().map(|v| (v - median).abs()).collect();
        d.sort_by(f64::total_cmp);
        d[n / 2]
    };
    let threshold = median + 8.0 * mad.max(0.25);
    let pitch_px = r_rim / 90.0 * indicator.pitch_deg;
    let mut out = Vec::new();
    for i in 1..n.saturating_sub(1) {
        let u = lo + i as i64;
        let offset = u as f64 - uc;
        if s[i] < threshold || s[i] < s[i - 1] || s[i] <= s[i + 1] || offset.abs() < 0.5 * pitch_px {
            continue;
        }
        let gated = (-3..=3).any(|d| {
            let x = u + d;
            x >= 0 && (x as usize) < w && edge_cols[x as usize]
        });
        if !gated {
            continue;
        }
        // Centroid of the response above the background over the peak and its neighbours.
        let (mut sw, mut swx) = (0.0, 0.0);
        for d in -1i64..=1 {
            let j = (i as i64 + d) as usize;
            let wgt = (s[j] - median).max(0.0);
            sw += wgt;
            swx += wgt * d as f64;
        }
        out.push(Candidate { offset_px: offset + swx / sw.max(1e-12), strength: s[i] });
    }
    // The ridge filter answers a line at +-2 px with side lobes of half its height: keep only
    // the strongest response within 3 px.
    out.sort_by(|a, b| b.strength.total_cmp(&a.strength));
    let mut kept: Vec<Candidate> = Vec::new();
    for c in out {
        if kept.iter().all(|k| (k.offset_px - c.offset_px).abs() > 3.0) {
            kept.push(c);
        }
    }
    let out = kept;
    if out.len() < 6 {
        return fail(format!(
            "found only {} tooth edges along row {row}: is the saw-tooth indicator pressed along the image's \
             x axis through the centre?",
            out.len()
        ));
    }
    Ok(out)
}

/// Assigns candidates to teeth by a radial model refitted as edges are accepted.
fn match_edges(cands: &[Candidate], r_rim: f64, pitch: f64, teeth: u32) -> Result<Vec<MatchedEdge>, CalibrationError> {
    use std::f64::consts::FRAC_PI_2;
    // theta(r) = a x + b x^3 + c x^5 with x = r / r_rim; starts equidistant through the rim.
    let mut model = [FRAC_PI_2, 0.0, 0.0];
    let eval = |m: &[f64; 3], r: f64| {
        let x = r / r_rim;
        x * (m[0] + x * x * (m[1] + x * x * m[2]))
    };
    let mut matched: Vec<MatchedEdge> = Vec::new();
    for (round, tolerance) in [0.3, 0.25, 0.2, 0.15].into_iter().enumerate() {
        matched.clear();
        for c in cands {
            let r = c.offset_px.abs();
            let t = eval(&model, r);
            let k = (t / pitch).round();
            if k < 1.0 || k > teeth as f64 || (t / pitch - k).abs() > tolerance {
                continue;
            }
            let e = MatchedEdge {
                side: if c.offset_px < 0.0 { -1 } else { 1 },
                tooth: k as u32,
                radius_px: r,
                theta_rad: k * pitch,
                residual_px: (t - k * pitch).abs(),
            };
            // Two candidates for one tooth: keep the one nearer the model, or the stronger
            // if the model cannot tell.
            if let Some(prev) = matched.iter_mut().find(|m| m.side == e.side && m.tooth == e.tooth) {
                if e.residual_px < prev.residual_px {
                    *prev = e;
                }
                continue;
            }
            matched.push(e);
        }
        if matched.len() < 6 {
            return fail(format!(
                "only {} edges match teeth every {:.1} degrees (round {round}): not a saw-tooth image, \
                 or another pitch",
                matched.len(),
                pitch.to_degrees()
            ));
        }
        // Refit the odd polynomial through the matched edges and the rim.
        let rows = matched.len() + 1;
        let a = nalgebra::DMatrix::from_fn(rows, 3, |i, j| {
            let r = if i < matched.len() { matched[i].radius_px } else { r_rim };
            let x = r / r_rim;
            x.powi(2 * j as i32 + 1) * if i < matched.len() { 1.0 } else { 10.0 }
        });
        let b =
            nalgebra::DVector::from_fn(
                rows,
                |i, _| if i < matched.len() { matched[i].theta_rad } else { 10.0 * FRAC_PI_2 },
            );
        let svd = a.svd(true, true);
        let sol = svd.solve(&b, 1e-12).map_err(|e| CalibrationError(format!("radial model fit: {e}")))?;
        model = [sol[0], sol[1], sol[2]];
    }
    // Strong edges along the indicator that match no tooth mean the pitch is wrong or this is
    // not a saw-tooth image; a speck or two is tolerated.
    let reach = matched.iter().map(|m| m.radius_px).fold(0.0, f64::max);
    let first = matched.iter().map(|m| m.radius_px).fold(f64::INFINITY, f64::min);
    let unmatched = cands
        .iter()
        .filter(|c| (first..=reach).contains(&c.offset_px.abs()))
        .filter(|c| !matched.iter().any(|m| (m.radius_px - c.offset_px.abs()).abs() < 1e-9))
        .count();
    if unmatched > 3.max(matched.len() / 5) {
        return fail(format!(
            "{unmatched} edges along the indicator match no tooth ({} do): is its pitch {:.1} degrees?",
            matched.len(),
            pitch.to_degrees()
        ));
    }
    let sides: Vec<i8> = matched.iter().map(|m| m.side).collect();
    let teeth_seen = |s: i8| matched.iter().filter(|m| m.side == s).map(|m| m.tooth).max().unwrap_or(0);
    if teeth_seen(-1).max(teeth_seen(1)) < teeth / 2 || !sides.contains(&1) && !sides.contains(&-1) {
        return fail(format!(
            "tooth edges reach only tooth {} of {teeth}: too little of the indicator is visible",
            teeth_seen(-1).max(teeth_seen(1))
        ));
    }
    // Left and right edges of one tooth must sit at the same radius (the map is radial).
    let mut disagree = 0;
    let mut pairs = 0;
    for l in matched.iter().filter(|m| m.side < 0) {
        if let Some(r) = matched.iter().find(|m| m.side > 0 && m.tooth == l.tooth) {
            pairs += 1;
            if (l.radius_px - r.radius_px).abs() > 2.0 {
                disagree += 1;
            }
        }
    }
    if pairs > 0 && disagree * 5 > pairs {
        return fail(format!(
            "{disagree} of {pairs} teeth sit at different radii left and right of the centre: the indicator \
             does not pass through the optical centre"
        ));
    }
    Ok(matched)
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
