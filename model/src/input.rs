//! What the network sees: a camera crop, and optionally its difference to the unit's reference
//! frame. Training and inference both encode through [`InputEncoder`], so the two cannot drift
//! apart.
//!
//! The difference channels carry what contact changed. They remove the unit's own shading (LED
//! placement, gel colour, vignetting) from what the network must learn, which a short CPU
//! budget and a fine-tune from a little data both need.

use image::RgbImage;
use serde::{Deserialize, Serialize};

/// The channels of the network's input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputChannels {
    /// R, G, B in [0, 1]: the paper's input.
    #[default]
    Rgb,
    /// R, G, B in [0, 1], then `gain * (frame - reference)` for each of R, G, B (the gain fitted
    /// to the unit's data: [`InputEncoding`]).
    RgbDifference,
}

/// Scale of the difference channels where a unit's data does not say otherwise (no labelled
/// contact to measure, bundles written before [`InputEncoding::difference_gain`] was fitted):
/// contact changes the renderer's shading by a few grey levels on average, noise by one or two;
/// four times the difference puts contact near the RGB channels' range.
pub const DIFFERENCE_GAIN: f32 = 4.0;

/// What the difference channels should read where a unit's labelled contact is: the mean over
/// those pixels of |frame - reference| (the three channels' mean, in [0, 1]) times the gain.
/// Measured at the quickstart's 128x128 (`DepthDataset::set_model`), contact changes the
/// project's renderer's units 0, 3, 7, 11, 23 and 31 by 0.019..0.029 and the independent image
/// model's (`gelcam`) units 40..44 by 0.007..0.017. The target keeps the renderer's units near
/// the [`DIFFERENCE_GAIN`] the recipe was measured with (3.1..4.7; unit 7, the quickstart's,
/// 4.05) and gives a gel that changes less a larger gain (gelcam's 5.3..12.7), so the network
/// reads every unit's contact at one scale and a base model's inputs keep their size when it
/// is fine-tuned on another unit.
pub const DIFFERENCE_TARGET: f32 = 0.09;

/// The gains a unit's data may give: beyond these the measurement is suspect (a unit whose
/// contact changes its frame by under a tenth of a grey level on average is not readable; one
/// that changes it by half the range needs no gain).
pub const DIFFERENCE_GAIN_RANGE: [f32; 2] = [1.0, 64.0];

/// How the network's input is made from a crop: the channels and, where they hold the
/// reference difference, its gain. The bundle records it as text (`input_encoding`), e.g.
/// `rgb/255,4.37*(rgb-reference)/255`, so that a reader of the bundle needs nothing else.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputEncoding {
    pub channels: InputChannels,
    /// Multiplies `(frame - reference) / 255` in the difference channels; unused by RGB alone.
    pub difference_gain: f32,
}

impl InputEncoding {
    /// `channels` with the default gain.
    pub fn new(channels: InputChannels) -> Self {
        InputEncoding { channels, difference_gain: DIFFERENCE_GAIN }
    }

    /// The gain that brings a unit's measured `contact_change` (mean |frame - reference| over
    /// its labelled contact pixels, in [0, 1]) to [`DIFFERENCE_TARGET`], to two decimals, kept
    /// within [`DIFFERENCE_GAIN_RANGE`]; `None` (nothing measured) gives the default.
    pub fn fitted(channels: InputChannels, contact_change: Option<f64>) -> Self {
        let gain = match contact_change {
            Some(c) if c.is_finite() && c > 0.0 => {
                let [lo, hi] = DIFFERENCE_GAIN_RANGE;
                ((DIFFERENCE_TARGET as f64 / c * 100.0).round() / 100.0).clamp(lo as f64, hi as f64) as f32
            }
            _ => DIFFERENCE_GAIN,
        };
        InputEncoding { channels, difference_gain: gain }
    }

    /// The bundle's `input_encoding` text.
    pub fn text(&self) -> String {
        match self.channels {
            InputChannels::Rgb => "rgb/255".into(),
            InputChannels::RgbDifference => format!("rgb/255,{}*(rgb-reference)/255", self.difference_gain),
        }
    }

    /// The encoding whose [`text`](Self::text) is `text`; `None` for anything else (a gain must
    /// be finite and within [`DIFFERENCE_GAIN_RANGE`]).
    pub fn parse(text: &str) -> Option<Self> {
        if text == "rgb/255" {
            return Some(InputEncoding::new(InputChannels::Rgb));
        }
        let gain: f32 = text.strip_prefix("rgb/255,")?.strip_suffix("*(rgb-reference)/255")?.parse().ok()?;
        let [lo, hi] = DIFFERENCE_GAIN_RANGE;
        (gain.is_finite() && (lo..=hi).contains(&gain))
            .then_some(InputEncoding { channels: InputChannels::RgbDifference, difference_gain: gain })
    }
}

impl InputChannels {
    /// Channels the network's first convolution takes.
    pub fn count(self) -> usize {
        match self {
            InputChannels::Rgb => 3,
            InputChannels::RgbDifference => 6,
        }
    }

    /// Whether encoding needs the unit's reference frame.
    pub fn needs_reference(self) -> bool {
        self == InputChannels::RgbDifference
    }

    pub const ALL: [InputChannels; 2] = [InputChannels::Rgb, InputChannels::RgbDifference];

    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            InputChannels::Rgb => "rgb",
            InputChannels::RgbDifference => "rgb-difference",
        }
    }
}

impl std::str::FromStr for InputChannels {
    type Err = formats::UnknownName;

    /// The channels by their name on the command line.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        formats::find_by_name("input", s, &InputChannels::ALL, InputChannels::name)
    }
}

/// A crop resized to the network's `[h, w]` as the input encoding resizes it (triangle filter);
/// an image already that size comes back unchanged, so a resized crop may be kept and encoded
/// later with the same result.
pub fn resized(img: &RgbImage, [h, w]: [usize; 2]) -> RgbImage {
    image::imageops::resize(img, w as u32, h as u32, image::imageops::FilterType::Triangle)
}

/// The taps of [`resized`] along one axis, from `n_in` to `n_out` pixels: per output pixel, its
/// first input pixel and the weights, computed as the `image` crate computes them (f32, triangle
/// kernel widened by the ratio when shrinking, normalised), so that a graph replaying the resize
/// (the ONNX export's) weighs the pixels alike. `resized` runs the vertical taps first, in f32
/// without rounding, then the horizontal ones, then rounds to the nearest grey level.
pub fn resize_taps(n_in: usize, n_out: usize) -> Vec<(usize, Vec<f32>)> {
    let ratio = n_in as f32 / n_out as f32;
    let sratio = ratio.max(1.0);
    // The triangle filter's support is one pixel, widened by the ratio.
    let support = sratio;
    (0..n_out)
        .map(|out| {
            let centre = (out as f32 + 0.5) * ratio;
            let left = ((centre - support).floor() as i64).clamp(0, n_in as i64 - 1);
            let right = ((centre + support).ceil() as i64).clamp(left + 1, n_in as i64);
            let centre = centre - 0.5;
            let mut weights: Vec<f32> = (left..right)
                .map(|i| {
                    let x = ((i as f32 - centre) / sratio).abs();
                    if x < 1.0 { 1.0 - x } else { 0.0 }
                })
                .collect();
            let sum: f32 = weights.iter().fold(0.0, |a, &w| a + w);
            weights.iter_mut().for_each(|w| *w /= sum);
            (left as usize, weights)
        })
        .collect()
}

/// A crop's R, G, B planes resized to `[h, w]` ([`resized`]), channel-major, values / 255.
pub fn rgb_planes(img: &RgbImage, [h, w]: [usize; 2]) -> Vec<f32> {
    let small = resized(img, [h, w]);
    let mut input = vec![0f32; 3 * h * w];
    for (k, px) in small.pixels().enumerate() {
        for c in 0..3 {
            input[c * h * w + k] = px.0[c] as f32 / 255.0;
        }
    }
    input
}

/// A change to channel-major R, G, B planes, in place.
pub type PlaneEdit<'a> = &'a dyn Fn(&mut [f32]);

/// The unit's reference frame is needed and missing, or does not fit the crop.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

/// Turns crops into the network's input for one unit at one input size.
#[derive(Clone, Debug)]
pub struct InputEncoder {
    encoding: InputEncoding,
    hw: [usize; 2],
    /// The reference frame's R, G, B planes, when the channels use it.
    reference: Option<Vec<f32>>,
}

impl InputEncoder {
    /// An encoder for `encoding` at `hw`; `reference` (the unit's no-contact crop) must be given
    /// when its channels use it, and is ignored otherwise.
    pub fn new(encoding: InputEncoding, hw: [usize; 2], reference: Option<&RgbImage>) -> Result<Self, InputError> {
        let channels = encoding.channels;
        let reference = match (channels.needs_reference(), reference) {
            (false, _) => None,
            (true, Some(r)) => Some(rgb_planes(r, hw)),
            (true, None) => {
                return Err(InputError(format!(
                    "the network's input ({}) needs the unit's reference frame (a crop with nothing touching)",
                    channels.name()
                )));
            }
        };
        Ok(InputEncoder { encoding, hw, reference })
    }

    pub fn channels(&self) -> InputChannels {
        self.encoding.channels
    }

    pub fn encoding(&self) -> InputEncoding {
        self.encoding
    }

    pub fn hw(&self) -> [usize; 2] {
        self.hw
    }

    /// The reference frame's R, G, B planes at the input size (values / 255), where the
    /// channels use them.
    pub fn reference_planes(&self) -> Option<&[f32]> {
        self.reference.as_deref()
    }

    /// The network's input for `img`, channel-major.
    pub fn encode(&self, img: &RgbImage) -> Vec<f32> {
        self.encode_with(img, |_| {})
    }

    /// Like [`encode`](Self::encode), with `edit` applied to the R, G, B planes first (training's
    /// photometric jitter): the difference channels then see the edited frame against the
    /// untouched reference, as a drifting lamp would show.
    pub fn encode_with(&self, img: &RgbImage, edit: impl FnOnce(&mut [f32])) -> Vec<f32> {
        self.encode_looking(img, None, edit)
    }

    /// Like [`encode_with`](Self::encode_with), with `look` applied first to the frame's and the
    /// reference's R, G, B planes alike: the scene as another unit's camera and lights would
    /// show it (training's variation between units), before `edit` changes the frame alone.
    pub fn encode_looking(
        &self,
        img: &RgbImage,
        look: Option<PlaneEdit<'_>>,
        edit: impl FnOnce(&mut [f32]),
    ) -> Vec<f32> {
        let mut planes = rgb_planes(img, self.hw);
        if let Some(look) = look {
            look(&mut planes);
        }
        edit(&mut planes);
        if let Some(reference) = &self.reference {
            let looked = look.map(|look| {
                let mut r = reference.clone();
                look(&mut r);
                r
            });
            let reference = looked.as_deref().unwrap_or(reference);
            let gain = self.encoding.difference_gain;
            let difference: Vec<f32> = planes.iter().zip(reference).map(|(a, b)| gain * (a - b)).collect();
            planes.extend(difference);
        }
        planes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(rgb: [u8; 3]) -> RgbImage {
        RgbImage::from_pixel(40, 40, image::Rgb(rgb))
    }

    /// [`resize_taps`] replayed as the `image` crate runs them (vertical, then horizontal, f32
    /// sums in tap order, clamped and rounded) gives `image`'s resize bit for bit, shrinking and
    /// growing, so the taps are its taps.
    #[test]
    fn resize_taps_are_the_image_crates() {
        let mut state = 0x2545_f491_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state >> 24) as u8
        };
        for ([h0, w0], [h, w]) in [([570, 570], [64, 64]), ([97, 131], [128, 40]), ([33, 20], [33, 57])] {
            let img = RgbImage::from_fn(w0, h0, |_, _| image::Rgb([next(), next(), next()]));
            let want = resized(&img, [h as usize, w as usize]);
            let (ty, tx) = (resize_taps(h0 as usize, h as usize), resize_taps(w0 as usize, w as usize));
            for c in 0..3 {
                let mut mid = vec![0f32; h as usize * w0 as usize];
                for (y, (lo, ws)) in ty.iter().enumerate() {
                    for x in 0..w0 as usize {
                        let mut t = 0f32;
                        for (k, wk) in ws.iter().enumerate() {
                            t += img.get_pixel(x as u32, (lo + k) as u32).0[c] as f32 * wk;
                        }
                        mid[y * w0 as usize + x] = t;
                    }
                }
                for y in 0..h as usize {
                    for (x, (lo, ws)) in tx.iter().enumerate() {
                        let mut t = 0f32;
                        for (k, wk) in ws.iter().enumerate() {
                            t += mid[y * w0 as usize + lo + k] * wk;
                        }
                        let got = t.clamp(0.0, 255.0).round() as u8;
                        assert_eq!(
                            got,
                            want.get_pixel(x as u32, y as u32).0[c],
                            "{h0}x{w0} to {h}x{w}, ({x}, {y}) {c}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn planes_are_red_green_blue_in_that_order() {
        let x = rgb_planes(&uniform([255, 51, 0]), [8, 8]);
        assert_eq!((x[0], x[64], x[128]), (1.0, 0.2, 0.0));
        assert_eq!(x.len(), 3 * 64);
    }

    #[test]
    fn difference_channels_follow_the_rgb_ones_and_vanish_on_the_reference() {
        let reference = uniform([100, 100, 100]);
        let enc =
            InputEncoder::new(InputEncoding::new(InputChannels::RgbDifference), [8, 16], Some(&reference)).unwrap();
        let same = enc.encode(&reference);
        assert_eq!(same.len(), 6 * 8 * 16);
        assert!(same[3 * 128..].iter().all(|&v| v == 0.0));
        let brighter = enc.encode(&uniform([110, 100, 90]));
        let per = 128;
        let want = [10.0, 0.0, -10.0].map(|g| DIFFERENCE_GAIN * g / 255.0);
        for (c, w) in want.into_iter().enumerate() {
            assert!((brighter[(3 + c) * per] - w).abs() < 1e-6, "channel {c}");
        }
        // The edit (jitter) reaches the difference too.
        let edited = enc.encode_with(&reference, |p| p.iter_mut().for_each(|v| *v += 0.01));
        assert!((edited[3 * per] - DIFFERENCE_GAIN * 0.01).abs() < 1e-6);
        // A look changes the reference as it changes the frame: the reference still reads as
        // no difference, and a brighter frame's difference is that of the looked values.
        let halve = |p: &mut [f32]| p.iter_mut().for_each(|v| *v *= 0.5);
        let looked = enc.encode_looking(&reference, Some(&halve), |_| {});
        assert!((looked[0] - 50.0 / 255.0).abs() < 1e-6);
        assert!(looked[3 * 128..].iter().all(|&v| v == 0.0));
        let brighter_looked = enc.encode_looking(&uniform([110, 100, 90]), Some(&halve), |_| {});
        for (c, w) in want.into_iter().enumerate() {
            assert!((brighter_looked[(3 + c) * per] - 0.5 * w).abs() < 1e-6, "channel {c}");
        }
    }

    #[test]
    fn a_missing_reference_is_an_error_only_when_needed() {
        assert!(InputEncoder::new(InputEncoding::new(InputChannels::Rgb), [8, 8], None).is_ok());
        let e =
            InputEncoder::new(InputEncoding::new(InputChannels::RgbDifference), [8, 8], None).unwrap_err().to_string();
        assert!(e.contains("reference frame"), "{e}");
        for c in [InputChannels::Rgb, InputChannels::RgbDifference] {
            assert_eq!(c.name().parse::<InputChannels>(), Ok(c));
        }
        let e = "bgr".parse::<InputChannels>().unwrap_err().to_string();
        assert!(e.contains("rgb, rgb-difference"), "{e}");
    }

    #[test]
    fn the_encoding_text_round_trips_and_reads_the_texts_bundles_were_written_with() {
        // Bundles written before the gain was fitted say 4 in so many words.
        let old = InputEncoding::parse("rgb/255,4*(rgb-reference)/255").unwrap();
        assert_eq!(old, InputEncoding::new(InputChannels::RgbDifference));
        assert_eq!(InputEncoding::parse("rgb/255"), Some(InputEncoding::new(InputChannels::Rgb)));
        for gain in [1.0, 4.37, 12.5, 64.0] {
            let e = InputEncoding { channels: InputChannels::RgbDifference, difference_gain: gain };
            assert_eq!(InputEncoding::parse(&e.text()), Some(e), "{}", e.text());
        }
        for bad in [
            "bgr/255",
            "rgb/255,",
            "rgb/255,nan*(rgb-reference)/255",
            "rgb/255,inf*(rgb-reference)/255",
            "rgb/255,0*(rgb-reference)/255",
            "rgb/255,-4*(rgb-reference)/255",
            "rgb/255,65*(rgb-reference)/255",
            "rgb/255,4*(rgb-reference)",
        ] {
            assert_eq!(InputEncoding::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn a_unit_whose_contact_changes_its_frame_less_gets_a_larger_gain() {
        let d = InputChannels::RgbDifference;
        // The target over the change, to two decimals.
        assert_eq!(InputEncoding::fitted(d, Some(0.0225)).difference_gain, 4.0);
        assert_eq!(InputEncoding::fitted(d, Some(0.01)).difference_gain, 9.0);
        assert_eq!(InputEncoding::fitted(d, Some(0.07)).difference_gain, 1.29);
        // Halving the change doubles the encoded difference's gain: the product stays the target.
        for change in [0.004, 0.0093, 0.02] {
            let g = InputEncoding::fitted(d, Some(change)).difference_gain as f64;
            assert!((g * change - DIFFERENCE_TARGET as f64).abs() < 0.005 * change, "{change}: {g}");
        }
        // Nothing measured, or nonsense: the default; extremes: the range's ends.
        for nothing in [None, Some(0.0), Some(f64::NAN), Some(-1.0)] {
            assert_eq!(InputEncoding::fitted(d, nothing).difference_gain, DIFFERENCE_GAIN, "{nothing:?}");
        }
        assert_eq!(InputEncoding::fitted(d, Some(1e-6)).difference_gain, DIFFERENCE_GAIN_RANGE[1]);
        assert_eq!(InputEncoding::fitted(d, Some(0.5)).difference_gain, DIFFERENCE_GAIN_RANGE[0]);
        // The encoder applies the gain it was given.
        let reference = uniform([100, 100, 100]);
        let e = InputEncoding { channels: d, difference_gain: 10.0 };
        let x = InputEncoder::new(e, [4, 4], Some(&reference)).unwrap().encode(&uniform([110, 100, 100]));
        assert!((x[3 * 16] - 10.0 * 10.0 / 255.0).abs() < 1e-6);
        assert_eq!(InputEncoder::new(e, [4, 4], Some(&reference)).unwrap().encoding(), e);
    }
}
