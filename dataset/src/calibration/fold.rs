//! Where the teeth are, roughly: the radial map under which the strip's profiles repeat tooth
//! after tooth.
//!
//! Looking for each drop on its own breaks down on a real gel: a drop smoothed over 3 px is
//! barely more than a ripple, near the apex its colour change is a grey level or two, and the
//! middle of a ripple is as strong as its drop. The teeth are many, though, and all alike. Under
//! the right map `theta(r)`, the strip's profiles cut into tooth-long pieces (`theta / pitch`
//! from one integer to the next) look the same from piece to piece; under a wrong one they
//! blur. So the map is the one that makes the profiles, folded onto one pitch, repeat best
//! (epoch folding): `theta(x) = 90 deg (x + a x (1 - x^2) + b x^3 (1 - x^2))`, `x = r / r_rim`,
//! which passes through the centre and the rim, searched over `a` and `b`. Its teeth (integer
//! multiples of the pitch) are where [`super::tooth_fit`] then looks for each drop.

use super::{CalibrationError, Plane, fail};

/// The strip's colour profile along the row through the centre: for each column between the
/// rim's ends, the mean of the rows `vc - 1 ..= vc + 1` (bilinear), as signed offsets from the
/// centre and RGB.
pub(super) struct StripProfile {
    pub(super) offsets_px: Vec<f64>,
    pub(super) rgb: Vec<[f64; 3]>,
}

impl StripProfile {
    pub(super) fn read(channels: &[Plane], uc: f64, vc: f64, r_rim: f64) -> Result<Self, CalibrationError> {
        let (w, h) = (channels[0].w, channels[0].h);
        if vc < 4.0 || vc + 4.0 >= h as f64 {
            return fail("the optical centre's row is too close to the image's border");
        }
        let lo = (uc - r_rim).ceil().max(2.0) as i64;
        let hi = (uc + r_rim).floor().min(w as f64 - 3.0) as i64;
        let (offsets_px, rgb) = (lo..=hi)
            .map(|u| {
                let x = u as f64;
                let rgb = std::array::from_fn(|c| {
                    (-1..=1).map(|k| channels[c].at(x, vc + k as f64) as f64).sum::<f64>() / 3.0
                });
                (x - uc, rgb)
            })
            .unzip();
        Ok(StripProfile { offsets_px, rgb })
    }
}

/// Phase bins of one pitch.
const BINS: usize = 12;
/// Teeth folded together: the pattern may change along the strip (its lighting does), so each
/// group of this many teeth has its own folded profile.
const TEETH_PER_GROUP: f64 = 4.0;

/// The map found: `theta(x) = 90 deg (x + a x (1 - x^2) + b x^3 (1 - x^2))`.
pub(super) struct FoldedMap {
    a: f64,
    b: f64,
}

impl FoldedMap {
    /// Polar angle (degrees) at radius `r` for a rim at `r_rim`.
    pub(super) fn theta_deg(&self, r: f64, r_rim: f64) -> f64 {
        theta_deg(self.a, self.b, r / r_rim)
    }

    /// Radius of polar angle `theta_deg` (bisection; the map rises monotonically).
    pub(super) fn radius_px(&self, theta_deg: f64, r_rim: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 1.2 * r_rim);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.theta_deg(mid, r_rim) < theta_deg {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }
}

fn theta_deg(a: f64, b: f64, x: f64) -> f64 {
    let w = x * (1.0 - x * x);
    90.0 * (x + a * w + b * x * x * w)
}

/// Whether the map rises over the strip (and a little beyond the rim).
fn monotone(a: f64, b: f64) -> bool {
    (0..=60).all(|i| {
        let x = i as f64 / 50.0;
        theta_deg(a, b, x + 0.01) > theta_deg(a, b, x)
    })
}

/// One signal along one side of the strip, high-passed and normalised: radius and value.
struct Signal {
    r: Vec<f64>,
    v: Vec<f64>,
}

/// The signals to fold: each colour channel of the strip's centre rows, on each side; each with
/// its slow trend over a pitch removed and scaled to unit local rms.
fn signals(profile: &StripProfile, pitch_px: f64) -> Vec<Signal> {
    let mut out = Vec::new();
    for side in [-1.0, 1.0] {
        let idx: Vec<usize> = (0..profile.offsets_px.len()).filter(|&i| profile.offsets_px[i] * side > 0.0).collect();
        let r: Vec<f64> = idx.iter().map(|&i| profile.offsets_px[i].abs()).collect();
        for c in 0..3 {
            let raw: Vec<f64> = idx.iter().map(|&i| profile.rgb[i][c]).collect();
            let n = raw.len();
            let half = (pitch_px / 2.0).round() as usize;
            let high: Vec<f64> = (0..n)
                .map(|i| {
                    let (a, b) = (i.saturating_sub(half), (i + half + 1).min(n));
                    raw[i] - raw[a..b].iter().sum::<f64>() / (b - a) as f64
                })
                .collect();
            let wide = 3 * half;
            let v = (0..n)
                .map(|i| {
                    let (a, b) = (i.saturating_sub(wide), (i + wide + 1).min(n));
                    let rms = (high[a..b].iter().map(|x| x * x).sum::<f64>() / (b - a) as f64).sqrt();
                    high[i] / rms.max(1e-9)
                })
                .collect();
            out.push(Signal { r: r.clone(), v });
        }
    }
    out
}

/// Fraction of the signals' variance that the fold under map `(a, b)` explains.
fn fold_score(signals: &[Signal], a: f64, b: f64, r_rim: f64, pitch_deg: f64, teeth: u32) -> f64 {
    let groups = (teeth as f64 / TEETH_PER_GROUP).ceil() as usize + 1;
    let (mut explained, mut total) = (0.0, 0.0);
    let mut sum = vec![0f64; groups * BINS];
    let mut count = vec![0u32; groups * BINS];
    for s in signals {
        sum.iter_mut().for_each(|v| *v = 0.0);
        count.iter_mut().for_each(|v| *v = 0);
        for (&r, &v) in s.r.iter().zip(&s.v) {
            let phase = theta_deg(a, b, r / r_rim) / pitch_deg;
            if !(phase > 0.5 && phase < teeth as f64 + 0.4) {
                continue;
            }
            let group = ((phase - 0.5) / TEETH_PER_GROUP) as usize;
            let bin = ((phase.fract() * BINS as f64) as usize).min(BINS - 1);
            sum[group * BINS + bin] += v;
            count[group * BINS + bin] += 1;
            total += v * v;
        }
        explained += sum.iter().zip(&count).filter(|(_, n)| **n > 1).map(|(s, &n)| s * s / n as f64).sum::<f64>();
    }
    if total > 0.0 { explained / total } else { 0.0 }
}

/// The best map for one pitch: `(a, b, explained)`.
fn best_fold(profile: &StripProfile, r_rim: f64, pitch_deg: f64, teeth: u32) -> Option<(f64, f64, f64)> {
    use rayon::prelude::*;
    let sig = signals(profile, r_rim / 90.0 * pitch_deg);
    let grid: Vec<(f64, f64)> = (-30..=30)
        .flat_map(|i| (-30..=30).map(move |j| (i as f64 * 0.005, j as f64 * 0.005)))
        .filter(|&(a, b)| monotone(a, b))
        .collect();
    let scores: Vec<f64> = grid.par_iter().map(|&(a, b)| fold_score(&sig, a, b, r_rim, pitch_deg, teeth)).collect();
    let best = (0..grid.len()).max_by(|&i, &j| scores[i].total_cmp(&scores[j]))?;
    let (mut a, mut b, mut explained) = (grid[best].0, grid[best].1, scores[best]);
    // Finer, about the best.
    for i in -5..=5 {
        for j in -5..=5 {
            let (ta, tb) = (grid[best].0 + i as f64 * 0.001, grid[best].1 + j as f64 * 0.001);
            if monotone(ta, tb) {
                let s = fold_score(&sig, ta, tb, r_rim, pitch_deg, teeth);
                if s > explained {
                    (a, b, explained) = (ta, tb, s);
                }
            }
        }
    }
    Some((a, b, explained))
}

/// The map whose fold explains the strip's profiles best; refuses where the profiles repeat
/// at the indicator's pitch no better than at pitches 0.7 and 1.4 times it (what folding finds
/// in any profile): no indicator on that row, or one of another pitch.
pub(super) fn fold_map(
    profile: &StripProfile,
    r_rim: f64,
    pitch_deg: f64,
    teeth: u32,
) -> Result<FoldedMap, CalibrationError> {
    let (a, b, explained) =
        best_fold(profile, r_rim, pitch_deg, teeth).ok_or_else(|| CalibrationError("no radial map to fold".into()))?;
    let reach_deg = teeth as f64 * pitch_deg;
    let chance = [0.7, 1.4]
        .iter()
        .filter_map(|k| {
            let p = pitch_deg * k;
            best_fold(profile, r_rim, p, (reach_deg / p).floor().max(1.0) as u32).map(|f| f.2)
        })
        .fold(0.0, f64::max);
    if !(explained > 1.3 * chance) {
        return fail(format!(
            "the strip along the row through the optical centre does not repeat every {pitch_deg:.1} degrees (folded at \
             that pitch it explains {:.0} % of its variance, at 0.7 or 1.4 times it {:.0} %): no saw-tooth indicator \
             pressed along the image's x axis through the centre, or one of another pitch",
            100.0 * explained,
            100.0 * chance
        ));
    }
    Ok(FoldedMap { a, b })
}
