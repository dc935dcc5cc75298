//! Simulated sensor units: what differs between two physical builds of the same design.
//!
//! Every DenseTact is hand-assembled: the camera sits a little off the dome's axis, lenses differ
//! in scale and distortion, LEDs are soldered at slightly different places and brightnesses, the
//! coating is sprayed thicker or thinner. A model trained on one unit sees another unit's images
//! as shifted colours and a warped geometry; [`SensorUnit::from_seed`] draws such a unit.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec3;
use sensor::{Correspondence, RadialMap, Sensor};
use serde::{Deserialize, Serialize};

use formats::SplitMix64;

use crate::mechanics::Material;

/// Format version of `unit.json` (2: the elastomer's drape and the camera's response, blur and
/// compression; 3: the elastomer's Young's modulus and Poisson's ratio; 4: contact frames shade
/// the contact model's solved surface, the drape is the saw-tooth shot's alone).
pub const UNIT_FORMAT_VERSION: u32 = 4;

/// One lit LED: a point light with a soft fall-off (the LEDs sit behind a diffuser).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Led {
    /// Position in the sensor frame (mm): on the ring at the dome's base.
    pub position_mm: [f64; 3],
    /// What the camera's R, G and B channels record of this LED's light (colour balance and
    /// cross-talk between channels), relative units.
    pub colour_rgb: [f64; 3],
    /// Distance (mm) at which the fall-off has halved the light: `1 / (1 + (d / d_half)^2)`.
    pub half_distance_mm: f64,
}

/// The reflective coating seen through the silicone: Lambertian plus a Blinn-Phong lobe.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coating {
    pub albedo: f64,
    pub specular: f64,
    pub shininess: f64,
}

/// The silicone between the indenter and the coating. What the camera shades is the membrane:
/// the surface the contact model solves (`mechanics::Contact::sink_mm`), which the indenter
/// pushes in where it touches and which sags around the contact, bridging what the gel cannot
/// follow; the ground truth stays the rigid indenter's ray-cast depth, as in the paper.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Elastomer {
    /// The saw-tooth calibration shot's membrane only: beyond each tooth's drop it falls off as
    /// `exp(-distance / drape_mm)` from the tip's depth (mm along the surface). The shot does
    /// not shade the solved surface because the calibration does not yet read its bridge
    /// (`SawToothShot::solved_membrane`).
    pub drape_mm: f64,
    /// Young's modulus (MPa) of the cured silicone; absent in older `unit.json`: the paper's
    /// estimate ([`Material::PAPER`]). A 20:1 mix cured a little warmer or longer is stiffer.
    /// It sets the pressure labels; the shaded surface does not depend on it.
    #[serde(default = "paper_modulus")]
    pub youngs_modulus_mpa: f64,
    /// Poisson's ratio (nearly incompressible silicone); absent in older files: the paper's.
    #[serde(default = "paper_poisson")]
    pub poisson_ratio: f64,
    /// The first image model's membrane: it follows the indenter exactly (no solved surface).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rigid_membrane: bool,
}

fn paper_modulus() -> f64 {
    Material::PAPER.youngs_modulus_mpa
}

fn paper_poisson() -> f64 {
    Material::PAPER.poisson_ratio
}

impl Elastomer {
    /// The material the contact model solves with.
    pub fn material(&self) -> Material {
        Material { youngs_modulus_mpa: self.youngs_modulus_mpa, poisson_ratio: self.poisson_ratio }
    }
}

/// Camera response: exposure, vignetting, optics, noise and encoding (8-bit grey levels).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Grey levels per unit of shaded radiance.
    pub exposure: f64,
    /// Fraction of light lost at the useful disk's rim: `1 - v (theta / theta_max)^2`.
    pub vignetting: f64,
    /// Largest polar angle the lens sees (a 185-degree fisheye sees 92.5 degrees).
    pub lens_max_theta_rad: f64,
    /// Grey level of the dark housing seen between the elastomer's rim and the lens' edge.
    pub housing_level: f64,
    /// Constant light (scatter inside the silicone), grey levels.
    pub ambient_level: f64,
    /// Read noise, grey levels (standard deviation).
    pub read_noise: f64,
    /// Shot noise: variance grows by this many grey levels squared per grey level of signal.
    pub shot_gain: f64,
    /// Lens blur: standard deviation (crop pixels) of a Gaussian point spread. 0: sharp.
    pub blur_px: f64,
    /// Encoding gamma: a linear level `v` is recorded as `255 (v / 255)^(1 / gamma)`, after the
    /// noise (which arises in the linear sensor). 1: linear.
    pub gamma: f64,
    /// JPEG quality of the camera's stream (a USB camera's MJPEG); `None`: uncompressed frames.
    pub jpeg_quality: Option<u8>,
    /// Whether the JPEG stream keeps one chroma sample per 2x2 pixels (4:2:0, most cameras'
    /// MJPEG) rather than one per pixel (4:4:4). Absent in older `unit.json`: 4:4:4.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub chroma_420: bool,
}

/// A physical sensor unit: its true geometry and its optics and lighting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorUnit {
    pub format_version: u32,
    /// The seed that drew this unit; `None` for the nominal unit.
    pub seed: Option<u64>,
    /// True geometry and correspondence (what calibration tries to recover).
    pub sensor: Sensor,
    /// Red, green and blue LEDs, in that order.
    pub leds: [Led; 3],
    pub coating: Coating,
    pub elastomer: Elastomer,
    pub camera: Camera,
}

/// Nominal LED ring: radius and height of the lit LEDs (mm), for a 25 mm dome.
const LED_RING_RADIUS_MM: f64 = 21.0;
const LED_RING_Z_MM: f64 = -2.0;

impl SensorUnit {
    /// The design's nominal unit: centred ideal fisheye, LEDs 120 degrees apart (red at +x).
    pub fn nominal(sensor: Sensor) -> Self {
        let scale = sensor.radius_mm / 25.0;
        let led = |azimuth_deg: f64, colour_rgb: [f64; 3]| {
            let a = azimuth_deg.to_radians();
            Led {
                position_mm: [
                    LED_RING_RADIUS_MM * scale * a.cos(),
                    LED_RING_RADIUS_MM * scale * a.sin(),
                    LED_RING_Z_MM * scale,
                ],
                colour_rgb,
                half_distance_mm: 20.0 * scale,
            }
        };
        SensorUnit {
            format_version: UNIT_FORMAT_VERSION,
            seed: None,
            sensor,
            leds: [led(0.0, [1.0, 0.06, 0.03]), led(120.0, [0.05, 0.9, 0.08]), led(240.0, [0.03, 0.08, 1.1])],
            coating: Coating { albedo: 0.8, specular: 0.25, shininess: 20.0 },
            elastomer: Elastomer {
                drape_mm: 0.5,
                rigid_membrane: false,
                youngs_modulus_mpa: Material::PAPER.youngs_modulus_mpa,
                poisson_ratio: Material::PAPER.poisson_ratio,
            },
            camera: Camera {
                exposure: 520.0,
                vignetting: 0.3,
                lens_max_theta_rad: 92.5f64.to_radians(),
                housing_level: 10.0,
                ambient_level: 8.0,
                read_noise: 1.5,
                shot_gain: 0.03,
                blur_px: 0.5,
                gamma: 1.0,
                jpeg_quality: None,
                chroma_420: false,
            },
        }
    }

    /// A unit drawn from `seed`: every build-to-build difference varied within plausible bounds.
    /// Its fisheye keeps the useful disk inside the crop, as a real build is adjusted to.
    pub fn from_seed(seed: u64, radius_mm: f64) -> Self {
        let mut rng = SplitMix64::for_item(seed, 0x005e_1150_a417_u64);
        let mut unit = SensorUnit::nominal(Sensor::with_radius(radius_mm));
        unit.seed = Some(seed);
        let mut vary = |lo: f64, hi: f64| rng.range(lo, hi);

        let s = &mut unit.sensor;
        s.correspondence = Correspondence {
            centre_u_px: 399.5 + vary(-8.0, 8.0),
            centre_v_px: 299.5 + vary(-6.0, 6.0),
            radial: RadialMap::Equidistant { focal_px_per_rad: 1.0 },
        };
        // Distortion drawn until the lens stays monotone out to the crop's corners; the focal
        // length puts the rim (90 degrees) 268..284 px from the centre.
        let rim_px = vary(268.0, 284.0);
        for _ in 0..100 {
            let k = [vary(-0.03, 0.03), vary(-0.005, 0.005), 0.0, 0.0];
            let poly = FRAC_PI_2 * (1.0 + FRAC_PI_2.powi(2) * (k[0] + FRAC_PI_2.powi(2) * k[1]));
            s.correspondence.radial = RadialMap::KannalaBrandt { focal_px_per_rad: rim_px / poly, k };
            if s.validate().is_ok() {
                break;
            }
        }

        for (i, led) in unit.leds.iter_mut().enumerate() {
            let scale = radius_mm / 25.0;
            let azimuth = (i as f64 * 120.0 + vary(-8.0, 8.0)).to_radians();
            let ring = (LED_RING_RADIUS_MM + vary(-1.0, 1.0)) * scale;
            let z = (LED_RING_Z_MM + vary(-0.8, 0.8)) * scale;
            led.position_mm = [ring * azimuth.cos(), ring * azimuth.sin(), z];
            let gain = vary(0.85, 1.15);
            for c in &mut led.colour_rgb {
                *c *= gain * vary(0.92, 1.08);
            }
        }
        unit.coating = Coating { albedo: vary(0.7, 0.9), specular: vary(0.1, 0.35), shininess: vary(12.0, 35.0) };
        let cam = &mut unit.camera;
        cam.exposure *= vary(0.9, 1.1);
        cam.vignetting = vary(0.15, 0.4);
        cam.housing_level = vary(5.0, 15.0);
        cam.ambient_level = vary(4.0, 12.0);
        cam.read_noise = vary(0.8, 2.5);
        cam.shot_gain = vary(0.01, 0.05);
        // Drawn after everything above, so that the units of earlier versions keep their
        // geometry, lights and noise.
        unit.elastomer.drape_mm = vary(0.25, 1.0);
        let cam = &mut unit.camera;
        cam.blur_px = vary(0.3, 1.0);
        cam.gamma = vary(1.0, 2.2);
        // One unit in three streams JPEG.
        cam.jpeg_quality = (vary(0.0, 1.0) < 1.0 / 3.0).then(|| vary(80.0, 95.0).round() as u8);
        // Drawn last again (format 3): the material, within 20 % of the paper's modulus.
        unit.elastomer.youngs_modulus_mpa = Material::PAPER.youngs_modulus_mpa * vary(0.8, 1.2);
        unit.elastomer.poisson_ratio = vary(0.46, 0.495);
        unit
    }

    /// The same unit seen through the first image model (`formats::dataset::IMAGE_MODEL` 1): the
    /// membrane follows the indenter, through a sharp, linear camera without JPEG.
    pub fn with_first_image_model(&self) -> Self {
        let mut unit = self.clone();
        unit.elastomer.rigid_membrane = true;
        unit.elastomer.drape_mm = 0.0;
        unit.camera = Camera { blur_px: 0.0, gamma: 1.0, jpeg_quality: None, ..unit.camera };
        unit
    }

    /// Checks the unit's numbers; the error says which is wrong.
    pub fn validate(&self) -> Result<(), UnitError> {
        self.sensor.validate()?;
        let c = &self.camera;
        let finite_nonneg = |name: &'static str, value: f64| {
            if value.is_finite() && value >= 0.0 { Ok(()) } else { Err(UnitError::Negative { name, value }) }
        };
        finite_nonneg("camera.exposure", c.exposure)?;
        finite_nonneg("camera.vignetting", c.vignetting)?;
        finite_nonneg("camera.read_noise", c.read_noise)?;
        finite_nonneg("camera.shot_gain", c.shot_gain)?;
        finite_nonneg("coating.albedo", self.coating.albedo)?;
        finite_nonneg("coating.specular", self.coating.specular)?;
        finite_nonneg("elastomer.drape_mm", self.elastomer.drape_mm)?;
        self.elastomer.material().validate().map_err(|e| UnitError::Material(e.to_string()))?;
        finite_nonneg("camera.blur_px", c.blur_px)?;
        if !(c.gamma.is_finite() && (0.2..=5.0).contains(&c.gamma)) {
            return Err(UnitError::Gamma(c.gamma));
        }
        if let Some(q) = c.jpeg_quality
            && !(1..=100).contains(&q)
        {
            return Err(UnitError::JpegQuality(q));
        }
        if !(c.lens_max_theta_rad > self.sensor.max_theta_rad && c.lens_max_theta_rad < PI) {
            return Err(UnitError::LensField(c.lens_max_theta_rad));
        }
        for (i, led) in self.leds.iter().enumerate() {
            if DVec3::from(led.position_mm).length() >= self.sensor.radius_mm || !(led.half_distance_mm > 0.0) {
                return Err(UnitError::Led(i));
            }
        }
        Ok(())
    }
}

/// Why a simulated unit's description is refused.
#[derive(Debug, thiserror::Error)]
pub enum UnitError {
    #[error(transparent)]
    Sensor(#[from] sensor::SensorError),
    #[error("{name} must be a finite number >= 0, got {value}")]
    Negative { name: &'static str, value: f64 },
    #[error("camera.gamma must be in 0.2..=5, got {0}")]
    Gamma(f64),
    #[error("camera.jpeg_quality must be in 1..=100, got {0}")]
    JpegQuality(u8),
    #[error("camera.lens_max_theta_rad must exceed the sensor's max_theta_rad and stay below pi, got {0}")]
    LensField(f64),
    #[error("LED {0} must sit inside the dome with a positive half distance")]
    Led(usize),
    #[error("{0}")]
    Material(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_differ_and_stay_valid() {
        let nominal = SensorUnit::nominal(Sensor::default());
        nominal.validate().unwrap();
        let mut centres = Vec::new();
        for seed in 0..50 {
            let unit = SensorUnit::from_seed(seed, 25.0);
            unit.validate().unwrap_or_else(|e| panic!("unit {seed}: {e}"));
            assert_eq!(unit, SensorUnit::from_seed(seed, 25.0), "a seed always gives the same unit");
            let radial = &unit.sensor.correspondence.radial;
            let rim = radial.radius_of_theta(FRAC_PI_2).unwrap();
            assert!((268.0..=284.0 + 1e-9).contains(&rim), "unit {seed}: rim at {rim} px");
            // The useful disk stays inside the crop.
            let n = unit.sensor.crop_size_px as usize;
            let mask = unit.sensor.valid_mask();
            assert!(!mask[0] && !mask[n - 1] && !mask[n * n - 1]);
            centres.push(unit.sensor.correspondence.centre_u_px);
        }
        centres.sort_by(f64::total_cmp);
        centres.dedup();
        assert_eq!(centres.len(), 50);
    }
}
