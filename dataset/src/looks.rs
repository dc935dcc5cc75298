//! Random looks: the same unit's geometry seen through another build's lights, gel and camera.
//!
//! A network trained on one renderer's idea of a sensor learns that renderer's shading. Drawing
//! each sample's look from wide ranges (wider than [`SensorUnit::from_seed`]'s spread between
//! builds) makes the only thing shared by all samples the one a real gel shows too: where the
//! membrane is pressed, its shading changes against the unit's untouched frame. The geometry
//! (the fisheye, the crop) is kept: it is what labels are cast through.

use std::f64::consts::TAU;

use formats::SplitMix64;

use crate::unit::{Coating, SensorUnit};

/// The ranges each look is drawn from (uniform unless said otherwise).
///
/// - LEDs: each azimuth 120 degrees apart from its neighbours plus +-20 degrees of its own, the
///   whole ring turned by +-15 degrees; ring radius and height +-2.5 mm about the design's; a
///   primary colour with 0 to 35 % cross-talk into each other channel, the ring's tint 0.8 to
///   1.2 per channel, brightness 0.6 to 1.4; half-distance 14 to 32 mm (25 mm dome).
/// - coating: albedo 0.6 to 0.95, specular 0.03 to 0.45, shininess 8 to 50.
/// - gel: the saw-tooth shot's drape 0.1 to 1.5 mm. Contact frames shade the contact model's
///   solved surface, which depends on the indenter alone (not on the silicone's modulus).
/// - camera: exposure x0.7 to x1.35, vignetting 0.05 to 0.5, housing 0 to 20 grey levels,
///   ambient 2 to 20, read noise 0.5 to 4 grey levels, shot gain 0.005 to 0.08, blur 0.2 to 1.5
///   px, gamma 1 to 2.4; JPEG at quality 75 to 95 in half the looks, with 4:2:0 chroma in three
///   of four of those.
pub fn random_look(unit: &SensorUnit, seed: u64) -> SensorUnit {
    let mut rng = SplitMix64::for_item(seed, 0x100c_5eed);
    let mut look = unit.clone();
    let scale = unit.sensor.radius_mm / 25.0;
    let turn = rng.range(-15.0, 15.0);
    let tint: [f64; 3] = std::array::from_fn(|_| rng.range(0.8, 1.2));
    for (i, led) in look.leds.iter_mut().enumerate() {
        let azimuth = (i as f64 * 120.0 + turn + rng.range(-20.0, 20.0)).to_radians().rem_euclid(TAU);
        let ring = (21.0 + rng.range(-2.5, 2.5)) * scale;
        let z = (-2.0 + rng.range(-2.5, 2.5)) * scale;
        led.position_mm = [ring * azimuth.cos(), ring * azimuth.sin(), z];
        let brightness = rng.range(0.6, 1.4);
        led.colour_rgb = std::array::from_fn(|c| {
            let own = if c == i { 1.0 } else { rng.range(0.0, 0.35) };
            own * tint[c] * brightness
        });
        led.half_distance_mm = rng.range(14.0, 32.0) * scale;
    }
    look.coating =
        Coating { albedo: rng.range(0.6, 0.95), specular: rng.range(0.03, 0.45), shininess: rng.range(8.0, 50.0) };
    look.elastomer.drape_mm = rng.range(0.1, 1.5);
    let cam = &mut look.camera;
    cam.exposure = 520.0 * rng.range(0.7, 1.35);
    cam.vignetting = rng.range(0.05, 0.5);
    cam.housing_level = rng.range(0.0, 20.0);
    cam.ambient_level = rng.range(2.0, 20.0);
    cam.read_noise = rng.range(0.5, 4.0);
    cam.shot_gain = rng.range(0.005, 0.08);
    cam.blur_px = rng.range(0.2, 1.5);
    cam.gamma = rng.range(1.0, 2.4);
    let jpeg = rng.unit() < 0.5;
    let quality = rng.range(75.0, 95.0).round() as u8;
    let chroma_420 = rng.unit() < 0.75;
    cam.jpeg_quality = jpeg.then_some(quality);
    cam.chroma_420 = jpeg && chroma_420;
    look
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looks_keep_the_geometry_vary_the_rest_and_stay_valid() {
        let unit = SensorUnit::from_seed(3, 25.0);
        let mut exposures = Vec::new();
        let mut jpeg = 0;
        for seed in 0..200 {
            let look = random_look(&unit, seed);
            look.validate().unwrap_or_else(|e| panic!("look {seed}: {e}"));
            assert_eq!(look.sensor, unit.sensor, "the geometry is the unit's");
            assert_eq!(look.camera.lens_max_theta_rad, unit.camera.lens_max_theta_rad);
            assert_eq!(look, random_look(&unit, seed), "a seed always gives the same look");
            // Each LED's own channel stays its strongest: the colours still tell the LEDs apart.
            for (i, led) in look.leds.iter().enumerate() {
                let own = led.colour_rgb[i];
                for (c, &v) in led.colour_rgb.iter().enumerate().filter(|&(c, _)| c != i) {
                    assert!(v <= own * 0.35 * 1.2 / 0.8 + 1e-9, "look {seed} LED {i} channel {c}");
                }
            }
            exposures.push(look.camera.exposure);
            jpeg += usize::from(look.camera.jpeg_quality.is_some());
            assert!(!look.camera.chroma_420 || look.camera.jpeg_quality.is_some());
        }
        exposures.sort_by(f64::total_cmp);
        assert!(exposures[0] < 520.0 * 0.75 && exposures[199] > 520.0 * 1.3, "the range is covered");
        assert!((70..130).contains(&jpeg), "{jpeg} of 200 looks stream JPEG");
    }
}
