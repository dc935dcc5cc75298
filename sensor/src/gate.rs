//! The contact gate: whether a frame differs from the unit's reference frame by more than the
//! unit's noise, so that an untouched frame is answered with zeros without running the network.
//!
//! A fixed threshold is tuned to one renderer's noise and one way of shading a contact; a real
//! unit's noise, compression and lighting differ, and a gate that closes on a pressed frame
//! answers it with zeros. So the gate is fitted to each unit's own labelled frames
//! ([`fit`]): the untouched ones (and the parts of pressed ones far from their contact) say how
//! many pixels noise alone pushes over each level; the pressed ones, how many their contact
//! pushes over it at least. The level that separates the two best is chosen, and the pixel
//! count is set so that no labelled contact frame is missed ([`Tally`] counts what it does).

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::{CONTACT_THRESHOLD_MM, DepthMap};

/// When a frame counts as differing from the unit's reference frame: at least `min_pixels`
/// useful pixels whose channels differ by more than `grey_levels` on average.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContactGate {
    pub grey_levels: f32,
    pub min_pixels: usize,
}

/// Levels (mean absolute difference over the three channels, grey levels) the fit chooses from.
pub const GATE_LEVELS: [f32; 14] = [3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 22.0, 27.0, 33.0, 40.0, 50.0];

/// Pixels this far (crop pixels) from any labelled contact are the frame's noise.
const NOISE_DISTANCE_PX: usize = 12;

impl ContactGate {
    /// Useful pixels of `frame` that differ from `reference` by more than the gate's grey
    /// levels once the frame's drift is taken out ([`Balance`]), counted up to `min_pixels`
    /// (the count stops there: enough to decide).
    pub fn changed_pixels(&self, frame: &RgbImage, reference: &RgbImage, mask: &[bool]) -> usize {
        let limit = self.grey_levels * 3.0;
        let comparison = Balance::fit(frame, reference, mask).comparison();
        let mut changed = 0;
        for ((p, q), &useful) in frame.pixels().zip(reference.pixels()).zip(mask) {
            if useful && comparison.difference(p.0, q.0) > limit {
                changed += 1;
                if changed >= self.min_pixels {
                    break;
                }
            }
        }
        changed
    }

    /// Whether `frame` differs from `reference` by more than noise.
    pub fn differs(&self, frame: &RgbImage, reference: &RgbImage, mask: &[bool]) -> bool {
        self.changed_pixels(frame, reference, mask) >= self.min_pixels
    }
}

/// What drift does to a whole frame against the reference: a gain per colour channel (an LED
/// warming up, a camera's exposure or white balance moving). Fitted to each frame robustly
/// (the median ratio over the useful pixels), so that a contact, which changes a part of the
/// frame, does not move it, and taken out before frame and reference are compared: drift
/// cannot open the gate, a contact still does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Balance {
    /// Frame over reference, per channel (R, G, B).
    pub gain: [f32; 3],
}

/// Ratios the balance resolves, and the range it fits in (a frame beyond it is not drift).
/// Public, with the rest of the fit's rule, for the ONNX export that replays it in a graph.
pub const BALANCE_BINS: usize = 1200;
pub const BALANCE_MIN: f32 = 0.5;
pub const BALANCE_MAX: f32 = 2.0;
/// Reference values darker than this give ratios that noise dominates; they are not used.
pub const BALANCE_MIN_LEVEL: u8 = 24;
/// A channel with fewer samples than this (its clipped levels left out) keeps gain 1.
pub const BALANCE_MIN_SAMPLES: u32 = 64;
/// The trimmed median keeps the bins within `TRIM_SIGMAS` robust standard deviations
/// (`MAD_TO_SIGMA` median absolute deviations) of the median, and at least `TRIM_MIN_BINS`.
pub const TRIM_SIGMAS: f64 = 3.0;
pub const MAD_TO_SIGMA: f64 = 1.4826;
pub const TRIM_MIN_BINS: usize = 2;
/// Gains this close to 1 are no drift (see [`Balance::is_none`]).
pub const NO_DRIFT: f32 = 0.005;

/// The width of one balance bin (a ratio).
pub fn balance_step() -> f32 {
    (BALANCE_MAX - BALANCE_MIN) / BALANCE_BINS as f32
}

/// The balance histogram's bin of a pixel whose frame value is `level` and reference value
/// `reference_level` (their ratio, binned).
pub fn balance_bin(level: u8, reference_level: u8) -> usize {
    let ratio = level as f32 / reference_level as f32;
    (((ratio - BALANCE_MIN) / balance_step()) as isize).clamp(0, BALANCE_BINS as isize - 1) as usize
}

/// [`balance_bin`] of every pair of levels, `table[reference << 8 | level]`, filled once: the fit
/// looks a sample's bin up instead of dividing (a tenth of a contact frame's time in `cargo
/// xtask bench force`, where each frame is fitted twice: the gate and the input), and the ONNX
/// export carries the same table, so that no runtime's division moves a bin.
pub fn balance_bin_table() -> &'static [u16] {
    static TABLE: std::sync::OnceLock<Vec<u16>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| (0..=255u8).flat_map(|q| (0..=255u8).map(move |p| balance_bin(p, q) as u16)).collect())
}

/// A grey level with a channel's drift undone: times `inverse` (one over the channel's gain),
/// rounded, kept in range.
pub fn undo_level(level: u8, inverse: f32) -> u8 {
    (level as f32 * inverse).round().clamp(0.0, 255.0) as u8
}

/// The gain (frame over reference) a bin stands for: its centre.
pub fn balance_gain(bin: usize) -> f32 {
    BALANCE_MIN + (bin as f32 + 0.5) * balance_step()
}

/// The median bin of a histogram, then again among the bins within three robust standard
/// deviations (1.4826 median absolute deviations) of it: a contact's pixels, all changed one way,
/// pull a plain median by a fraction of the noise; trimmed, they no longer count.
fn trimmed_median_bin(counts: &[u32]) -> usize {
    let median_in = |lo: usize, hi: usize| {
        let total: u64 = counts[lo..=hi].iter().map(|&c| c as u64).sum();
        let mut seen = 0u64;
        (lo..=hi).find(|&k| {
            seen += counts[k] as u64;
            2 * seen >= total
        })
    };
    let last = counts.len() - 1;
    let Some(m) = median_in(0, last) else { return counts.len() / 2 };
    let total: u64 = counts.iter().map(|&c| c as u64).sum();
    let mut seen = counts[m] as u64;
    let mut mad = 0;
    while 2 * seen < total && mad < counts.len() {
        mad += 1;
        seen += m.checked_sub(mad).map_or(0, |k| counts[k] as u64) + counts.get(m + mad).map_or(0, |&c| c as u64);
    }
    let reach = ((TRIM_SIGMAS * MAD_TO_SIGMA * mad as f64).ceil() as usize).max(TRIM_MIN_BINS);
    median_in(m.saturating_sub(reach), (m + reach).min(last)).unwrap_or(m)
}

impl Balance {
    /// No drift.
    pub const NONE: Balance = Balance { gain: [1.0; 3] };

    /// The median of frame / reference per channel over every second useful pixel whose
    /// reference is bright enough (to 1/800 of a ratio); no drift where too few pixels are.
    /// A level the camera clipped at 255 bounds its ratio from below only: left out, as the
    /// reference's own clipped levels are ([`samples`](Self::samples)), so that a camera
    /// brightening past its range is not fitted darker than it is.
    pub fn fit(frame: &RgbImage, reference: &RgbImage, mask: &[bool]) -> Balance {
        let mut hist = vec![[0u32; 3]; BALANCE_BINS];
        let mut counted = [0u32; 3];
        let (levels, references) = (frame.as_raw(), reference.as_raw());
        let bins = balance_bin_table();
        let count = |image: &RgbImage| image.width() as usize * image.height() as usize;
        let pixels = mask.len().min(count(frame)).min(count(reference));
        for i in (0..pixels).step_by(2) {
            for c in 0..3 {
                let (q, p) = (references[3 * i + c], levels[3 * i + c]);
                if Balance::samples(i, mask[i], q) && p < u8::MAX {
                    hist[bins[usize::from(q) << 8 | usize::from(p)] as usize][c] += 1;
                    counted[c] += 1;
                }
            }
        }
        let mut gain = [1.0f32; 3];
        for c in 0..3 {
            if counted[c] >= BALANCE_MIN_SAMPLES {
                let counts: Vec<u32> = hist.iter().map(|bins| bins[c]).collect();
                gain[c] = balance_gain(trimmed_median_bin(&counts));
            }
        }
        Balance { gain }
    }

    /// Whether the fit reads pixel `index` (row-major crop) in a channel whose reference value
    /// is `reference_level`: every second pixel, useful, with a reference bright enough and not
    /// clipped (the fit also leaves out the frame's clipped levels).
    pub fn samples(index: usize, useful: bool, reference_level: u8) -> bool {
        index.is_multiple_of(2) && useful && (BALANCE_MIN_LEVEL..u8::MAX).contains(&reference_level)
    }

    /// Whether this is no drift worth undoing (every gain within 0.5 % of 1: a grey level at
    /// 200; what a contact or noise moves a fit by on an undrifted frame).
    pub fn is_none(&self) -> bool {
        self.gain.iter().all(|g| (g - 1.0).abs() < NO_DRIFT)
    }

    /// `frame` with the drift undone (each channel divided by its gain): the frame as the
    /// reference's camera would have taken it. A level the camera clipped at 255 says only that
    /// the undrifted level is at least 255 / gain; where `reference` is brighter than that, its
    /// level is the reading (a brighter camera saturates the bright spots near the LEDs, and the
    /// gain alone would undo them darker than the reference: a change that is not there).
    pub fn undo(&self, frame: &RgbImage, reference: &RgbImage) -> RgbImage {
        let mut out = frame.clone();
        let inverse = self.gain.map(|g| 1.0 / g);
        // Each channel's 256 levels undone once, then looked up: per pixel, the rounding was a
        // tenth of a contact frame's time (`cargo xtask bench force`).
        let undone: [[u8; 256]; 3] = std::array::from_fn(|c| std::array::from_fn(|v| undo_level(v as u8, inverse[c])));
        let values = 3 * out.width() as usize * out.height() as usize;
        // A reference smaller than the frame (never in a crop) lifts nothing past its end.
        let references = reference.as_raw().chunks_exact(3).map(Some).chain(std::iter::repeat(None));
        let raw: &mut [u8] = &mut out;
        for (p, q) in raw[..values].chunks_exact_mut(3).zip(references) {
            for c in 0..3 {
                let level = p[c];
                p[c] = undone[c][usize::from(level)];
                if let (u8::MAX, Some(q)) = (level, q) {
                    p[c] = p[c].max(q[c]);
                }
            }
        }
        out
    }

    /// The gate's comparison under this drift (worked out once, for a frame's pixels).
    pub fn comparison(&self) -> Comparison {
        let (frame, reference) = (self.gain.map(|g| (1.0 / g).max(1.0)), self.gain.map(|g| g.max(1.0)));
        Comparison {
            frame: std::array::from_fn(|c| std::array::from_fn(|v| v as f32 * frame[c])),
            reference: std::array::from_fn(|c| std::array::from_fn(|v| v as f32 * reference[c])),
        }
    }
}

/// Frame against reference at the brighter of their two exposures, per channel: a darker
/// camera's frame brought up to the reference's colours (its drift undone as
/// [`Balance::undo`] undoes it, unrounded), a brighter camera's reference brought up to the
/// frame's. A contact's change is never shrunk by drift: compared in the frame's colours, a
/// camera 25 % darker showed a contact's change 25 % smaller, and the gate's fixed levels kept
/// faint presses shut; compared in the reference's, a brighter camera's change shrank the same
/// way.
#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// Each channel's 256 frame levels at the brighter exposure: times one over the gain where
    /// the camera darkened, else as they are. Looked up: per pixel, converting and multiplying
    /// cost the gate a tenth of its time.
    frame: [[f32; 256]; 3],
    /// The reference's levels there: times the gain where the camera brightened.
    reference: [[f32; 256]; 3],
}

impl Comparison {
    /// Sum over the channels of |frame level - reference level|, both at the brighter exposure
    /// (grey levels); a level the camera clipped at 255 reads as the reference where that is
    /// brighter, as `undo` lifts it.
    pub fn difference(&self, p: [u8; 3], q: [u8; 3]) -> f32 {
        (0..3)
            .map(|c| {
                let d = self.frame[c][usize::from(p[c])] - self.reference[c][usize::from(q[c])];
                // Clipped, the level is at least what it reads: no change below it. Selects,
                // not one branch on both conditions (which cost the gate a tenth of its time).
                let floor = if p[c] == u8::MAX { 0.0 } else { f32::NEG_INFINITY };
                (if d > floor { d } else { floor }).abs()
            })
            .sum()
    }
}

/// What the fit needs of one labelled frame.
#[derive(Clone, Debug, PartialEq)]
pub struct GateFrame {
    /// Whether its label has contact.
    pub contact: bool,
    /// Useful pixels above each of [`GATE_LEVELS`].
    pub changed: [u32; GATE_LEVELS.len()],
    /// Pixels above each level among its noise pixels (far from contact), scaled to the whole
    /// useful disk: what noise alone would push over the level in an untouched frame.
    pub noise: [f32; GATE_LEVELS.len()],
}

impl GateFrame {
    /// Measures `frame` against `reference` on the useful pixels `mask`; `contact_px` marks the
    /// crop pixels its label has contact at (all false for an untouched frame).
    pub fn measure(frame: &RgbImage, reference: &RgbImage, mask: &[bool], contact_px: &[bool]) -> Self {
        let n = frame.width() as usize;
        let far = far_from(contact_px, n, NOISE_DISTANCE_PX);
        // Measured as the gate compares: the frame's drift taken out.
        let comparison = Balance::fit(frame, reference, mask).comparison();
        let (mut changed, mut noisy) = ([0u32; GATE_LEVELS.len()], [0u32; GATE_LEVELS.len()]);
        let (mut useful, mut noise_px) = (0u32, 0u32);
        for (i, (p, q)) in frame.pixels().zip(reference.pixels()).enumerate() {
            if !mask[i] {
                continue;
            }
            useful += 1;
            let d = comparison.difference(p.0, q.0) / 3.0;
            let above = GATE_LEVELS.partition_point(|&l| l < d);
            changed[..above].iter_mut().for_each(|c| *c += 1);
            if far[i] {
                noise_px += 1;
                noisy[..above].iter_mut().for_each(|c| *c += 1);
            }
        }
        let scale = useful as f32 / noise_px.max(1) as f32;
        let noise = if noise_px > 0 { noisy.map(|c| c as f32 * scale) } else { [f32::INFINITY; GATE_LEVELS.len()] };
        GateFrame { contact: contact_px.iter().any(|&c| c), changed, noise }
    }

    /// [`GateFrame::measure`] for a labelled frame: its contact is where its ground truth
    /// `depth` is deeper than [`CONTACT_THRESHOLD_MM`], as everywhere else.
    pub fn labelled(frame: &RgbImage, reference: &RgbImage, mask: &[bool], depth: &DepthMap) -> Self {
        GateFrame::measure(frame, reference, mask, &depth.contact_px(CONTACT_THRESHOLD_MM))
    }
}

/// Pixels (row-major `n` x `n`) at least `d` pixels (chessboard distance) from every marked one.
fn far_from(marked: &[bool], n: usize, d: usize) -> Vec<bool> {
    // Rows then columns: a marked pixel's reach is a square.
    let rows = dilate(marked, n, d, |line, k| line * n + k);
    let near = dilate(&rows, n, d, |line, k| k * n + line);
    near.into_iter().map(|v| !v).collect()
}

/// Every sample within `d - 1` of a marked one along `n` lines of `n` samples, sample `k` of
/// line `line` at `index(line, k)`.
fn dilate(marked: &[bool], n: usize, d: usize, index: impl Fn(usize, usize) -> usize) -> Vec<bool> {
    let mut out = vec![false; marked.len()];
    for line in 0..n {
        let mut last: Option<usize> = None;
        for k in 0..n {
            if marked[index(line, k)] {
                last = Some(k);
            }
            out[index(line, k)] = last.is_some_and(|l| k - l < d);
        }
        let mut next: Option<usize> = None;
        for k in (0..n).rev() {
            if marked[index(line, k)] {
                next = Some(k);
            }
            out[index(line, k)] |= next.is_some_and(|l| l - k < d);
        }
    }
    out
}

/// What a gate does on a set of labelled frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tally {
    pub frames: usize,
    /// Frames with contact, and those the gate closed on (answered with zeros).
    pub contact: usize,
    pub misses: usize,
    /// Untouched frames, and those the gate opened on (the network ran for nothing).
    pub untouched: usize,
    pub false_opens: usize,
}

impl Tally {
    pub fn of(gate: &ContactGate, frames: &[GateFrame]) -> Self {
        let level = GATE_LEVELS.iter().position(|&l| l == gate.grey_levels);
        let mut t = Tally { frames: frames.len(), ..Default::default() };
        for f in frames {
            // A level the fit did not measure (a hand-set gate) counts as open.
            let open = level.is_none_or(|k| f.changed[k] as usize >= gate.min_pixels);
            if f.contact {
                t.contact += 1;
                t.misses += usize::from(!open);
            } else {
                t.untouched += 1;
                t.false_opens += usize::from(open);
            }
        }
        t
    }
}

/// The gate for a unit from its labelled frames; `None` without a frame with contact (nothing
/// to keep open for).
///
/// For each level: the fewest pixels any contact frame pushes over it (`c`), and the most that
/// noise pushes over it (`u`: the untouched frames' counts and every frame's noise pixels,
/// scaled to the disk). The level with the largest margin `c / (u + 1)` is chosen, and the
/// count set between the two (their geometric mean) where `c > u`, at `c` otherwise: never
/// above a labelled contact frame's count, so none of them is missed.
pub fn fit(frames: &[GateFrame]) -> Option<ContactGate> {
    let contact: Vec<&GateFrame> = frames.iter().filter(|f| f.contact).collect();
    if contact.is_empty() {
        return None;
    }
    let best = (0..GATE_LEVELS.len())
        .map(|k| {
            let c = contact.iter().map(|f| f.changed[k]).min().unwrap_or(0) as f64;
            let u = frames
                .iter()
                .map(|f| if f.contact { f.noise[k] as f64 } else { (f.changed[k] as f64).max(f.noise[k] as f64) })
                .fold(0.0, f64::max);
            (k, c, u)
        })
        .filter(|&(_, c, u)| c >= 1.0 && u.is_finite())
        .max_by(|a, b| (a.1 / (a.2 + 1.0)).total_cmp(&(b.1 / (b.2 + 1.0))))?;
    let (k, c, u) = best;
    let min_pixels = if c > u + 1.0 { ((u + 1.0) * c).sqrt().ceil().clamp(u + 1.0, c) } else { c };
    Some(ContactGate { grey_levels: GATE_LEVELS[k], min_pixels: min_pixels as usize })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit and the undo read tables; they must give what the per-sample formulas give.
    #[test]
    fn the_balance_is_the_per_sample_formulas() {
        let mut state = 12345u64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        for case in 0..12 {
            let (w, h) = (37 + case, 29 + 2 * case);
            let gain = [0.8 + 0.04 * case as f32, 1.0, 1.15 - 0.02 * case as f32];
            let reference = RgbImage::from_fn(w, h, |_, _| image::Rgb([0, 1, 2].map(|_| (next() % 256) as u8)));
            let frame = RgbImage::from_fn(w, h, |x, y| {
                let q = reference.get_pixel(x, y).0;
                image::Rgb(
                    [0, 1, 2].map(|c| (q[c] as f32 * gain[c] + (next() % 9) as f32 - 4.0).clamp(0.0, 255.0) as u8),
                )
            });
            let mask: Vec<bool> = (0..w * h).map(|_| next() % 5 != 0).collect();
            let mut hist = vec![[0u32; 3]; BALANCE_BINS];
            let mut counted = [0u32; 3];
            for (i, ((p, q), &useful)) in frame.pixels().zip(reference.pixels()).zip(&mask).enumerate() {
                for c in 0..3 {
                    if Balance::samples(i, useful, q.0[c]) && p.0[c] != 255 {
                        hist[balance_bin(p.0[c], q.0[c])][c] += 1;
                        counted[c] += 1;
                    }
                }
            }
            let expected = std::array::from_fn(|c| {
                let counts: Vec<u32> = hist.iter().map(|b| b[c]).collect();
                if counted[c] >= BALANCE_MIN_SAMPLES { balance_gain(trimmed_median_bin(&counts)) } else { 1.0 }
            });
            let fitted = Balance::fit(&frame, &reference, &mask);
            assert_eq!(fitted.gain.map(f32::to_bits), expected.map(f32::to_bits), "case {case}");
            assert!(fitted.gain.iter().zip(gain).all(|(a, b)| (a - b).abs() < 0.02), "case {case}: {fitted:?}");
            let undone = fitted.undo(&frame, &reference);
            let inverse = fitted.gain.map(|g| 1.0 / g);
            for ((p, q), r) in frame.pixels().zip(undone.pixels()).zip(reference.pixels()) {
                let level = |c: usize| match p.0[c] {
                    255 => undo_level(255, inverse[c]).max(r.0[c]),
                    v => undo_level(v, inverse[c]),
                };
                assert_eq!(q.0, [0, 1, 2].map(level));
            }
            // A container longer than its image (and a longer mask): only the image is read
            // and changed.
            let mut longer = frame.as_raw().clone();
            longer.extend([7u8; 6]);
            let longer = RgbImage::from_raw(w, h, longer).expect("container large enough");
            let longer_mask: Vec<bool> = mask.iter().copied().chain([true; 2]).collect();
            assert_eq!(Balance::fit(&longer, &reference, &longer_mask), fitted, "case {case}");
            assert_eq!(fitted.undo(&longer, &reference).as_raw()[undone.as_raw().len()..], [7u8; 6]);
        }
    }

    /// A camera brighter by 30 % saturates the reference's bright spots: undone, the frame is
    /// the reference again (within rounding) on every pixel, the clipped ones included, and
    /// the gate's comparison sees no change; the gain alone would leave the clipped pixels up
    /// to 54 levels darker than the reference.
    #[test]
    fn a_clipped_level_reads_as_the_reference_where_that_is_brighter() {
        let (w, h) = (64, 48);
        let reference =
            RgbImage::from_fn(w, h, |x, y| image::Rgb([0, 1, 2].map(|c| (24 + (x * 7 + y * 13 + c * 31) % 227) as u8)));
        let gain = [1.3f32, 1.22, 1.1];
        let frame = RgbImage::from_fn(w, h, |x, y| {
            let q = reference.get_pixel(x, y).0;
            image::Rgb([0, 1, 2].map(|c| (q[c] as f32 * gain[c]).round().min(255.0) as u8))
        });
        let clipped = frame.as_raw().iter().filter(|&&v| v == 255).count();
        assert!(clipped > 300, "the case clips ({clipped} levels)");
        let mask = vec![true; (w * h) as usize];
        let balance = Balance::fit(&frame, &reference, &mask);
        assert!(balance.gain.iter().zip(gain).all(|(a, b)| (a - b).abs() < 0.0025), "{balance:?}");
        let undone = balance.undo(&frame, &reference);
        let comparison = balance.comparison();
        for ((u, q), p) in undone.pixels().zip(reference.pixels()).zip(frame.pixels()) {
            for c in 0..3 {
                assert!(
                    u.0[c].abs_diff(q.0[c]) <= 1,
                    "channel {c}: {} undone to {}, reference {}",
                    p.0[c],
                    u.0[c],
                    q.0[c]
                );
            }
            assert!(comparison.difference(p.0, q.0) <= 3.0, "the gate sees {p:?} against {q:?} as a change");
        }
        let gain_only = reference.pixels().zip(frame.pixels()).flat_map(|(q, p)| {
            (0..3).map(move |c| i32::from(q.0[c]) - i32::from(undo_level(p.0[c], 1.0 / balance.gain[c])))
        });
        assert!(gain_only.max().unwrap() > 40, "without the lift the clipped pixels undo dark");
    }

    /// A frame of a flat grey unit with noise of `sd` grey levels and, if `contact`, a disk of
    /// radius `r` changed by `change` grey levels; its contact label.
    fn frame(n: u32, sd: f64, seed: u64, contact: Option<(u32, f32)>) -> (RgbImage, Vec<bool>) {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut noise = || {
            // Sum of uniforms, about normal.
            (0..6)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .sum::<f64>()
                * sd
                * 2.0
        };
        let mut label = vec![false; (n * n) as usize];
        let img = RgbImage::from_fn(n, n, |x, y| {
            let inside = contact.is_some_and(|(r, _)| {
                let (dx, dy) = (x as i64 - n as i64 / 2, y as i64 - n as i64 / 2);
                dx * dx + dy * dy <= (r * r) as i64
            });
            label[(y * n + x) as usize] = inside;
            let change = if inside { contact.unwrap().1 } else { 0.0 };
            image::Rgb(
                [0, 1, 2].map(|c| (100.0 + c as f64 * 20.0 + change as f64 + noise()).round().clamp(0.0, 255.0) as u8),
            )
        });
        (img, label)
    }

    #[test]
    fn the_fitted_gate_keeps_every_contact_frame_and_closes_on_noise() {
        let n = 120;
        let reference = RgbImage::from_fn(n, n, |_, _| image::Rgb([100, 120, 140]));
        let mask = vec![true; (n * n) as usize];
        for sd in [1.0, 4.0] {
            let mut frames = Vec::new();
            for seed in 0..6 {
                let (img, label) = frame(n, sd, seed, None);
                frames.push(GateFrame::measure(&img, &reference, &mask, &label));
            }
            // Small, faint contacts: 4 px radius, 10 grey levels.
            for seed in 10..16 {
                let (img, label) = frame(n, sd, seed, Some((4, 10.0)));
                frames.push(GateFrame::measure(&img, &reference, &mask, &label));
            }
            let gate = fit(&frames).unwrap();
            let t = Tally::of(&gate, &frames);
            assert_eq!((t.contact, t.misses, t.untouched), (6, 0, 6), "noise {sd}: {gate:?} {t:?}");
            assert_eq!(t.false_opens, 0, "noise {sd}: a faint contact still stands above this noise: {gate:?}");
            // Unseen frames of the same unit behave alike.
            let (quiet, label) = frame(n, sd, 99, None);
            assert!(!gate.differs(&quiet, &reference, &mask), "noise {sd}");
            let (pressed, _) = frame(n, sd, 98, Some((5, 10.0)));
            assert!(gate.differs(&pressed, &reference, &mask), "noise {sd}");
            // Without untouched frames the noise comes from the pressed frames' far pixels.
            let only_contact: Vec<GateFrame> = frames.iter().filter(|f| f.contact).cloned().collect();
            let gate = fit(&only_contact).unwrap();
            assert!(!gate.differs(&quiet, &reference, &mask) && gate.differs(&pressed, &reference, &mask));
            let _ = label;
        }
        // Nothing labelled with contact: nothing to fit.
        let (img, label) = frame(n, 1.0, 1, None);
        assert_eq!(fit(&[GateFrame::measure(&img, &reference, &mask, &label)]), None);
    }

    /// `img` as drift leaves it: each channel times its gain.
    fn drifted(img: &RgbImage, gain: [f32; 3]) -> RgbImage {
        RgbImage::from_fn(img.width(), img.height(), |x, y| {
            let p = img.get_pixel(x, y).0;
            image::Rgb([0, 1, 2].map(|c| (p[c] as f32 * gain[c]).round().clamp(0.0, 255.0) as u8))
        })
    }

    #[test]
    fn drift_does_not_open_the_gate_and_a_contact_under_drift_still_does() {
        let n = 120;
        let reference = RgbImage::from_fn(n, n, |x, y| image::Rgb([90 + (x % 40) as u8, 110, 130 + (y % 30) as u8]));
        let mask = vec![true; (n * n) as usize];
        let noisy = |seed, contact| {
            let (img, label) = frame(n, 1.5, seed, contact);
            // The test frame's flat colours replaced by the reference's pattern, its noise kept.
            let img = RgbImage::from_fn(n, n, |x, y| {
                let (p, q) = (img.get_pixel(x, y).0, reference.get_pixel(x, y).0);
                let base = [100u8, 120, 140];
                image::Rgb([0, 1, 2].map(|c| (q[c] as i32 + p[c] as i32 - base[c] as i32).clamp(0, 255) as u8))
            });
            (img, label)
        };
        let gate = ContactGate { grey_levels: 8.0, min_pixels: 30 };
        // A global gain of 0.9 to 1.1 with a 5 % cast per channel: what a fixed comparison
        // reads as a change of 5 to 15 grey levels everywhere.
        for (k, gain) in
            [[0.9, 0.95, 0.86], [1.1, 1.05, 1.155], [1.0, 1.05, 0.95], [0.95, 0.95, 0.95]].iter().enumerate()
        {
            let (quiet, _) = noisy(40 + k as u64, None);
            let quiet = drifted(&quiet, *gain);
            let fitted = Balance::fit(&quiet, &reference, &mask);
            for c in 0..3 {
                assert!((fitted.gain[c] - gain[c]).abs() < 0.01, "{gain:?}: fitted {fitted:?}");
            }
            assert!(!gate.differs(&quiet, &reference, &mask), "drift {gain:?} opened the gate");
            // The same drift on a small, faint contact (5 px, 12 grey levels): still open.
            let (pressed, _) = noisy(50 + k as u64, Some((5, 12.0)));
            assert!(gate.differs(&drifted(&pressed, *gain), &reference, &mask), "drift {gain:?} closed on a contact");
        }
        // Without the balance, the same drift opens a fixed comparison (the test means something).
        let (quiet, _) = noisy(60, None);
        let quiet = drifted(&quiet, [1.1, 1.05, 1.155]);
        let unbalanced = Balance::NONE.comparison();
        let opened = quiet
            .pixels()
            .zip(reference.pixels())
            .filter(|(p, q)| unbalanced.difference(p.0, q.0) > gate.grey_levels * 3.0)
            .count();
        assert!(opened >= gate.min_pixels, "{opened}");
        // A contact covering a third of the frame does not move the fitted balance.
        let (big, _) = noisy(61, Some((40, 30.0)));
        let fitted = Balance::fit(&big, &reference, &mask);
        assert!(fitted.gain.iter().all(|g| (g - 1.0).abs() < 0.01), "{fitted:?}");
    }

    /// A camera drifted 25 % darker shows a contact's change 25 % smaller: compared at the
    /// reference's exposure, a faint contact the gate opens on undrifted still opens it, where
    /// the frame's colours (the drifted reference against the frame) keep it shut; a camera 25 %
    /// brighter is compared at its own exposure, where the change is larger, and the reference's
    /// colours (the frame's drift undone) would shrink it and keep the gate shut.
    #[test]
    fn a_faint_contact_under_a_darker_or_brighter_camera_still_opens_the_gate() {
        let n = 120;
        let reference = RgbImage::from_fn(n, n, |_, _| image::Rgb([100, 120, 140]));
        let mask = vec![true; (n * n) as usize];
        let gate = ContactGate { grey_levels: 8.0, min_pixels: 30 };
        let gain = [0.75f32; 3];
        for seed in 70..74 {
            // 5 px radius (81 px), 10 grey levels: 30 summed against the gate's 24.
            let (pressed, _) = frame(n, 1.5, seed, Some((5, 10.0)));
            assert!(gate.differs(&pressed, &reference, &mask), "seed {seed}: undrifted");
            let dark = drifted(&pressed, gain);
            let balance = Balance::fit(&dark, &reference, &mask);
            assert!(balance.gain.iter().all(|g| (g - 0.75).abs() < 0.01), "{balance:?}");
            assert!(gate.differs(&dark, &reference, &mask), "seed {seed}: the darker camera shut the gate");
            let in_frame_colours = dark
                .pixels()
                .zip(reference.pixels())
                .filter(|(p, q)| {
                    (0..3).map(|c| (p.0[c] as f32 - balance.gain[c] * q.0[c] as f32).abs()).sum::<f32>()
                        > gate.grey_levels * 3.0
                })
                .count();
            assert!(in_frame_colours < gate.min_pixels, "seed {seed}: {in_frame_colours} (the case means nothing)");
        }
        // And noise alone, as dark, does not open it.
        let (quiet, _) = frame(n, 1.5, 80, None);
        assert!(!gate.differs(&drifted(&quiet, gain), &reference, &mask));
        // Brighter: 7 grey levels (21 summed) undrifted, 26 at x1.25, against the gate's 24.
        let gain = [1.25f32; 3];
        for seed in 90..94 {
            let (pressed, _) = frame(n, 1.0, seed, Some((5, 7.0)));
            let bright = drifted(&pressed, gain);
            assert!(gate.differs(&bright, &reference, &mask), "seed {seed}: the brighter camera shut the gate");
            let balance = Balance::fit(&bright, &reference, &mask);
            let in_reference_colours = bright
                .pixels()
                .zip(reference.pixels())
                .filter(|(p, q)| {
                    (0..3).map(|c| (p.0[c] as f32 / balance.gain[c] - q.0[c] as f32).abs()).sum::<f32>()
                        > gate.grey_levels * 3.0
                })
                .count();
            assert!(in_reference_colours < gate.min_pixels, "seed {seed}: {in_reference_colours}");
        }
        let (quiet, _) = frame(n, 1.0, 81, None);
        assert!(!gate.differs(&drifted(&quiet, gain), &reference, &mask));
    }

    #[test]
    fn far_pixels_keep_their_distance() {
        let n = 9;
        let mut marked = vec![false; 81];
        marked[4 * 9 + 4] = true;
        let far = far_from(&marked, n, 2);
        assert!(!far[4 * 9 + 4] && !far[4 * 9 + 5] && !far[3 * 9 + 3]);
        assert!(far[4 * 9 + 6] && far[2 * 9 + 4] && far[0]);
    }
}
