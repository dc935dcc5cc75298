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
    offsets_plausible(offsets, pitch_px)?;
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
    left_right_agree(&edges, pitch_px)?;
    Ok((edges, found.sigma_px, found.tail_px, reg.offsets_sd_px))
}

/// A side's pulses may sit off its drops by what the lighting does, not by 0.3 of the pitch or
/// more: beyond that the teeth may be numbered one off. Refused with what the offsets say: the
/// same on both sides (measured on the independent image model's refusals) is the pulses read
/// at another band of the teeth's shading; opposite, the strip's apex is off the optical centre
/// found from the rim.
fn offsets_plausible([left, right]: [f64; 2], pitch_px: f64) -> Result<(), CalibrationError> {
    if left.abs() <= 0.3 * pitch_px && right.abs() <= 0.3 * pitch_px {
        return Ok(());
    }
    let opening = format!(
        "the tooth drops sit {left:+.1} px (left) and {right:+.1} px (right) off any fisheye's radial map through the \
         centre, more than 0.3 of the {pitch_px:.1} px pitch that a lighting offset reaches"
    );
    let why = if left.signum() == right.signum() {
        "alike on both sides: the pulses were read at another band of the teeth's shading, or the teeth numbered one \
         off (is the indicator's pitch right?); light the strip more evenly"
            .to_string()
    } else {
        format!(
            "opposite on the two sides: the optical centre found from the rim is off by about {:.1} px along the strip \
             (a dim or unevenly lit stretch of the rim pulls it), or the indicator's apex is not on the centre",
            0.5 * (right - left).abs()
        )
    };
    fail(format!("{opening}; {why}"))
}

/// Left and right drops of one tooth sit at the same radius (the map is radial) once each side's
/// offset is taken off; where more than a quarter of the pairs differ by over 2 px, the frame is
/// refused. A centre or apex off along the strip moves all of a side's drops alike, which the
/// offsets take; what is left is drops placed inconsistently, measured on the independent image
/// model's refusals as some pairs half a tooth from the others (one side's drop read at another
/// band of the teeth's shading).
fn left_right_agree(edges: &[MatchedEdge], pitch_px: f64) -> Result<(), CalibrationError> {
    let mut diffs: Vec<f64> = edges
        .iter()
        .filter(|l| l.side < 0)
        .filter_map(|l| edges.iter().find(|r| r.side > 0 && r.tooth == l.tooth).map(|r| r.radius_px - l.radius_px))
        .collect();
    let pairs = diffs.len();
    let disagree = diffs.iter().filter(|d| d.abs() > 2.0).count();
    if pairs == 0 || disagree * 4 <= pairs {
        return Ok(());
    }
    diffs.sort_by(f64::total_cmp);
    let (low, high) = (diffs[0], diffs[pairs - 1]);
    let why = if high - low >= 0.3 * pitch_px {
        format!(
            "spread over {:.1} px, {:.2} of the {pitch_px:.1} px pitch: on one side some drops were read at another band \
             of the teeth's shading; light the strip more evenly",
            high - low,
            (high - low) / pitch_px
        )
    } else {
        "the drops were not placed consistently on the two sides".to_string()
    };
    fail(format!(
        "{disagree} of {pairs} teeth sit at different radii left and right of the centre (by {low:+.1} to {high:+.1} px, \
         right minus left); {why}"
    ))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Drops of teeth 1..=12 on both sides, the right ones moved by `shift(tooth)` px.
    fn pairs(shift: impl Fn(u32) -> f64) -> Vec<MatchedEdge> {
        let edge = |side: i8, tooth: u32, radius_px: f64| MatchedEdge {
            side,
            tooth,
            radius_px,
            theta_rad: (5.0 * tooth as f64).to_radians(),
            residual_px: 0.0,
        };
        (1..=12).flat_map(|k| [edge(-1, k, 15.0 * k as f64), edge(1, k, 15.0 * k as f64 + shift(k))]).collect()
    }

    #[test]
    fn left_and_right_drops_that_disagree_are_refused_with_what_the_difference_looks_like() {
        // Within 2 px, or few teeth off: kept.
        assert!(left_right_agree(&pairs(|k| 0.3 * (k % 3) as f64 - 0.3), 15.0).is_ok());
        assert!(left_right_agree(&pairs(|k| if k <= 3 { 7.5 } else { 0.0 }), 15.0).is_ok());
        // Half of them half a tooth from the others: read at another band.
        let e = left_right_agree(&pairs(|k| if k % 2 == 0 { -3.5 } else { 3.5 }), 15.0).unwrap_err().to_string();
        assert!(
            e.contains("12 of 12 teeth") && e.contains("by -3.5 to +3.5 px") && e.contains("0.47 of the 15.0"),
            "{e}"
        );
        let e = left_right_agree(&pairs(|k| if k % 2 == 0 { -2.5 } else { 1.0 }), 15.0).unwrap_err().to_string();
        assert!(e.contains("6 of 12 teeth") && e.contains("not placed consistently"), "{e}");
    }

    #[test]
    fn offsets_beyond_what_lighting_does_are_refused_with_what_their_signs_say() {
        assert!(offsets_plausible([-4.4, 4.4], 15.0).is_ok());
        let e = offsets_plausible([-5.9, -6.2], 15.0).unwrap_err().to_string();
        assert!(e.contains("-5.9 px (left) and -6.2 px (right)") && e.contains("alike on both sides"), "{e}");
        let e = offsets_plausible([-5.0, 4.0], 15.0).unwrap_err().to_string();
        assert!(e.contains("opposite") && e.contains("off by about 4.5 px"), "{e}");
    }
}
