//! Tooth drops along the row through the optical centre: the strip's profile, the map from
//! folding it ([`super::fold`]), each drop's pulse placed ([`super::tooth_fit`]), and each
//! side's pulses registered to the drops through the lens' odd symmetry ([`register`]).

use super::fold::{FoldedMap, StripProfile};
use super::sawtooth::SawTooth;
use super::tooth_fit::{self, ToothWindow};
use super::{CalibrationError, MatchedEdge, fail};

/// Each tooth's drop on each side: the folded map's prediction, its pulse placed by the tooth
/// fit and registered per side. Teeth whose pulse the fit does not find (hidden, broken, beyond
/// the frame) are left out. Returns the edges, the pulse's Gaussian and tail (px), and each
/// side's registration's standard error (px).
pub(super) fn locate_teeth(
    profile: &StripProfile,
    map: &FoldedMap,
    r_rim: f64,
    rim_sd_px: f64,
    indicator: &SawTooth,
) -> Result<(Vec<MatchedEdge>, f64, f64, [f64; 2]), CalibrationError> {
    let pitch_deg = indicator.pitch_deg;
    let mut windows = Vec::new();
    let mut which = Vec::new();
    let r_max = profile.offsets_px.iter().fold(0f64, |m, o| m.max(o.abs()));
    for side in [-1i8, 1] {
        for k in 1..=indicator.teeth {
            let theta = k as f64 * pitch_deg;
            let guess = map.radius_px(theta, r_rim);
            let pitch = guess - map.radius_px(theta - pitch_deg, r_rim);
            if guess + pitch > r_max {
                continue;
            }
            let mut w = ToothWindow { offsets_px: vec![], rgb: vec![], guess_px: guess, pitch_px: pitch };
            for (i, &o) in profile.offsets_px.iter().enumerate() {
                if o.signum() == side as f64 && (o.abs() - guess).abs() <= pitch {
                    w.offsets_px.push(o.abs());
                    w.rgb.push(profile.rgb[i]);
                }
            }
            windows.push(w);
            which.push((side, k));
        }
    }
    let found = tooth_fit::locate(&windows);
    let mut edges: Vec<MatchedEdge> = which
        .iter()
        .zip(&found.drops_px)
        .filter_map(|(&(side, tooth), d)| {
            d.map(|r| MatchedEdge {
                side,
                tooth,
                radius_px: r,
                theta_rad: (tooth as f64 * pitch_deg).to_radians(),
                residual_px: 0.0,
            })
        })
        .collect();
    let reg = register(&mut edges, r_rim, rim_sd_px)?;
    let offsets = reg.offsets_px;
    let pitch_px = r_rim / 90.0 * pitch_deg;
    if offsets.iter().any(|b| b.abs() > 0.3 * pitch_px) {
        return fail(format!(
            "the tooth drops sit {:.1} and {:.1} px off any fisheye's radial map left and right: the strip's profile is \
             not a saw-tooth's",
            offsets[0], offsets[1]
        ));
    }
    let reach = |s: i8| edges.iter().filter(|e| e.side == s).map(|e| e.tooth).max().unwrap_or(0);
    if edges.len() < 6 || reach(-1).max(reach(1)) < indicator.teeth / 2 {
        return fail(format!(
            "the tooth drops were found for only {} teeth, reaching tooth {} of {}: too little of the indicator is \
             visible along the row through the centre",
            edges.len(),
            reach(-1).max(reach(1)),
            indicator.teeth
        ));
    }
    // Left and right drops of one tooth sit at the same radius (the map is radial).
    let mut pairs = 0;
    let mut disagree = 0;
    for l in edges.iter().filter(|e| e.side < 0) {
        if let Some(r) = edges.iter().find(|e| e.side > 0 && e.tooth == l.tooth) {
            pairs += 1;
            if (l.radius_px - r.radius_px).abs() > 2.0 {
                disagree += 1;
            }
        }
    }
    if pairs > 0 && disagree * 4 > pairs {
        return fail(format!(
            "{disagree} of {pairs} teeth sit at different radii left and right of the centre: the indicator does not \
             pass through the optical centre"
        ));
    }
    Ok((edges, found.sigma_px, found.tail_px, reg.offsets_sd_px))
}

/// What the registration found: each side's offset of the pulses from the drops (px) and its
/// standard error.
pub(super) struct Registration {
    pub(super) offsets_px: [f64; 2],
    pub(super) offsets_sd_px: [f64; 2],
}

/// Where a drop's pulse sits relative to the drop depends on how the lighting shades it, which
/// differs from one side of the strip to the other but hardly along it. A lens's radial map is
/// odd in theta (`r(-theta) = -r(theta)`: a polynomial in odd powers), so a constant offset of
/// every pulse on a side is told apart from the map: `r = b_side + a1 x + a3 x^3 + a5 x^5 + a7 x^7`
/// (`x = theta / 90 deg`) through the pulses, weighted least squares, the worst-fitting pulses
/// dropped (from the fit and from `edges`). The rim (`r_rim` at `x = 1`, no offset) joins with
/// the weight its own uncertainty `rim_sd_px` gives it against the pulses' scatter: a sharp rim
/// steadies the offsets, a soft one hardly moves them. Each side's `b` is taken off its pulses.
pub(super) fn register(
    edges: &mut Vec<MatchedEdge>,
    r_rim: f64,
    rim_sd_px: f64,
) -> Result<Registration, CalibrationError> {
    use std::f64::consts::FRAC_PI_2;
    let mut keep = vec![true; edges.len()];
    let mut solution = None;
    let mut scatter = f64::INFINITY;
    for _ in 0..4 {
        let mut rows: Vec<(usize, [f64; 6], f64, f64)> = edges
            .iter()
            .enumerate()
            .filter(|(i, _)| keep[*i])
            .map(|(i, e)| {
                let x = e.theta_rad / FRAC_PI_2;
                let side = [f64::from(e.side < 0), f64::from(e.side > 0)];
                (i, [side[0], side[1], x, x.powi(3), x.powi(5), x.powi(7)], e.radius_px, 1.0)
            })
            .collect();
        if scatter.is_finite() {
            rows.push((usize::MAX, [0.0, 0.0, 1.0, 1.0, 1.0, 1.0], r_rim, scatter / rim_sd_px.max(1e-3)));
        }
        if rows.len() < 8 {
            return fail(format!("only {} tooth drops fit a fisheye's radial map", rows.len()));
        }
        let a = nalgebra::DMatrix::from_fn(rows.len(), 6, |i, j| rows[i].1[j] * rows[i].3);
        let b = nalgebra::DVector::from_fn(rows.len(), |i, _| rows[i].2 * rows[i].3);
        let x = a
            .clone()
            .svd(true, true)
            .solve(&b, 1e-12)
            .map_err(|e| CalibrationError(format!("radial map through the drops: {e}")))?;
        let res = &a * &x - &b;
        let edge_res: Vec<f64> =
            rows.iter().zip(res.iter()).filter(|(r, _)| r.0 != usize::MAX).map(|(_, v)| *v).collect();
        let mut abs: Vec<f64> = edge_res.iter().map(|v| v.abs()).collect();
        abs.sort_by(f64::total_cmp);
        let limit = 4.0 * 1.4826 * abs[abs.len() / 2].max(0.05);
        for (r, v) in rows.iter().zip(res.iter()) {
            if r.0 != usize::MAX && v.abs() > limit {
                keep[r.0] = false;
            }
        }
        // The pulses' scatter about the map (the kept ones), for the rim's weight and the
        // offsets' errors.
        let inside: Vec<f64> = edge_res.iter().copied().filter(|v| v.abs() <= limit).collect();
        let dof = (inside.len() as f64 - 6.0).max(1.0);
        scatter = (inside.iter().map(|v| v * v).sum::<f64>() / dof).sqrt().max(0.02);
        let cov = (a.transpose() * &a).try_inverse().map(|m| m * scatter * scatter);
        let sd = cov.map_or([f64::INFINITY; 2], |c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt()]);
        solution = Some(Registration { offsets_px: [x[0], x[1]], offsets_sd_px: sd });
    }
    let reg = solution.expect("four rounds ran");
    let mut kept = keep.iter();
    edges.retain(|_| *kept.next().expect("one flag an edge"));
    for e in edges.iter_mut() {
        e.radius_px -= reg.offsets_px[usize::from(e.side > 0)];
    }
    Ok(reg)
}
