//! gelcam: a second image model of a DenseTact-style sensor, written apart from
//! `dataset::render` and different from it on purpose. It stands for the sensors this project
//! has not met: calibration, labelling, the contact gate and training are tested and measured on
//! its frames, and nothing anywhere is tuned to it.
//!
//! Where it differs from the renderer, by design:
//! - **lights**: 3 or 4 LEDs at drawn azimuths and heights, impure colours or white, each a
//!   cone-shaped emitter with inverse-square fall-off; tinted room light through the gel; glare;
//! - **membrane**: the rigid depth convolved with a Gaussian (0.5 to 3 px), where the renderer
//!   drapes one-sided from contact edges;
//! - **shading**: wrapped diffuse and a GGX lobe, normals from Sobel differences;
//! - **rim**: the coating fades out over a soft edge, with no dark housing ring;
//! - **lens**: lateral chromatic aberration, Gaussian point spread 0.3 to 1.5 px,
//!   `cos(theta / 2)^k` vignetting;
//! - **sensor**: an RGGB Bayer mosaic with bilinear demosaicing, shot noise from a full-well
//!   count, read noise, row noise and a fixed gain pattern;
//! - **encoding**: a power or sRGB tone curve, JPEG at quality 75 to 95 with 4:2:0 chroma.

#![deny(unsafe_code)]
// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod camera;
mod look;

use dataset::SawTooth;
use dataset::session::SessionCamera;
use sensor::Sensor;

pub use camera::Camera;
pub use look::{GelUnit, Light, Look, Rng, ToneCurve};

/// A gelcam unit ready to film sessions: one camera at one sample per pixel for frames, and the
/// saw-tooth shot supersampled.
pub struct GelSession {
    frames: Camera,
    indicator: SawTooth,
}

impl GelSession {
    pub fn new(unit: &GelUnit) -> Self {
        GelSession { frames: Camera::new(unit, 1), indicator: SawTooth::default() }
    }
}

/// The saw-tooth indicator's frame of `unit` (3 x 3 samples a pixel) as its stream writes it:
/// the file extension and bytes.
pub fn sawtooth_capture(unit: &GelUnit, indicator: &SawTooth, noise_seed: Option<u64>) -> (&'static str, Vec<u8>) {
    let camera = Camera::new(unit, 3);
    let radius = unit.sensor.radius_mm;
    let depth = camera.depth_from(|d| indicator.depth_mm(radius, d.as_vec3()));
    camera.encode(&camera.render(&depth, noise_seed))
}

/// The same frame as a reader decodes it.
pub fn sawtooth_frame(unit: &GelUnit, indicator: &SawTooth, noise_seed: Option<u64>) -> image::RgbImage {
    let (_, bytes) = sawtooth_capture(unit, indicator, noise_seed);
    image::load_from_memory(&bytes).expect("own frame decodes").to_rgb8()
}

impl SessionCamera for GelSession {
    fn sensor(&self) -> &Sensor {
        &self.frames.unit().sensor
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "gelcam": self.frames.unit() })
    }

    fn frame(&self, crop_depth_mm: &[f32], noise_seed: u64) -> (&'static str, Vec<u8>) {
        let depth = self.frames.depth_from_crop(crop_depth_mm);
        self.frames.encode(&self.frames.render(&depth, Some(noise_seed)))
    }

    fn reference(&self, noise_seed: u64) -> (&'static str, Vec<u8>) {
        let depth = self.frames.depth_from_crop(&vec![0.0; self.sensor().crop_len()]);
        self.frames.encode(&self.frames.render(&depth, Some(noise_seed)))
    }

    fn sawtooth(&self) -> (&'static str, Vec<u8>) {
        let unit = self.frames.unit();
        sawtooth_capture(unit, &self.indicator, Some(unit.seed ^ 0x5a17))
    }
}
