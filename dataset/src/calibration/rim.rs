//! The optical centre from the elastomer's rim (90 degrees): the outer edge of the lit disk.
//!
//! A real rim is rarely a crisp dark ring: scatter in the gel, the lens' blur and the mount make
//! it a soft edge whose light fades over several pixels, and some of it may be dim where no LED
//! reaches. So: a rough circle where rays from the lit region's centroid leave it; on 720 radial
//! profiles, the strongest fall of the smoothed brightness near that circle; there a logistic
//! edge (the coating's light times its coverage, over what lies beyond) fitted to the raw
//! profile, whose centre is the rim on that ray; a robust circle through those points (Tukey's
//! biweight, sharper falls weighing more), twice from the new centre.

use super::{CalibrationError, Plane, fail};

/// The elastomer's rim: centre and radius `(u, v, r)` in frame pixels, the circle fit's rms, and
/// the median width (px) of the edge's fall, which says how sharp the rim is.
pub(super) struct Rim {
    pub(super) circle: (f64, f64, f64),
    pub(super) rms_px: f64,
    pub(super) width_px: f64,
    /// How far the centre moves over half-circles of the rim (px, see `centre_sd`).
    pub(super) centre_sd_px: f64,
}

impl Rim {
    /// How well the rim's radius is placed (px): a tenth of its fall's width, 0.3 px at least.
    pub(super) fn radius_sd_px(&self) -> f64 {
        (0.12 * self.width_px).max(0.3)
    }
}

/// How far the centre moves when the circle is fitted to half of the rim only (px, rms over
/// the eight half-circles starting every 45 degrees): a dim or unevenly lit stretch of the rim
/// that pulls the circle, or one that alone holds it in place, shows here. A fit to half a
/// circle is well placed when the rim is a clean circle.
fn centre_sd(pts: &[(f64, f64, f64)], circle: (f64, f64, f64)) -> f64 {
    const HALVES: usize = 8;
    let angle = |p: &(f64, f64, f64)| (p.1 - circle.1).atan2(p.0 - circle.0);
    let moves: Vec<f64> = (0..HALVES)
        .map(|k| {
            let start = k as f64 * std::f64::consts::TAU / HALVES as f64;
            let half: Vec<(f64, f64, f64)> = pts
                .iter()
                .copied()
                .filter(|p| (angle(p) - start).rem_euclid(std::f64::consts::TAU) < std::f64::consts::PI)
                .collect();
            robust_circle(&half).map_or(f64::INFINITY, |c| (c.0 - circle.0).hypot(c.1 - circle.1))
        })
        .collect();
    (moves.iter().map(|m| m * m).sum::<f64>() / HALVES as f64).sqrt()
}

const RAYS: usize = 720;

pub(super) fn find_rim(gray: &Plane) -> Result<Rim, CalibrationError> {
    let mut sorted = gray.v.clone();
    sorted.sort_by(f32::total_cmp);
    let pct = |p: f64| sorted[((sorted.len() - 1) as f64 * p) as usize] as f64;
    // The frame beyond the lens is the darkest tenth; the lit disk holds about half the frame.
    let (dark, lit) = (pct(0.1), pct(0.75));
    if !(lit - dark > 8.0) {
        return fail("no bright disk in the image: is this a frame of the sensor with its LEDs on?");
    }
    let level = (dark + 0.25 * (lit - dark)) as f32;
    let (mut n, mut su, mut sv) = (0f64, 0f64, 0f64);
    for (i, &v) in gray.v.iter().enumerate() {
        if v > level {
            n += 1.0;
            su += (i % gray.w) as f64;
            sv += (i / gray.w) as f64;
        }
    }
    if n < 1000.0 {
        return fail("no bright disk in the image: is this a frame of the sensor with its LEDs on?");
    }
    // Rough circle: on rays from the lit region's centroid, the outermost sample still well
    // above the dark level.
    let centre = (su / n, sv / n);
    let rough: Vec<(f64, f64)> = (0..RAYS)
        .filter_map(|i| {
            let a = i as f64 * std::f64::consts::TAU / RAYS as f64;
            let (ca, sa) = (a.cos(), a.sin());
            let mut last = None;
            let mut r = 4.0;
            loop {
                let (u, v) = (centre.0 + r * ca, centre.1 + r * sa);
                if u < 0.0 || v < 0.0 || u > (gray.w - 1) as f64 || v > (gray.h - 1) as f64 {
                    break;
                }
                if gray.at(u, v) > level {
                    last = Some((u, v));
                }
                r += 1.0;
            }
            last
        })
        .collect();
    let mut circle = rough_circle(&rough).ok_or_else(|| {
        CalibrationError("no circular edge around the lit disk: is the whole sensor in the frame?".into())
    })?;
    let mut last = Vec::new();
    for (round, reach) in [(0, 0.09), (1, 0.06)] {
        let (uc, vc, r) = circle;
        let window = (reach * r).max(20.0);
        let points = edge_points(gray, (uc, vc), r - window, r + window.max(EDGE_REACH_PX + 2.0));
        if points.len() < RAYS / 4 {
            return fail(format!(
                "the elastomer's rim is visible on only {} of {RAYS} rays from the disk's centre (round {round}): \
                 is the whole sensor in the frame?",
                points.len()
            ));
        }
        // A sharp fall places its point better than a soft one.
        let weighted: Vec<(f64, f64, f64)> = points.iter().map(|p| (p.0, p.1, 1.0 / p.2.max(1.0))).collect();
        circle =
            robust_circle(&weighted).ok_or_else(|| CalibrationError("the rim's edge points are degenerate".into()))?;
        last = points;
    }
    // The last round's points: how well they fit, how wide the fall is, how far half of them
    // would move the centre.
    let weighted: Vec<(f64, f64, f64)> = last.iter().map(|p| (p.0, p.1, 1.0 / p.2.max(1.0))).collect();
    let (res, scale) = residual_scale(&weighted, circle);
    let inliers: Vec<f64> = res.into_iter().filter(|e| e.abs() <= 3.0 * scale).collect();
    let rms_px = (inliers.iter().map(|e| e * e).sum::<f64>() / inliers.len().max(1) as f64).sqrt();
    let mut widths: Vec<f64> = last.iter().map(|p| p.2).collect();
    widths.sort_by(f64::total_cmp);
    let rim = Rim { circle, rms_px, width_px: widths[widths.len() / 2], centre_sd_px: centre_sd(&weighted, circle) };
    // A soft rim places each ray's point less precisely; a circle through hundreds of them is
    // still well placed. What is refused is a shape that is not a circle.
    if rim.rms_px > 1.5f64.max(0.4 * rim.width_px) {
        return fail(format!(
            "the elastomer's rim is not a circle (rms {:.2} px for an edge {:.1} px wide)",
            rim.rms_px, rim.width_px
        ));
    }
    Ok(rim)
}

/// On each ray from `centre`, the rim's sub-pixel radius between `r_lo` and `r_hi` and the
/// width and height of its fall, as `(u, v, width, step)`; rays without a clear fall give
/// nothing.
fn edge_points(gray: &Plane, centre: (f64, f64), r_lo: f64, r_hi: f64) -> Vec<(f64, f64, f64, f64)> {
    const STEP: f64 = 0.5;
    let r_lo = r_lo.max(4.0);
    let count = ((r_hi - r_lo) / STEP) as usize + 1;
    let mut out = Vec::new();
    for i in 0..RAYS {
        let a = i as f64 * std::f64::consts::TAU / RAYS as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let inside = |r: f64| {
            let (u, v) = (centre.0 + r * ca, centre.1 + r * sa);
            u >= 0.0 && v >= 0.0 && u <= (gray.w - 1) as f64 && v <= (gray.h - 1) as f64
        };
        // Only rays that stay in the frame well past the rim: a profile cut short by the
        // frame's edge leaves a soft rim's outer half unseen, and its fit then drifts.
        let rs: Vec<f64> = (0..count).map(|k| r_lo + STEP * k as f64).collect();
        if !inside(rs[count - 1]) {
            continue;
        }
        let prof: Vec<f64> = rs.iter().map(|&r| gray.at(centre.0 + r * ca, centre.1 + r * sa) as f64).collect();
        if let Some((r0, width, step)) = fall(&rs, &prof) {
            out.push((centre.0 + r0 * ca, centre.1 + r0 * sa, width, step));
        }
    }
    out
}

/// The strongest fall of a radial profile: its place from a smoothed derivative, then a
/// logistic edge fitted to the raw samples around it. `(radius, 10-90 % width, step)`, or `None`
/// where the fall is not clearly above what the edge model leaves unexplained.
fn fall(rs: &[f64], prof: &[f64]) -> Option<(f64, f64, f64)> {
    let n = prof.len();
    if n < 16 {
        return None;
    }
    // Derivative of a Gaussian (sigma 4 samples, 2 px).
    let taps: Vec<f64> = (-12i32..=12).map(|k| k as f64 * (-(k * k) as f64 / 32.0).exp()).collect();
    let d: Vec<f64> = (0..n)
        .map(|i| {
            taps.iter()
                .enumerate()
                .map(|(j, t)| t * prof[(i as i64 + j as i64 - 12).clamp(0, n as i64 - 1) as usize])
                .sum()
        })
        .collect();
    let (k, &steepest) = d.iter().enumerate().skip(4).take(n.saturating_sub(8)).min_by(|a, b| a.1.total_cmp(b.1))?;
    if !(steepest < 0.0) {
        return None;
    }
    let r_guess = rs[k];
    let (best, rms) = logistic_fit(rs, prof, r_guess)?;

    // A fall (bright inside, dark outside) well above what the model leaves unexplained.
    (best.step > 8.0 * rms.max(0.1) && (best.centre - r_guess).abs() < 10.0).then_some((
        best.centre,
        4.394 * best.scale,
        best.step,
    ))
}

struct Logistic {
    centre: f64,
    scale: f64,
    step: f64,
}

/// Half-width (px) of the samples every trial edge is fitted to: the same samples for all, so
/// that their residuals compare; wide enough for a soft rim's whole fall.
const EDGE_REACH_PX: f64 = 28.0;

/// Least squares of `(a + b t) L + c`, `t = r - r0`, `L = 1 / (1 + exp(t / s))`, over the
/// samples within [`EDGE_REACH_PX`] of `about`: the coating's light (smooth: a line locally)
/// times how much of it the pixel sees, over what lies beyond. The coefficients and the rms
/// residual.
fn logistic_lsq(rs: &[f64], prof: &[f64], about: f64, r0: f64, s: f64) -> Option<([f64; 3], f64)> {
    let (rows, rhs): (Vec<[f64; 3]>, Vec<f64>) = rs
        .iter()
        .zip(prof)
        .filter(|(r, _)| (**r - about).abs() <= EDGE_REACH_PX)
        .map(|(&r, &p)| {
            let (t, l) = (r - r0, 1.0 / (1.0 + ((r - r0) / s).exp()));
            ([l, t * l / EDGE_REACH_PX, 1.0], p)
        })
        .unzip();
    if rows.len() < 8 {
        return None;
    }
    let (sse, x) = super::least_squares(&rows, &rhs)?;
    Some((x, (sse / rows.len() as f64).sqrt()))
}

/// The logistic edge by a grid over `r0` and `s` (a, b, c solved linearly at each), its centre
/// refined by a parabola; the edge and its rms residual.
fn logistic_fit(rs: &[f64], prof: &[f64], r_guess: f64) -> Option<(Logistic, f64)> {
    let mut best: Option<(f64, Logistic)> = None;
    for si in 0..12 {
        let s = 0.25 * 1.4f64.powi(si);
        for ci in -24..=24 {
            let r0 = r_guess + 0.25 * ci as f64;
            let Some((x, rms)) = logistic_lsq(rs, prof, r_guess, r0, s) else { continue };
            if best.as_ref().is_none_or(|b| rms < b.0) {
                best = Some((rms, Logistic { centre: r0, scale: s, step: x[0] }));
            }
        }
    }
    let (rms, mut fit) = best?;
    let at = |r0: f64| logistic_lsq(rs, prof, r_guess, r0, fit.scale).map(|(_, rms)| rms * rms);
    if let (Some(l), Some(c), Some(r)) = (at(fit.centre - 0.25), at(fit.centre), at(fit.centre + 0.25)) {
        let denom = l - 2.0 * c + r;
        if denom > 0.0 {
            fit.centre += 0.25 * (0.5 * (l - r) / denom).clamp(-1.0, 1.0);
        }
    }
    Some((fit, rms))
}

/// A robust circle through unweighted points (the rough rim).
fn rough_circle(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let weighted: Vec<(f64, f64, f64)> = pts.iter().map(|&(x, y)| (x, y, 1.0)).collect();
    robust_circle(&weighted)
}

/// Residuals of `pts` from `circle` and their robust scale (1.4826 median absolute residual).
fn residual_scale(pts: &[(f64, f64, f64)], circle: (f64, f64, f64)) -> (Vec<f64>, f64) {
    let res: Vec<f64> = pts.iter().map(|&(x, y, _)| (x - circle.0).hypot(y - circle.1) - circle.2).collect();
    let mut abs: Vec<f64> = res.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    (res, (1.4826 * abs[abs.len() / 2]).max(0.05))
}

/// A circle through weighted points `(u, v, weight)` that a sector of wrong points cannot drag:
/// Gauss-Newton on the geometric distances with Tukey's biweight (cut at 4.685 robust scales)
/// times each point's own weight, from the algebraic fit.
fn robust_circle(pts: &[(f64, f64, f64)]) -> Option<(f64, f64, f64)> {
    let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
    let mut c = fit_circle(&xy)?;
    for _ in 0..30 {
        let (res, scale) = residual_scale(pts, c);
        let cut = 4.685 * scale;
        let (mut jtj, mut jtr) = (nalgebra::Matrix3::<f64>::zeros(), nalgebra::Vector3::<f64>::zeros());
        let mut used = 0;
        for (&(x, y, w), &e) in pts.iter().zip(&res) {
            if e.abs() >= cut {
                continue;
            }
            let tukey = (1.0 - (e / cut).powi(2)).powi(2) * w;
            let (dx, dy) = (x - c.0, y - c.1);
            let d = dx.hypot(dy).max(1e-12);
            let j = nalgebra::Vector3::new(-dx / d, -dy / d, -1.0);
            jtj += j * j.transpose() * tukey;
            jtr += j * e * tukey;
            used += 1;
        }
        if used < 20 {
            return None;
        }
        let step = jtj.try_inverse()? * jtr;
        c = (c.0 - step[0], c.1 - step[1], c.2 - step[2]);
        if step.norm() < 1e-6 {
            break;
        }
    }
    (c.2.is_finite() && c.2 > 0.0).then_some(c)
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
