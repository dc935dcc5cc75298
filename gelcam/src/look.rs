//! What one gelcam unit looks like: its geometry, lights, coating, lens, sensor and encoding,
//! drawn from a seed by gelcam's own generator and ranges (none shared with `dataset::unit`).

use std::f64::consts::{FRAC_PI_2, TAU};

use sensor::{Correspondence, RadialMap, Sensor};
use serde::{Deserialize, Serialize};

/// gelcam's own random stream (xorshift64*), so that nothing here shares a draw with the
/// renderer's SplitMix64 streams.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng((seed ^ 0xd1b5_4a32_d192_ed03).wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Standard normal (Marsaglia's polar method).
    pub fn gauss(&mut self) -> f64 {
        loop {
            let (a, b) = (self.uniform(-1.0, 1.0), self.uniform(-1.0, 1.0));
            let s = a * a + b * b;
            if s > 0.0 && s < 1.0 {
                return a * (-2.0 * s.ln() / s).sqrt();
            }
        }
    }

    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform(0.0, 1.0) < p
    }
}

/// One LED: a cone-shaped emitter pointing up into the dome, with inverse-square fall-off.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    pub position_mm: [f64; 3],
    /// Linear RGB the camera records of it (impure colours, white, tints).
    pub rgb: [f64; 3],
    /// Emission `cos(angle off +z)^m`.
    pub cone_exponent: f64,
}

/// The camera's encoding curve from linear light to 8 bits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ToneCurve {
    Power { gamma: f64 },
    Srgb,
}

impl ToneCurve {
    /// Encodes a linear level in `[0, 1]`.
    pub fn encode(self, x: f64) -> f64 {
        let x = x.clamp(0.0, 1.0);
        match self {
            ToneCurve::Power { gamma } => x.powf(1.0 / gamma),
            ToneCurve::Srgb if x <= 0.003_130_8 => 12.92 * x,
            ToneCurve::Srgb => 1.055 * x.powf(1.0 / 2.4) - 0.055,
        }
    }
}

/// Everything of a unit but its geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Look {
    pub lights: Vec<Light>,
    /// Room light leaking through the gel, linear RGB relative to the LEDs' scale.
    pub ambient_rgb: [f64; 3],
    /// The coating's colour (linear reflectance per channel).
    pub albedo_rgb: [f64; 3],
    /// Wrapped diffuse: `(n.l + w) / (1 + w)`, a coating that scatters below its surface.
    pub wrap: f64,
    /// GGX specular lobe: weight and roughness.
    pub specular: f64,
    pub roughness: f64,
    /// Vignetting `cos(theta / 2)^k`.
    pub vignetting_power: f64,
    /// The membrane: the rigid depth convolved with a Gaussian of this sigma (frame pixels).
    pub membrane_sigma_px: f64,
    /// The coating ends at 90 degrees over a logistic edge of this width (degrees).
    pub rim_soft_deg: f64,
    /// Veiling glare: this fraction of the disk's mean level everywhere inside the lens' circle.
    pub flare: f64,
    /// Lateral chromatic aberration: red magnified by this many pixels at the rim, blue shrunk
    /// by `chromatic_blue` times as much.
    pub chromatic_px: f64,
    pub chromatic_blue: f64,
    /// Lens point spread: Gaussian sigma (pixels).
    pub blur_px: f64,
    /// Linear level (0..1 of full scale) of the no-contact frame's 99th percentile.
    pub white_level: f64,
    /// Sensor: electrons at full scale (shot noise), read noise and per-row offsets (grey
    /// levels, linear), per-pixel gain spread (PRNU).
    pub full_well_e: f64,
    pub read_noise_dn: f64,
    pub row_noise_dn: f64,
    pub prnu: f64,
    /// Multiplies every noise (1: the unit's own).
    pub noise_scale: f64,
    pub tone: ToneCurve,
    /// JPEG quality of the camera's stream, always with 4:2:0 chroma; `None`: PNG.
    pub jpeg_quality: Option<u8>,
}

/// A gelcam unit: the true geometry (what calibration should recover) and its look.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GelUnit {
    pub seed: u64,
    pub sensor: Sensor,
    pub look: Look,
}

/// Hue (turns) to a linear RGB of the given saturation.
fn hue_rgb(hue: f64, saturation: f64) -> [f64; 3] {
    let c = |offset: f64| {
        let x = (hue - offset).rem_euclid(1.0);
        let d = x.min(1.0 - x) * 3.0;
        (1.0 - d).clamp(0.0, 1.0)
    };
    let pure = [c(0.0), c(1.0 / 3.0), c(2.0 / 3.0)];
    pure.map(|p| (1.0 - saturation) + saturation * p)
}

impl GelUnit {
    /// A unit drawn from `seed` with every part of its look varied.
    pub fn from_seed(seed: u64, radius_mm: f64) -> Self {
        let mut rng = Rng::new(seed);
        let mut sensor = Sensor::with_radius(radius_mm);
        let centre = (399.5 + rng.uniform(-10.0, 10.0), 299.5 + rng.uniform(-8.0, 8.0));
        let rim_px = rng.uniform(262.0, 282.0);
        for _ in 0..200 {
            let k = [rng.uniform(-0.04, 0.04), rng.uniform(-0.006, 0.006), rng.uniform(-0.001, 0.001), 0.0];
            let t = FRAC_PI_2;
            let poly = t * (1.0 + t * t * (k[0] + t * t * (k[1] + t * t * k[2])));
            sensor.correspondence = Correspondence {
                centre_u_px: centre.0,
                centre_v_px: centre.1,
                radial: RadialMap::KannalaBrandt { focal_px_per_rad: rim_px / poly, k },
            };
            if sensor.validate().is_ok() {
                break;
            }
        }
        let scale = radius_mm / 25.0;
        let count = if rng.chance(1.0 / 3.0) { 4 } else { 3 };
        let start = rng.uniform(0.0, TAU);
        let hue0 = rng.uniform(0.0, 1.0);
        let white = rng.chance(0.25).then(|| rng.uniform(0.0, count as f64) as usize);
        let lights = (0..count)
            .map(|i| {
                let azimuth = start + i as f64 * TAU / count as f64 + rng.uniform(-0.25, 0.25);
                let ring = rng.uniform(18.0, 22.5) * scale;
                let z = rng.uniform(-4.0, 1.0) * scale;
                let rgb = if white == Some(i) {
                    [rng.uniform(0.85, 1.0), rng.uniform(0.85, 1.0), rng.uniform(0.8, 1.0)]
                } else {
                    let hue = hue0 + i as f64 / count as f64 + rng.uniform(-0.06, 0.06);
                    hue_rgb(hue, rng.uniform(0.45, 0.95)).map(|c| c * rng.uniform(0.8, 1.2))
                };
                Light {
                    position_mm: [ring * azimuth.cos(), ring * azimuth.sin(), z],
                    rgb,
                    cone_exponent: rng.uniform(0.3, 1.5),
                }
            })
            .collect();
        let tint = [rng.uniform(0.8, 1.0), rng.uniform(0.8, 1.0), rng.uniform(0.8, 1.0)];
        let ambient = rng.uniform(0.0, 0.12);
        let look = Look {
            lights,
            ambient_rgb: hue_rgb(rng.uniform(0.0, 1.0), rng.uniform(0.0, 0.3)).map(|c| c * ambient),
            albedo_rgb: tint,
            wrap: rng.uniform(0.0, 0.4),
            specular: rng.uniform(0.0, 0.6),
            roughness: rng.uniform(0.25, 0.6),
            vignetting_power: rng.uniform(1.0, 4.0),
            membrane_sigma_px: rng.uniform(0.5, 3.0),
            rim_soft_deg: rng.uniform(0.3, 1.5),
            flare: rng.uniform(0.0, 0.04),
            chromatic_px: rng.uniform(0.0, 0.8),
            chromatic_blue: rng.uniform(0.3, 1.0),
            blur_px: rng.uniform(0.3, 1.5),
            white_level: rng.uniform(0.6, 0.92),
            full_well_e: rng.uniform(2500.0, 12000.0),
            read_noise_dn: rng.uniform(0.4, 2.0),
            row_noise_dn: rng.uniform(0.0, 0.8),
            prnu: rng.uniform(0.002, 0.012),
            noise_scale: 1.0,
            tone: if rng.chance(1.0 / 3.0) {
                ToneCurve::Srgb
            } else {
                ToneCurve::Power { gamma: rng.uniform(1.0, 2.2) }
            },
            jpeg_quality: rng.chance(0.5).then(|| rng.uniform(75.0, 95.99) as u8),
        };
        GelUnit { seed, sensor, look }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drawn_units_are_valid_reproducible_and_varied() {
        let mut sigmas = Vec::new();
        for seed in 0..40 {
            let unit = GelUnit::from_seed(seed, 25.0);
            unit.sensor.validate().unwrap_or_else(|e| panic!("unit {seed}: {e}"));
            assert_eq!(unit, GelUnit::from_seed(seed, 25.0));
            let rim = unit.sensor.correspondence.radial.radius_of_theta(FRAC_PI_2).unwrap();
            assert!((262.0..=282.0 + 1e-6).contains(&rim), "unit {seed}: rim {rim}");
            assert!(matches!(unit.look.lights.len(), 3 | 4));
            sigmas.push(unit.look.membrane_sigma_px);
        }
        let (lo, hi) = sigmas.iter().fold((f64::MAX, 0f64), |(a, b), &s| (a.min(s), b.max(s)));
        assert!(lo < 1.0 && hi > 2.5, "membrane smoothing spans its range: {lo}..{hi}");
    }

    #[test]
    fn tone_curves_are_monotone_and_span_the_range() {
        for tone in [ToneCurve::Srgb, ToneCurve::Power { gamma: 1.0 }, ToneCurve::Power { gamma: 2.2 }] {
            assert_eq!(tone.encode(0.0), 0.0);
            assert!((tone.encode(1.0) - 1.0).abs() < 1e-9);
            let v: Vec<f64> = (0..=100).map(|i| tone.encode(i as f64 / 100.0)).collect();
            assert!(v.windows(2).all(|w| w[1] > w[0]), "{tone:?}");
        }
    }
}
