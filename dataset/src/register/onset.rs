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
/// over 443 sweeps of twelve simulated sessions, the onsets scatter by 0.028 mm about their mean
/// (within one session less, about 0.02 mm; a session's own lateness adds the rest).
const MIN_ONSET_SD_MM: f64 = 0.028;
/// An onset less certain than this (mm, one sd) is not used: its change grows unlike a contact.
const MAX_ONSET_SD_MM: f64 = 0.04;
/// The growth projection's spatial filter (Gaussian sd, px): a gel spreads a contact's change
/// over several pixels, while a camera's noise and JPEG blocks vary from pixel to pixel.
const MATCHED_SIGMA_PX: f64 = 3.0;
/// Frames in each of the growth projection's three groups at a sweep's start: the template's
/// base, the change's base, and the frames that measure the projection's noise.
const GROUP_FRAMES: usize = 4;
/// The growth law is fitted up to where the change reaches this share of the sweep's deepest.
const GROWTH_FIT_TOP: f64 = 0.6;
/// The growth law may put the onset at most this many sweep steps before its first clear frame.
const GROWTH_BACK_STEPS: f64 = 8.0;
/// Where the growth law puts the onset at least this far (mm) before the first frame whose
/// local change stands out, the camera shows a touch's first tenths faintly (a soft gel's
/// smoothing, JPEG blocks): the onset is the growth law's.
const LATE_TOUCH_MM: f64 = 0.15;

/// What one sweep's frames show: the logged z of first touch and where the contact sits.
#[derive(Clone, Copy, Debug)]
pub(super) struct Onset {
    pub z_mm: f64,
    pub sd_mm: f64,
    pub centroid_px: [f64; 2],
    /// How far past the onset (mm of travel) the centroid was taken: the cast's is taken there too.
    pub probe_mm: f64,
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

/// The onset of one sweep, from its frames (in z order, inside the useful disk `mask`), their
/// change maps and their logged z: where the first frames whose local change stands out say the
/// touch began ([`first_visible`]), unless the change's growth law puts it clearly earlier
/// ([`growth_onset`]), or where that alone finds one.
pub(super) fn onset(
    frames: &[RgbImage],
    maps: &[Vec<f32>],
    z_mm: &[f32],
    n: usize,
    mask: &[bool],
) -> Result<Onset, String> {
    let visible = first_visible(frames, maps, z_mm, n);
    let grown = growth_onset(frames, z_mm, n, mask);
    match (visible, grown) {
        // Known to about half the way it reaches back past the visible onset.
        (Ok(v), Some(g)) if v.z_mm - g.z_mm >= LATE_TOUCH_MM => {
            Ok(Onset { sd_mm: g.sd_mm.hypot(0.5 * (v.z_mm - g.z_mm)), ..g })
        }
        (Ok(v), _) => Ok(v),
        // Where the first clear frames cannot be read, the growth law alone gives the onset, to
        // no better than the visible rule accepts.
        (Err(_), Some(g)) => Ok(Onset { sd_mm: g.sd_mm.max(MAX_ONSET_SD_MM), ..g }),
        (Err(why), None) => Err(why),
    }
}

/// The onset from the first frames whose local change stands out of the untouched frames' noise.
fn first_visible(frames: &[RgbImage], maps: &[Vec<f32>], z_mm: &[f32], n: usize) -> Result<Onset, String> {
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
    let (z0, var_z) = growth_law(&c, z_mm, first.saturating_sub(2)..t, 3.0 * c_sd)
        .ok_or("the change does not grow along the sweep")?;
    // A sweep that starts touched has no untouched frames: its first frames' change already
    // grows along the template, a good part as fast as after the onset.
    if let Some(share) = touched_start(&c, z_mm, 0..BASELINE_FRAMES, first..t) {
        return Err(format!(
            "the image already changes along the sweep's first {BASELINE_FRAMES} frames ({:.0} % of the rate past its \
             onset): the sweep starts touched",
            100.0 * share
        ));
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
    Ok(Onset { z_mm: z, sd_mm, centroid_px, probe_mm: PROBE_MM as f64 })
}

/// The onset where the change's growth law, extrapolated back, begins. A camera that shows a
/// touch's first tenths of a millimetre faintly shows its first clear frame late, but the growth
/// that follows still points at the touch. Each frame's change is projected on the sweep's
/// deepest change (its last frames against its first), through a spatial matched filter, and
/// measured against a second group of untouched frames, so that template and change share no
/// frame's noise; a third group measures the projection's noise. `None` where the sweep is too
/// short for the groups, starts touched, or shows no growth.
fn growth_onset(frames: &[RgbImage], z_mm: &[f32], n: usize, mask: &[bool]) -> Option<Onset> {
    let k = GROUP_FRAMES;
    let len = frames.len();
    if len < 3 * k + 8 {
        return None;
    }
    let blur = crate::render::optics::LensBlur::new(MATCHED_SIGMA_PX)?;
    let mean_of = |group: &[RgbImage]| -> Vec<[f32; 3]> {
        let mut m = vec![[0f32; 3]; n * n];
        for f in group {
            for (v, p) in m.iter_mut().zip(f.as_raw().chunks_exact(3)) {
                for c in 0..3 {
                    v[c] += p[c] as f32 / group.len() as f32;
                }
            }
        }
        m
    };
    let (template_base, change_base, deepest) =
        (mean_of(&frames[..k]), mean_of(&frames[k..2 * k]), mean_of(&frames[len - 3..]));
    let difference = |a: &[[f32; 3]], b: &[[f32; 3]]| -> Vec<[f32; 3]> {
        a.iter().zip(b).map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]]).collect()
    };
    let smooth = blur.whole(&difference(&deepest, &template_base), n);
    let energy: Vec<f32> =
        smooth.iter().zip(mask).map(|(v, &m)| if m { v.iter().map(|x| x * x).sum() } else { 0.0 }).collect();
    let peak = energy.iter().fold(0f32, |a, &b| a.max(b));
    if !(peak > 0.0) {
        return None;
    }
    // The template over its window, filtered once more: a frame's projection through the
    // filter is then one dot product with its raw change.
    let window: Vec<bool> = energy.iter().map(|&e| e > 0.1 * peak).collect();
    let windowed: Vec<[f32; 3]> = smooth.iter().zip(&window).map(|(v, &w)| if w { *v } else { [0.0; 3] }).collect();
    let norm: f64 = windowed.iter().flatten().map(|&x| (x as f64).powi(2)).sum();
    let weight = blur.whole(&windowed, n);
    let base_dot: f64 =
        change_base.iter().zip(&weight).map(|(b, w)| (0..3).map(|c| (b[c] * w[c]) as f64).sum::<f64>()).sum();
    let c: Vec<f64> = frames
        .iter()
        .map(|f| {
            let dot: f64 = f
                .as_raw()
                .chunks_exact(3)
                .zip(&weight)
                .map(|(p, w)| (0..3).map(|c| (p[c] as f32 * w[c]) as f64).sum::<f64>())
                .sum();
            (dot - base_dot) / norm
        })
        .collect();
    let quiet = &c[2 * k..3 * k];
    let Summary { mean: level, sd, .. } = Summary::of(quiet.iter().copied());
    let noise = sd.max(0.002);
    // Untouched frames keep the projection level at zero; a sweep that starts touched lifts it.
    if level.abs() > 6.0 * noise + 0.01 {
        return None;
    }
    let threshold = level + (5.0 * noise).max(0.01);
    let first = (3 * k..len - 2).find(|&j| c[j..j + 3].iter().all(|&v| v > threshold))?;
    let top = c[len - 1] - level;
    let hi = (first..len).find(|&j| c[j] - level > GROWTH_FIT_TOP * top).unwrap_or(len - 1);
    // A sweep that starts touched: its untouched groups already grow along the template, a good
    // part as fast as past the onset.
    if touched_start(&c, z_mm, k..3 * k, first..hi.max(first + 2).min(len - 1) + 1).is_some() {
        return None;
    }
    let above: Vec<f64> = c.iter().map(|v| v - level).collect();
    let (z0, var_z) = growth_law(&above, z_mm, first.saturating_sub(3).max(2 * k)..hi + 1, 2.0 * noise)?;
    let step = (z_mm[len - 1] - z_mm[0]) as f64 / (len - 1) as f64;
    let z = z0.clamp(z_mm[first] as f64 - GROWTH_BACK_STEPS * step, z_mm[first] as f64);
    // The contact is placed two frames past the first clear one, where the frame shows it: the
    // frame's own filtered change, where it agrees with the template.
    let j = (first + 2).min(len - 1);
    let change = blur.whole(&difference(&mean_of(std::slice::from_ref(&frames[j])), &change_base), n);
    let agree = |p: usize| if window[p] { (0..3).map(|c| (change[p][c] * smooth[p][c]) as f64).sum() } else { 0.0 };
    let centroid_px = blob_centroid(n, agree)?;
    // The law is extrapolated over the faint frames before the first clear one: an onset
    // that far back is known to about half that distance, whatever the fit's own scatter.
    let reach = z_mm[first] as f64 - z;
    let sd_mm = (var_z.max(0.0) + (0.5 * reach).powi(2)).sqrt().max(MIN_ONSET_SD_MM);
    Some(Onset { z_mm: z, sd_mm, centroid_px, probe_mm: z_mm[j] as f64 - z })
}

/// The growth law that explains a projection `c` (0 untouched) over the frames `span` best: for
/// each exponent, the frames above `floor` fitted as a line in `c^(1/q)`, the one of least
/// squared misfit over the span chosen. Its onset (mm of logged travel) and the onset's variance.
fn growth_law(c: &[f64], z_mm: &[f32], span: std::ops::Range<usize>, floor: f64) -> Option<(f64, f64)> {
    let mut best: Option<(f64, f64, f64)> = None;
    for q in GROWTH_EXPONENTS {
        let fit: Vec<(f64, f64)> =
            span.clone().filter(|&j| c[j] > floor).map(|j| (z_mm[j] as f64, c[j].powf(1.0 / q))).collect();
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
    best.map(|(_, z0, var_z)| (z0, var_z))
}

/// Whether a projection `c` already grows over the frames `early` (meant to be untouched) by
/// more than [`TOUCHED_START_SLOPE`] of its rate over `late` (past the onset): that share.
fn touched_start(c: &[f64], z_mm: &[f32], early: std::ops::Range<usize>, late: std::ops::Range<usize>) -> Option<f64> {
    let points = |r: std::ops::Range<usize>| -> Vec<(f64, f64)> { r.map(|j| (z_mm[j] as f64, c[j])).collect() };
    let (early, late) = (line_fit(&points(early))?, line_fit(&points(late))?);
    (early.1 > TOUCHED_START_SLOPE * late.1).then(|| early.1 / late.1)
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

    /// A sweep of `len` frames 0.05 mm apart from z = 0 whose contact (a broad blob, as a gel
    /// spreads it) grows as `(z - z0)^1.5` from 128 grey levels plus noise of +-3: faint for
    /// its first tenths of a millimetre.
    fn faint_sweep(z0: f64, len: usize) -> (Vec<RgbImage>, Vec<f32>) {
        let n = 64;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut noise = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % 7) as f32 - 3.0
        };
        let z: Vec<f32> = (0..len).map(|j| 0.05 * j as f32).collect();
        let frames = z
            .iter()
            .map(|&z| {
                let amplitude = 70.0 * ((z as f64 - z0).max(0.0)).powf(1.5) as f32;
                RgbImage::from_fn(n as u32, n as u32, |x, y| {
                    let r2 = (x as f32 - 30.0).powi(2) + (y as f32 - 36.0).powi(2);
                    let blob = amplitude * (-r2 / (2.0 * 36.0)).exp();
                    let v = |gain: f32, noise: f32| (128.0 + gain * blob + noise).round().clamp(0.0, 255.0) as u8;
                    image::Rgb([v(1.0, noise()), v(-0.5, noise()), v(0.3, noise())])
                })
            })
            .collect();
        (frames, z)
    }

    #[test]
    fn the_growth_law_finds_a_faint_touch_and_refuses_a_touched_start() {
        let mask = vec![true; 64 * 64];
        let (frames, z) = faint_sweep(1.0, 40);
        let grown = growth_onset(&frames, &z, 64, &mask).expect("a growing contact");
        assert!((grown.z_mm - 1.0).abs() <= 0.06, "onset {} against 1.0", grown.z_mm);
        assert!(grown.sd_mm >= MIN_ONSET_SD_MM && grown.sd_mm < 0.2, "sd {}", grown.sd_mm);
        let [x, y] = grown.centroid_px;
        assert!((x - 30.0).abs() < 2.0 && (y - 36.0).abs() < 2.0, "centroid {x}, {y}");
        // The contact is placed on a frame of the sweep, past the onset.
        assert!(grown.probe_mm > 0.0 && grown.z_mm + grown.probe_mm <= z[39] as f64 + 1e-6);
        // Touched from the start: its first frames already grow, so no onset.
        let (frames, z) = faint_sweep(-0.3, 40);
        assert!(growth_onset(&frames, &z, 64, &mask).is_none());
        // Too short for the three groups and a fit.
        let (frames, z) = faint_sweep(0.5, 18);
        assert!(growth_onset(&frames, &z, 64, &mask).is_none());
    }

    #[test]
    fn a_line_fit_recovers_an_exact_line_and_its_onset() {
        let points: Vec<(f64, f64)> = (0..4).map(|k| (0.1 * k as f64, 3.0 * (0.1 * k as f64 - 0.05))).collect();
        let (a, b, var_a, var_b, _) = line_fit(&points).unwrap();
        assert!((b - 3.0).abs() < 1e-12 && (-a / b - 0.05).abs() < 1e-12, "{a} {b}");
        assert!(var_a < 1e-20 && var_b < 1e-20);
    }
}
