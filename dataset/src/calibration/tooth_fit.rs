//! Where each tooth's drop shows along the strip, to a fraction of a pixel.
//!
//! A real gel never shows the indicator's sharp drop. Its membrane is smoothed about the drop
//! (0.5 to 3 px), or drapes one-sidedly from the tooth's tip over its foot (it cannot enter the
//! corner), and the lens blurs what is left; how the band it draws looks depends on the
//! lighting. Whatever its colours, each drop draws a pulse in the centre rows' profile. It is
//! fitted per channel as `a + e t + A pulse(t - drop)`, the pulse a Gaussian of `sigma`
//! convolved with an outward exponential tail of `tau` (a symmetric band when `tau = 0`, a
//! drape's sharp front and long tail otherwise), averaged over each pixel's width, with
//! `(sigma, tau)` shared by all teeth (the least total residual over a grid). Fitting the whole
//! window, not picking a peak, uses every sample of a smoothed pulse.
//!
//! This places the pulses precisely relative to each other, all teeth of a side alike; where a
//! pulse sits relative to its drop depends on the lighting of that side, and is found from the
//! pulses together (`super::teeth::register`). A window whose pulse explains too little of it
//! beyond a straight line has no drop (a hidden or broken tooth).

/// One tooth to locate: the strip's colour profile along it and where to search.
pub(super) struct ToothWindow {
    /// Outward distance from the optical centre of each sample (px) and the centre rows' RGB.
    pub(super) offsets_px: Vec<f64>,
    pub(super) rgb: Vec<[f64; 3]>,
    /// Coarse position of the drop (outward px) and the local pitch (px).
    pub(super) guess_px: f64,
    pub(super) pitch_px: f64,
}

/// The located pulse of each window, and the pulse's shape: Gaussian and outward tail (px).
pub(super) struct Located {
    pub(super) drops_px: Vec<Option<f64>>,
    pub(super) sigma_px: f64,
    pub(super) tail_px: f64,
}

/// Fine grid of the shapes (px).
const STEP: f64 = 0.05;
/// Search for the drop this far (fraction of the pitch) either side of the coarse guess.
const SEARCH: f64 = 0.3;
/// Least share of a window's colour variance beyond a straight line that its drop must explain.
const MIN_EXPLAINED: f64 = 0.3;

const SIGMAS_PX: [f64; 9] = [0.3, 0.6, 0.9, 1.3, 1.7, 2.2, 2.8, 3.4, 4.2];
const TAILS_PX: [f64; 9] = [0.0, 0.6, 1.2, 1.8, 2.6, 3.5, 4.5, 6.0, 8.0];

/// A shape sampled every `STEP` px over `[-span, span]`.
struct Shape {
    span: f64,
    v: Vec<f64>,
}

impl Shape {
    /// From samples over `[-span - pad, span + pad]` (computed wider so that smoothing sees its
    /// neighbours), averaged over each pixel's width and cut to `[-span, span]`.
    fn from_padded(v: Vec<f64>, span_steps: usize, pad_steps: usize) -> Self {
        let v = box_average(&v, (0.5 / STEP).round() as usize);
        Shape { span: span_steps as f64 * STEP, v: v[pad_steps..v.len() - pad_steps].to_vec() }
    }

    /// A pulse at 0: a Gaussian of `sigma` with an outward exponential tail of `tail`, peak 1.
    fn pulse(sigma: f64, tail: f64, span: f64) -> Self {
        let (span_steps, pad_steps) = ((span / STEP).ceil() as usize, ((4.0 * sigma + 2.0) / STEP) as usize);
        let n = (span_steps + pad_steps) as i64;
        let mut p: Vec<f64> = (-n..=n)
            .map(|i| {
                let t = i as f64 * STEP;
                match tail > 0.0 {
                    true if t >= 0.0 => (-t / tail).exp(),
                    true => 0.0,
                    false if i == 0 => 1.0,
                    false => 0.0,
                }
            })
            .collect();
        p = gaussian(&p, sigma / STEP);
        let shape = Shape::from_padded(p, span_steps, pad_steps);
        let peak = shape.v.iter().fold(0f64, |m, &x| m.max(x)).max(1e-12);
        Shape { v: shape.v.iter().map(|x| x / peak).collect(), ..shape }
    }

    /// The value at `t` (px from the drop), linearly interpolated; `None` outside.
    fn at(&self, t: f64) -> Option<f64> {
        let x = (t + self.span) / STEP;
        if !(x >= 0.0) || x >= (self.v.len() - 1) as f64 {
            return None;
        }
        let (i, f) = (x as usize, x.fract());
        Some(self.v[i] * (1.0 - f) + self.v[i + 1] * f)
    }
}

fn gaussian(v: &[f64], sigma_steps: f64) -> Vec<f64> {
    if !(sigma_steps > 0.1) {
        return v.to_vec();
    }
    let r = (3.5 * sigma_steps).ceil() as i64;
    let k: Vec<f64> = (-r..=r).map(|j| (-(j * j) as f64 / (2.0 * sigma_steps * sigma_steps)).exp()).collect();
    let norm: f64 = k.iter().sum();
    let n = v.len() as i64;
    (0..n)
        .map(|i| {
            k.iter().enumerate().map(|(j, w)| w * v[(i + j as i64 - r).clamp(0, n - 1) as usize]).sum::<f64>() / norm
        })
        .collect()
}

fn box_average(v: &[f64], half: usize) -> Vec<f64> {
    let n = v.len();
    let mut prefix = vec![0f64; n + 1];
    for i in 0..n {
        prefix[i + 1] = prefix[i] + v[i];
    }
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(half), (i + half + 1).min(n));
            (prefix[b] - prefix[a]) / (b - a) as f64
        })
        .collect()
}

/// The window's samples used for a fit: within 0.55 pitch of the guess.
fn rows_of(w: &ToothWindow) -> impl Iterator<Item = usize> + '_ {
    let half = 0.55 * w.pitch_px;
    (0..w.offsets_px.len()).filter(move |&i| (w.offsets_px[i] - w.guess_px).abs() <= half)
}

/// Residual (three channels) of the window with a pulse of `shape` at `drop_px`; `None` where
/// the window leaves the shape.
fn residual(w: &ToothWindow, shape: &Shape, drop_px: f64) -> Option<f64> {
    let mut rows = Vec::with_capacity(w.offsets_px.len());
    for i in rows_of(w) {
        let t = w.offsets_px[i] - drop_px;
        rows.push([1.0, t / w.pitch_px, shape.at(t)?]);
    }
    (rows.len() >= 8).then_some(())?;
    channels_residual(w, &rows)
}

/// The same for a window without any drop: a straight line.
fn null_residual(w: &ToothWindow) -> Option<f64> {
    let rows: Vec<[f64; 2]> = rows_of(w).map(|i| [1.0, (w.offsets_px[i] - w.guess_px) / w.pitch_px]).collect();
    channels_residual(w, &rows)
}

/// The least-squares residuals of the three channels on `rows`, summed.
fn channels_residual<const K: usize>(w: &ToothWindow, rows: &[[f64; K]]) -> Option<f64> {
    (0..3)
        .map(|c| {
            let rhs: Vec<f64> = rows_of(w).map(|i| w.rgb[i][c]).collect();
            super::least_squares(rows, &rhs).map(|r| r.0)
        })
        .sum()
}

/// The residual curve over trial drops about the guess, every `2 STEP` px.
fn scan(w: &ToothWindow, shape: &Shape) -> Vec<(f64, f64)> {
    let n = (SEARCH * w.pitch_px / (2.0 * STEP)).ceil() as i64;
    (-n..=n)
        .filter_map(|k| {
            let d = w.guess_px + k as f64 * 2.0 * STEP;
            residual(w, shape, d).map(|r| (d, r))
        })
        .collect()
}

/// The best drop of a scan, refined by a parabola; `None` at the scan's ends (no minimum inside).
fn minimum(curve: &[(f64, f64)]) -> Option<(f64, f64)> {
    let (k, _) = curve.iter().enumerate().min_by(|a, b| a.1.1.total_cmp(&b.1.1))?;
    if k == 0 || k + 1 == curve.len() {
        return None;
    }
    let (l, c, r) = (curve[k - 1].1, curve[k].1, curve[k + 1].1);
    let h = curve[k + 1].0 - curve[k].0;
    let denom = l - 2.0 * c + r;
    let off = if denom > 0.0 { (0.5 * (l - r) / denom).clamp(-1.0, 1.0) } else { 0.0 };
    Some((curve[k].0 + off * h, c))
}

/// Locates every window's pulse (see the module's notes).
pub(super) fn locate(windows: &[ToothWindow]) -> Located {
    use rayon::prelude::*;
    let pairs: Vec<(f64, f64)> = SIGMAS_PX.iter().flat_map(|&s| TAILS_PX.iter().map(move |&d| (s, d))).collect();
    let span = |w: &ToothWindow| (0.55 + SEARCH) * w.pitch_px + 1.0;
    let totals: Vec<f64> = pairs
        .par_iter()
        .map(|&(sigma, tail)| {
            windows
                .iter()
                .map(|w| {
                    // A window without a minimum counts its smallest residual: it cannot win by
                    // dropping out.
                    scan(w, &Shape::pulse(sigma, tail, span(w))).iter().map(|c| c.1).fold(f64::INFINITY, f64::min)
                })
                .filter(|r| r.is_finite())
                .sum()
        })
        .collect();
    let best = (0..pairs.len()).min_by(|&a, &b| totals[a].total_cmp(&totals[b])).unwrap_or(0);
    let (sigma_px, tail_px) = pairs[best];
    let drops_px = windows
        .par_iter()
        .map(|w| {
            let (drop, r) = minimum(&scan(w, &Shape::pulse(sigma_px, tail_px, span(w))))?;
            let null = null_residual(w)?;
            (null > 0.0 && r <= (1.0 - MIN_EXPLAINED) * null).then_some(drop)
        })
        .collect();
    Located { drops_px, sigma_px, tail_px }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Windows drawn by a model of their own: the indicator's ramp-and-drop profile, smoothed
    /// symmetrically or draped one-sidedly, its slope shaded through a nonlinear response per
    /// channel, with a trend and a little noise.
    fn synthetic(sigma: f64, drape: f64, shift: f64) -> Vec<ToothWindow> {
        let mut noise = formats::SplitMix64::new(9);
        (3..9)
            .map(|k| {
                let pitch = 15.0 + 0.2 * k as f64;
                let drop = 15.0 * k as f64 + shift;
                let fine = |x: f64| {
                    // Rigid profile, draped over the foot, then smoothed (numerically).
                    let rigid = |t: f64| 0.5 + (t / pitch).rem_euclid(1.0);
                    let draped = |t: f64| {
                        let mut m = rigid(t);
                        if drape > 0.0 {
                            for j in 1..200 {
                                let back = j as f64 * 0.05;
                                m = m.max(rigid(t - back) * (-back / drape).exp());
                            }
                        }
                        m
                    };
                    let g = |j: i32| (-(j * j) as f64 * 0.0025 / (2.0 * sigma * sigma)).exp();
                    let (num, den) = (-120..=120)
                        .fold((0.0, 0.0), |(n, d), j| (n + g(j) * draped(x - drop + j as f64 * 0.05), d + g(j)));
                    num / den
                };
                let offsets: Vec<f64> =
                    (0..(2.0 * pitch) as usize).map(|i| (drop - pitch).floor() + i as f64).collect();
                let rgb = offsets
                    .iter()
                    .map(|&x| {
                        let slope = (fine(x + 0.25) - fine(x - 0.25)) * 2.0 * pitch;
                        let shade = |a: f64, b: f64| 100.0 + 40.0 * (a * slope).tanh() + b * fine(x) + 0.3 * x;
                        [shade(0.3, 5.0), shade(-0.2, 12.0), shade(0.1, -3.0)].map(|v| v + 0.3 * noise.normal())
                    })
                    .collect();
                ToothWindow { offsets_px: offsets, rgb, guess_px: drop + 2.0, pitch_px: pitch }
            })
            .collect()
    }

    #[test]
    fn pulses_keep_their_spacing_under_a_symmetric_smoothing_and_a_one_sided_drape() {
        for (sigma, drape) in [(0.5, 0.0), (2.5, 0.0), (0.6, 4.0), (0.9, 1.5)] {
            let windows = synthetic(sigma, drape, 0.37);
            let found = locate(&windows);
            // Where a pulse sits relative to its drop is a side's registration; here every
            // window has the same shading, so the pulses keep the drops' spacing exactly.
            let off: Vec<f64> =
                windows.iter().zip(&found.drops_px).map(|(w, d)| d.expect("a drop") - (w.guess_px - 2.0)).collect();
            let mean = off.iter().sum::<f64>() / off.len() as f64;
            for o in &off {
                assert!((o - mean).abs() < 0.1, "sigma {sigma} drape {drape}: offsets {off:?}");
            }
            assert!(mean.abs() < 1.5, "sigma {sigma} drape {drape}: pulses {mean:.2} px from their drops");
        }
    }

    #[test]
    fn a_window_without_a_drop_has_none() {
        let mut windows = synthetic(0.8, 0.0, 0.0);
        // A flat ramp (a hidden tooth): a line plus noise.
        let mut noise = formats::SplitMix64::new(3);
        for p in windows[2].rgb.iter_mut() {
            *p = [80.0, 90.0, 100.0].map(|v| v + noise.normal());
        }
        let found = locate(&windows);
        assert!(found.drops_px[2].is_none() && found.drops_px.iter().filter(|d| d.is_some()).count() == 5);
    }
}
