//! The optical centre from the elastomer's rim (90 degrees): a rough disk from Otsu's
//! threshold, Canny edge points near its boundary, sub-pixel points on radial profiles, and a
//! trimmed circle fit.

use imageproc::edges::canny;

use super::{CalibrationError, Plane, fail};

/// The elastomer's rim: centre and radius `(u, v, r)` in frame pixels, and the circle fit's rms.
pub(super) struct Rim {
    pub(super) circle: (f64, f64, f64),
    pub(super) rms_px: f64,
}

/// The elastomer's rim: rough disk from a threshold, Canny edge points near its boundary,
/// then sub-pixel points on radial profiles and a trimmed circle fit.
pub(super) fn find_rim(gray: &Plane) -> Result<Rim, CalibrationError> {
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
