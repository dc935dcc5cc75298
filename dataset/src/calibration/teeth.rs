//! Tooth edges along the row through the optical centre, and their matching to the indicator's
//! teeth (multiples of the pitch) by a radial model refitted as edges are accepted.

use imageproc::edges::canny;

use super::sawtooth::SawTooth;
use super::{CalibrationError, MatchedEdge, Plane, fail};

/// A tooth-edge candidate on the centre row: signed distance from the centre (px) and strength.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    offset_px: f64,
    strength: f64,
}

/// Thin lines across the centre row, gated by Canny edges near them.
pub(super) fn find_tooth_edges(
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
pub(super) fn match_edges(
    cands: &[Candidate],
    r_rim: f64,
    pitch: f64,
    teeth: u32,
) -> Result<Vec<MatchedEdge>, CalibrationError> {
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
