//! Keeping the reference frame current while streaming: a camera drifts (LEDs warm up, auto
//! exposure and white balance move, the gel ages), and a reference taken at the start reads the
//! drift as contact. The gate takes out a frame's global drift itself ([`sensor::gate::Balance`]);
//! what is left (the network's input difference, its tare, drift that is not the same
//! everywhere) follows the unit as it looks now, slowly, from untouched frames only (`infer
//! stream`'s default; `--fixed-reference` keeps the bundle's; `cargo xtask bench drift`
//! measures both).

use image::RgbImage;
use serde::{Deserialize, Serialize};

/// How the reference follows the camera. A frame counts as untouched when the gate closes on it
/// (without a gate: when the network finds no contact pixel).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefreshConfig {
    /// Untouched this long (seconds) before frames are used: a gel released a moment ago may
    /// still be relaxing.
    pub settle_s: f64,
    /// Untouched frames are averaged over this long (seconds) for each update.
    pub window_s: f64,
    /// Each update moves the reference this far towards the window's mean (0..=1).
    pub weight: f32,
    /// A window needs at least this many frames.
    pub min_frames: u32,
}

impl Default for RefreshConfig {
    fn default() -> Self {
        RefreshConfig { settle_s: 2.0, window_s: 5.0, weight: 0.25, min_frames: 3 }
    }
}

/// Follows the untouched frames of a stream and says when, and to what, the reference moves.
/// A contact resets everything it gathered: a pressed frame never enters the reference.
#[derive(Clone, Debug)]
pub struct ReferenceKeeper {
    config: RefreshConfig,
    /// When the current untouched stretch began (seconds).
    quiet_since: Option<f64>,
    /// When the current window began, and its frames' sum (RGB, row-major).
    window_start: Option<f64>,
    sum: Vec<f32>,
    frames: u32,
    /// Updates made so far.
    pub updates: u64,
}

impl ReferenceKeeper {
    pub fn new(config: RefreshConfig) -> Self {
        ReferenceKeeper { config, quiet_since: None, window_start: None, sum: Vec::new(), frames: 0, updates: 0 }
    }

    /// Feeds the frame seen at `t_s` (seconds, any origin, not decreasing) and whether it was
    /// untouched; returns the new reference when an update is due (`reference` is the current
    /// one, which the frames must match in size).
    pub fn observe(&mut self, t_s: f64, frame: &RgbImage, untouched: bool, reference: &RgbImage) -> Option<RgbImage> {
        if !untouched || frame.dimensions() != reference.dimensions() {
            self.quiet_since = None;
            self.forget();
            return None;
        }
        let since = *self.quiet_since.get_or_insert(t_s);
        if t_s - since < self.config.settle_s {
            return None;
        }
        let start = *self.window_start.get_or_insert(t_s);
        if self.sum.len() != frame.as_raw().len() {
            self.sum = vec![0.0; frame.as_raw().len()];
        }
        self.sum.iter_mut().zip(frame.as_raw()).for_each(|(s, &v)| *s += v as f32);
        self.frames += 1;
        if t_s - start < self.config.window_s || self.frames < self.config.min_frames {
            return None;
        }
        let (w, n) = (self.config.weight.clamp(0.0, 1.0), self.frames as f32);
        let mixed: Vec<u8> = reference
            .as_raw()
            .iter()
            .zip(&self.sum)
            .map(|(&r, &s)| ((1.0 - w) * r as f32 + w * s / n).round().clamp(0.0, 255.0) as u8)
            .collect();
        self.forget();
        self.updates += 1;
        RgbImage::from_raw(reference.width(), reference.height(), mixed)
    }

    fn forget(&mut self) {
        self.window_start = None;
        self.sum.iter_mut().for_each(|s| *s = 0.0);
        self.frames = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(v: u8) -> RgbImage {
        RgbImage::from_pixel(8, 8, image::Rgb([v, v, v]))
    }

    #[test]
    fn untouched_frames_move_the_reference_slowly_and_a_contact_never_does() {
        let config = RefreshConfig { settle_s: 2.0, window_s: 5.0, weight: 0.25, min_frames: 3 };
        let mut keeper = ReferenceKeeper::new(config);
        let reference = flat(100);
        // Untouched at 120 for 1.9 s: still settling, nothing gathered.
        for k in 0..20 {
            assert_eq!(keeper.observe(k as f64 * 0.1, &flat(120), true, &reference), None);
        }
        // A contact (a bright frame) resets the stretch: it is never part of an update.
        assert_eq!(keeper.observe(2.0, &flat(250), false, &reference), None);
        let mut updated = None;
        let mut t = 2.1;
        while updated.is_none() {
            updated = keeper.observe(t, &flat(120), true, &reference);
            t += 0.1;
            assert!(t < 20.0, "no update");
        }
        // Settling (2 s) and a window (5 s) after the contact, a quarter of the way to 120.
        assert!((t - 2.1 - 7.0).abs() < 0.25, "{t}");
        assert_eq!(updated.unwrap(), flat(105));
        assert_eq!(keeper.updates, 1);
        // A frame of another size never enters (and resets).
        assert_eq!(keeper.observe(t, &RgbImage::new(4, 4), true, &reference), None);
    }
}
