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
    /// R, G, B in [0, 1], then `DIFFERENCE_GAIN * (frame - reference)` for each of R, G, B.
    RgbDifference,
}

/// Scale of the difference channels: contact changes shading by a few tens of grey levels,
/// noise by one or two; four times the difference puts contact near the RGB channels' range.
pub const DIFFERENCE_GAIN: f32 = 4.0;

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

    /// The bundle's `input_encoding` text for these channels.
    pub fn encoding(self) -> &'static str {
        match self {
            InputChannels::Rgb => "rgb/255",
            InputChannels::RgbDifference => "rgb/255,4*(rgb-reference)/255",
        }
    }

    /// The channels whose [`encoding`](Self::encoding) is `text`.
    pub fn from_encoding(text: &str) -> Option<Self> {
        [InputChannels::Rgb, InputChannels::RgbDifference].into_iter().find(|c| c.encoding() == text)
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
    channels: InputChannels,
    hw: [usize; 2],
    /// The reference frame's R, G, B planes, when the channels use it.
    reference: Option<Vec<f32>>,
}

impl InputEncoder {
    /// An encoder for `channels` at `hw`; `reference` (the unit's no-contact crop) must be given
    /// when the channels use it, and is ignored otherwise.
    pub fn new(channels: InputChannels, hw: [usize; 2], reference: Option<&RgbImage>) -> Result<Self, InputError> {
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
        Ok(InputEncoder { channels, hw, reference })
    }

    pub fn channels(&self) -> InputChannels {
        self.channels
    }

    pub fn hw(&self) -> [usize; 2] {
        self.hw
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
            let difference: Vec<f32> = planes.iter().zip(reference).map(|(a, b)| DIFFERENCE_GAIN * (a - b)).collect();
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

    #[test]
    fn planes_are_red_green_blue_in_that_order() {
        let x = rgb_planes(&uniform([255, 51, 0]), [8, 8]);
        assert_eq!((x[0], x[64], x[128]), (1.0, 0.2, 0.0));
        assert_eq!(x.len(), 3 * 64);
    }

    #[test]
    fn difference_channels_follow_the_rgb_ones_and_vanish_on_the_reference() {
        let reference = uniform([100, 100, 100]);
        let enc = InputEncoder::new(InputChannels::RgbDifference, [8, 16], Some(&reference)).unwrap();
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
        assert!(InputEncoder::new(InputChannels::Rgb, [8, 8], None).is_ok());
        let e = InputEncoder::new(InputChannels::RgbDifference, [8, 8], None).unwrap_err().to_string();
        assert!(e.contains("reference frame"), "{e}");
        for c in [InputChannels::Rgb, InputChannels::RgbDifference] {
            assert_eq!(InputChannels::from_encoding(c.encoding()), Some(c));
            assert_eq!(c.name().parse::<InputChannels>(), Ok(c));
        }
        let e = "bgr".parse::<InputChannels>().unwrap_err().to_string();
        assert!(e.contains("rgb, rgb-difference"), "{e}");
    }
}
