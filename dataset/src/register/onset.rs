//! What a sweep's frames show: where the image first departs from the untouched frames (the
//! logged z of first touch) and where on the image the change sits.

use formats::stats::Summary;
use image::RgbImage;

use super::PROBE_MM;

/// Frames at a sweep's start taken as untouched, to learn the change's noise.
const BASELINE_FRAMES: usize = 4;
/// Growth laws tried: the change's projection on the template as a power of the depth pressed.
const GROWTH_EXPONENTS: [f64; 5] = [1.0, 1.25, 1.5, 1.75, 2.0];
/// The first frames' peak change spreads by about a tenth of its mean when they are untouched;
/// beyond this share they are not.
const BASELINE_SPREAD: f64 = 0.3;
/// A sweep whose first frames' change grows at more than this share of its rate past the onset
/// started touched.
const TOUCHED_START_SLOPE: f64 = 0.15;
/// The template frame is this far (mm of travel) past the first frame that shows the touch.
const TEMPLATE_MM: f64 = 0.25;
/// The template's window: where its local change exceeds this share of its peak.
const WINDOW_FRACTION: f32 = 0.05;
/// Half the side of the box that averages the change (px): noise falls by its area.
const BOX_RADIUS_PX: usize = 4;
/// An onset's standard deviation is never taken below this (mm): measured against the truth
/// on simulated sweeps, onsets scatter by about this much.
const MIN_ONSET_SD_MM: f64 = 0.02;
/// An onset less certain than this (mm, one sd) is not used: its change grows unlike a contact.
const MAX_ONSET_SD_MM: f64 = 0.04;

/// What one sweep's frames show: the logged z of first touch and where the contact sits.
#[derive(Clone, Copy, Debug)]
pub(super) struct Onset {
    pub z_mm: f64,
    pub sd_mm: f64,
    pub centroid_px: [f64; 2],
}

/// The local change of `frame` against `reference`: per channel the difference less its mean
/// over the useful disk (a camera's exposure step), averaged over a box, squared and summed.
pub(super) fn change_map(frame: &RgbImage, reference: &RgbImage, mask: &[bool]) -> Vec<f32> {
    let n = frame.width() as usize;
    let (f, r) = (frame.as_raw(), reference.as_raw());
    let mut mean = [0f64; 3];
    let mut count = 0usize;
    for (p, _) in mask.iter().enumerate().filter(|m| *m.1) {
        for c in 0..3 {
            mean[c] += f[3 * p + c] as f64 - r[3 * p + c] as f64;
        }
        count += 1;
    }
    let mean = mean.map(|m| (m / count.max(1) as f64) as f32);
    let mut energy = vec![0f32; n * n];
    let w = n + 1;
    let mut integral = vec![0f32; w * w];
    for (c, &mean_c) in mean.iter().enumerate() {
        for y in 0..n {
            let mut row = 0f32;
            for x in 0..n {
                let p = y * n + x;
                row += f[3 * p + c] as f32 - r[3 * p + c] as f32 - mean_c;
                integral[(y + 1) * w + x + 1] = integral[y * w + x + 1] + row;
            }
        }
        let b = BOX_RADIUS_PX;
        let area = ((2 * b + 1) * (2 * b + 1)) as f32;
        for y in b..n.saturating_sub(b) {
            for x in b..n - b {
                let (y0, y1, x0, x1) = (y - b, y + b + 1, x - b, x + b + 1);
                let s = integral[y1 * w + x1] - integral[y0 * w + x1] - integral[y1 * w + x0] + integral[y0 * w + x0];
                let m = s / area;
                energy[y * n + x] += m * m;
            }
        }
    }
    for (e, &m) in energy.iter_mut().zip(mask) {
        if !m {
            *e = 0.0;
        }
    }
    energy
}

/// The onset of one sweep, from its frames' change maps (in z order) and their logged z.
pub(super) fn onset(frames: &[RgbImage], maps: &[Vec<f32>], z_mm: &[f32], n: usize) -> Result<Onset, String> {
    // The sweep's own untouched frames are its reference: free of the reference frame's noise
    // and of a drift between sessions.
    let mut base = vec![0f32; frames[0].as_raw().len()];
    for f in &frames[..BASELINE_FRAMES] {
        for (b, &v) in base.iter_mut().zip(f.as_raw()) {
            *b += v as f32 / BASELINE_FRAMES as f32;
        }
    }
    let peaks: Vec<f64> = maps.iter().map(|m| m.iter().fold(0f32, |a, &b| a.max(b)) as f64).collect();
    let Summary { mean: mu, sd, .. } = Summary::of(peaks[..BASELINE_FRAMES].iter().copied());
    if sd > BASELINE_SPREAD * mu {
        return Err(format!(
            "the change's peak over the first {BASELINE_FRAMES} frames spreads by {:.0} % of its mean (noise alone: \
             about 10 %): the sweep starts touched, or the camera flickers",
            100.0 * sd / mu
        ));
    }
    let threshold = mu + (6.0 * sd).max(0.5 * mu);
    // The first frame from which the change stays above the noise for three frames.
    let first = (BASELINE_FRAMES..peaks.len().saturating_sub(2))
        .find(|&j| peaks[j..j + 3].iter().all(|&p| p > threshold))
        .ok_or("the image never departs from the reference beyond its noise (no touch in the sweep?)")?;
    if first <= BASELINE_FRAMES + 1 {
        return Err(format!(
            "the image changes within its first {} frames: the sweep starts too near its touch (or past it) to learn \
             the untouched frames' noise",
            first + 1
        ));
    }
    // Then on a frame a little past the onset (the template), whose change is most like the
    // first frames': the onset is fitted on that projection.
    let step = (z_mm[z_mm.len() - 1] - z_mm[0]) as f64 / (z_mm.len() - 1) as f64;
    let t = (first + (TEMPLATE_MM / step).round().max(3.0) as usize).min(frames.len() - 1);
    if t < first + 3 {
        return Err("the sweep ends too soon after its onset to fit it".into());
    }
    let c = project(frames, &base, maps, t, n);
    let c_sd = Summary::of(c[..BASELINE_FRAMES].iter().copied()).sd;
    // The growth law is the gel's and the camera's: the exponent that explains the frames
    // from just before the onset to the template best is chosen, and the onset is where that
    // curve starts.
    let span = first.saturating_sub(2)..t;
    let mut best: Option<(f64, f64, f64)> = None;
    for q in GROWTH_EXPONENTS {
        let fit: Vec<(f64, f64)> =
            span.clone().filter(|&j| c[j] > 3.0 * c_sd).map(|j| (z_mm[j] as f64, c[j].powf(1.0 / q))).collect();
        let Some((alpha, beta, var_a, var_b, cov)) = line_fit(&fit) else { continue };
        if beta <= 0.0 {
            continue;
        }
        let z0 = -alpha / beta;
        let sse: f64 = span.clone().map(|j| (c[j] - (beta * (z_mm[j] as f64 - z0)).max(0.0).powf(q)).powi(2)).sum();
        let var_z = (var_a + z0 * z0 * var_b + 2.0 * z0 * cov) / (beta * beta);
        if best.is_none_or(|b| sse < b.0) {
            best = Some((sse, z0, var_z));
        }
    }
    let (_, z0, var_z) = best.ok_or("the change does not grow along the sweep")?;
    // A sweep that starts touched has no untouched frames: its first frames' change already
    // grows along the template, a good part as fast as after the onset.
    {
        let projection = &c;
        let start: Vec<(f64, f64)> = (0..BASELINE_FRAMES).map(|j| (z_mm[j] as f64, projection[j])).collect();
        let after: Vec<(f64, f64)> = (first..t).map(|j| (z_mm[j] as f64, projection[j])).collect();
        if let (Some(early), Some(late)) = (line_fit(&start), line_fit(&after))
            && early.1 > TOUCHED_START_SLOPE * late.1
        {
            return Err(format!(
                "the image already changes along the sweep's first {BASELINE_FRAMES} frames ({:.0} % of the rate past \
                 its onset): the sweep starts touched",
                100.0 * early.1 / late.1
            ));
        }
    }
    // Not before the last frame that looked untouched less one step.
    let floor = z_mm[first.saturating_sub(2)] as f64;
    let z = z0.max(floor).min(z_mm[first] as f64);
    // The centroid of the change a little past the onset.
    let j = (first..maps.len()).find(|&j| z_mm[j] as f64 >= z + PROBE_MM as f64).unwrap_or(maps.len() - 1);
    let centroid_px =
        blob_centroid(n, |p| maps[j][p] as f64 - threshold).ok_or("no change left to place the contact")?;
    let sd_mm = var_z.max(0.0).sqrt().max(MIN_ONSET_SD_MM);
    if sd_mm > MAX_ONSET_SD_MM {
        return Err(format!("the change's growth fits no curve well (onset +-{sd_mm:.3} mm)"));
    }
    Ok(Onset { z_mm: z, sd_mm, centroid_px })
}

/// The weighted centroid (px) of the blob around the largest of `weight` on an `n` x `n` grid:
/// the 4-connected pixels of positive weight that reach it. A second contact elsewhere (another
/// indenter of the trial touching later) is not part of the first one's place.
pub(super) fn blob_centroid(n: usize, weight: impl Fn(usize) -> f64) -> Option<[f64; 2]> {
    let start = (0..n * n).max_by(|&a, &b| weight(a).total_cmp(&weight(b)))?;
    if weight(start) <= 0.0 {
        return None;
    }
    let mut seen = vec![false; n * n];
    let mut stack = vec![start];
    seen[start] = true;
    let (mut sx, mut sy, mut sw) = (0f64, 0f64, 0f64);
    while let Some(p) = stack.pop() {
        let w = weight(p);
        let (x, y) = (p % n, p / n);
        sx += w * x as f64;
        sy += w * y as f64;
        sw += w;
        let neighbours =
            [(x > 0).then(|| p - 1), (x + 1 < n).then(|| p + 1), (y > 0).then(|| p - n), (y + 1 < n).then(|| p + n)];
        for q in neighbours.into_iter().flatten() {
            if !seen[q] && weight(q) > 0.0 {
                seen[q] = true;
                stack.push(q);
            }
        }
    }
    Some([sx / sw, sy / sw])
}

/// Each frame's change against `base` projected on frame `t`'s, over the pixels where frame
/// `t`'s local change ([`change_map`]) is a fair share of its peak: 0 for the base, 1 for `t`.
fn project(frames: &[RgbImage], base: &[f32], maps: &[Vec<f32>], t: usize, n: usize) -> Vec<f64> {
    let peak = maps[t].iter().fold(0f32, |a, &b| a.max(b));
    let window: Vec<usize> = (0..n * n).filter(|&p| maps[t][p] > WINDOW_FRACTION * peak).collect();
    let values = |f: &RgbImage| -> Vec<f32> {
        let raw = f.as_raw();
        window.iter().flat_map(|&p| (0..3).map(move |c| 3 * p + c)).map(|i| raw[i] as f32 - base[i]).collect()
    };
    let template = values(&frames[t]);
    let norm: f64 = template.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().max(f64::MIN_POSITIVE);
    frames.iter().map(|f| values(f).iter().zip(&template).map(|(&a, &b)| (a * b) as f64).sum::<f64>() / norm).collect()
}

/// Least-squares line `y = a + b x`: a, b, var a, var b, cov(a, b) (from the residuals).
fn line_fit(points: &[(f64, f64)]) -> Option<(f64, f64, f64, f64, f64)> {
    let k = points.len() as f64;
    if points.len() < 3 {
        return None;
    }
    let mx = points.iter().map(|p| p.0).sum::<f64>() / k;
    let my = points.iter().map(|p| p.1).sum::<f64>() / k;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let b = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / sxx;
    let a = my - b * mx;
    let s2 = points.iter().map(|p| (p.1 - a - b * p.0).powi(2)).sum::<f64>() / (k - 2.0);
    let var_b = s2 / sxx;
    let var_a = s2 * (1.0 / k + mx * mx / sxx);
    Some((a, b, var_a, var_b, -mx * var_b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_fit_recovers_an_exact_line_and_its_onset() {
        let points: Vec<(f64, f64)> = (0..4).map(|k| (0.1 * k as f64, 3.0 * (0.1 * k as f64 - 0.05))).collect();
        let (a, b, var_a, var_b, _) = line_fit(&points).unwrap();
        assert!((b - 3.0).abs() < 1e-12 && (-a / b - 0.05).abs() < 1e-12, "{a} {b}");
        assert!(var_a < 1e-20 && var_b < 1e-20);
    }
}
