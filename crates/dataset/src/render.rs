//! The camera image a sensor unit would record of a pressed surface.
//!
//! Each pixel sees the coating at `(R - depth) * dir` along its true ray. Surface normals come
//! from central differences of those points over the pixel grid, so they follow the depth map's
//! own resolution. The three LEDs light the coating (Lambert plus a Blinn-Phong lobe); because
//! they stand at different azimuths, a surface tilted towards one LED turns that LED's colour,
//! which is how the real sensor encodes the normal in colour. Vignetting, the housing beyond the
//! elastomer's rim and sensor noise follow; the result is 8-bit RGB.
//!
//! Only what changes is shaded: the no-contact image of the unit is cached, and a frame re-shades
//! just the pixels whose depth (or a neighbour's, through the normal) differs from zero.

use glam::Vec3;
use image::RgbImage;
use sensor::Sensor;

use crate::rng::SplitMix64;
use crate::unit::SensorUnit;

/// A regular grid of sample points in frame pixel coordinates (pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelGrid {
    pub origin_u_px: f64,
    pub origin_v_px: f64,
    pub step_px: f64,
    pub width: u32,
    pub height: u32,
}

impl PixelGrid {
    /// The sensor's square crop, one sample per pixel.
    pub fn crop(sensor: &Sensor) -> Self {
        let (u, v) = sensor.crop_to_frame(0, 0);
        PixelGrid {
            origin_u_px: u,
            origin_v_px: v,
            step_px: 1.0,
            width: sensor.crop_size_px,
            height: sensor.crop_size_px,
        }
    }

    /// The whole camera frame with `samples`^2 samples per pixel (for antialiased images).
    pub fn frame(sensor: &Sensor, samples: u32) -> Self {
        let step = 1.0 / samples as f64;
        PixelGrid {
            origin_u_px: -0.5 + step / 2.0,
            origin_v_px: -0.5 + step / 2.0,
            step_px: step,
            width: sensor.frame_width_px * samples,
            height: sensor.frame_height_px * samples,
        }
    }

    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn point(&self, i: usize) -> (f64, f64) {
        let (x, y) = (i % self.width as usize, i / self.width as usize);
        (self.origin_u_px + x as f64 * self.step_px, self.origin_v_px + y as f64 * self.step_px)
    }
}

/// What a sample point sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Seen {
    /// Beyond the lens' field: black.
    Nothing,
    /// Between the elastomer's rim and the lens' edge: the dark housing.
    Housing,
    /// The coated elastomer.
    Elastomer,
}

/// Linear grey levels (before noise and quantisation), RGB per sample point.
pub type Radiance = Vec<[f32; 3]>;

/// Renders images of one unit on one pixel grid; build once, render many frames.
pub struct Renderer {
    unit: SensorUnit,
    grid: PixelGrid,
    dirs: Vec<Vec3>,
    seen: Vec<Seen>,
    vignette: Vec<f32>,
    reference: Radiance,
}

impl Renderer {
    pub fn new(unit: &SensorUnit, grid: PixelGrid) -> Self {
        let (mut dirs, mut seen, mut vignette) = (Vec::new(), Vec::new(), Vec::new());
        let s = &unit.sensor;
        for i in 0..grid.len() {
            let (u, v) = grid.point(i);
            let hit = s.correspondence.direction(u, v);
            let (dir, theta) = hit.map_or((Vec3::ZERO, f64::INFINITY), |(d, t)| (d.as_vec3(), t));
            seen.push(if theta <= s.max_theta_rad {
                Seen::Elastomer
            } else if theta <= unit.camera.lens_max_theta_rad {
                Seen::Housing
            } else {
                Seen::Nothing
            });
            dirs.push(dir);
            let t = (theta.min(unit.camera.lens_max_theta_rad) / s.max_theta_rad) as f32;
            vignette.push((1.0 - unit.camera.vignetting as f32 * t * t).max(0.0));
        }
        let mut renderer = Renderer { unit: unit.clone(), grid, dirs, seen, vignette, reference: Vec::new() };
        let zeros = vec![0.0; grid.len()];
        renderer.reference = (0..grid.len()).map(|i| renderer.shade_at(&zeros, i)).collect();
        renderer
    }

    /// Renderer for the crop of `sensor`, which must be the unit's own geometry.
    pub fn for_crop(unit: &SensorUnit) -> Self {
        Renderer::new(unit, PixelGrid::crop(&unit.sensor))
    }

    pub fn grid(&self) -> &PixelGrid {
        &self.grid
    }

    pub fn unit(&self) -> &SensorUnit {
        &self.unit
    }

    /// Unit ray direction of every sample point (zero beyond the lens).
    pub fn directions(&self) -> &[Vec3] {
        &self.dirs
    }

    /// The no-contact image before noise.
    pub fn reference(&self) -> &Radiance {
        &self.reference
    }

    /// Radiance of a frame with `depth_mm` per sample point: the reference, with every sample
    /// whose normal the depth changes shaded again. Returns the radiance and how many samples
    /// were shaded.
    pub fn radiance(&self, depth_mm: &[f32]) -> (Radiance, usize) {
        assert_eq!(depth_mm.len(), self.grid.len(), "depth map does not match the render grid");
        let (w, h) = (self.grid.width as usize, self.grid.height as usize);
        let mut out = self.reference.clone();
        let mut dirty = vec![false; w * h];
        for (i, &d) in depth_mm.iter().enumerate() {
            if d != 0.0 {
                let (x, y) = (i % w, i / w);
                dirty[i] = true;
                if x > 0 {
                    dirty[i - 1] = true;
                }
                if x + 1 < w {
                    dirty[i + 1] = true;
                }
                if y > 0 {
                    dirty[i - w] = true;
                }
                if y + 1 < h {
                    dirty[i + w] = true;
                }
            }
        }
        let mut shaded = 0;
        for (i, px) in out.iter_mut().enumerate() {
            if dirty[i] {
                *px = self.shade_at(depth_mm, i);
                shaded += 1;
            }
        }
        (out, shaded)
    }

    /// Radiance of sample `i` given the whole grid's depth.
    fn shade_at(&self, depth_mm: &[f32], i: usize) -> [f32; 3] {
        let cam = &self.unit.camera;
        let v = self.vignette[i];
        match self.seen[i] {
            Seen::Nothing => return [0.0; 3],
            Seen::Housing => return [cam.housing_level as f32 * v; 3],
            Seen::Elastomer => {}
        }
        let radius = self.unit.sensor.radius_mm as f32;
        let w = self.grid.width as usize;
        let (x, y) = (i % w, i / w);
        // A neighbour that does not see the elastomer is replaced by the sample itself
        // (a one-sided difference).
        let point = |j: usize| -> Vec3 {
            let j = if self.seen[j] == Seen::Elastomer { j } else { i };
            self.dirs[j] * (radius - depth_mm[j])
        };
        let left = point(if x > 0 { i - 1 } else { i });
        let right = point(if x + 1 < w { i + 1 } else { i });
        let up = point(if y > 0 { i - w } else { i });
        let down = point(if y + 1 < self.grid.height as usize { i + w } else { i });
        let p = point(i);
        let mut normal = (right - left).cross(down - up).normalize_or_zero();
        // The camera sees the coating from inside: the normal faces the centre.
        if normal.dot(p) > 0.0 {
            normal = -normal;
        }
        if normal == Vec3::ZERO {
            normal = -p.normalize_or_zero();
        }
        let shade = shade_point(&self.unit, p, normal);
        let ambient = cam.ambient_level as f32;
        shade.map(|c| (c * cam.exposure as f32 + ambient) * v)
    }

    /// Noise-free 8-bit image of a radiance on this grid (`samples`^2 samples averaged per pixel).
    pub fn to_image(&self, radiance: &Radiance, samples: u32, noise_seed: Option<u64>) -> RgbImage {
        let s = samples as usize;
        let (w, h) = (self.grid.width / samples, self.grid.height / samples);
        let mut img = RgbImage::new(w, h);
        let mut noise = noise_seed.map(|seed| GaussianNoise::new(seed, &self.unit));
        let gw = self.grid.width as usize;
        let norm = 1.0 / (s * s) as f32;
        for (idx, px) in img.pixels_mut().enumerate() {
            let (x, y) = (idx % w as usize, idx / w as usize);
            let mut sum = [0f32; 3];
            for sy in 0..s {
                let row = (y * s + sy) * gw + x * s;
                for sample in &radiance[row..row + s] {
                    for c in 0..3 {
                        sum[c] += sample[c];
                    }
                }
            }
            for c in 0..3 {
                let mut value = sum[c] * norm;
                if let Some(noise) = &mut noise {
                    value += noise.sample(value);
                }
                px.0[c] = value.round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    }

    /// The unit's no-contact image on this grid, without noise.
    pub fn reference_image(&self, samples: u32) -> RgbImage {
        self.to_image(&self.reference, samples, None)
    }

    /// One frame (one sample per pixel) with noise drawn from `noise_seed` (`None`: no noise).
    pub fn render(&self, depth_mm: &[f32], noise_seed: Option<u64>) -> RgbImage {
        let (radiance, _) = self.radiance(depth_mm);
        self.to_image(&radiance, 1, noise_seed)
    }
}

/// Light reflected towards the camera at the centre from point `p` (sensor frame, mm) with
/// inward unit normal `n`: per channel, before exposure.
pub fn shade_point(unit: &SensorUnit, p: Vec3, n: Vec3) -> [f32; 3] {
    let view = (-p).normalize_or_zero();
    let coating = &unit.coating;
    let mut out = [0f32; 3];
    for led in &unit.leds {
        let to_led = Vec3::from(led.position_mm.map(|c| c as f32)) - p;
        let dist2 = to_led.length_squared();
        let l = to_led / dist2.sqrt();
        let lambert = n.dot(l);
        if lambert <= 0.0 {
            continue;
        }
        let half = (l + view).normalize_or_zero();
        let spec = coating.specular as f32 * n.dot(half).max(0.0).powf(coating.shininess as f32);
        let half_d2 = (led.half_distance_mm * led.half_distance_mm) as f32;
        let light = (coating.albedo as f32 * lambert + spec) / (1.0 + dist2 / half_d2);
        for c in 0..3 {
            out[c] += light * led.colour_rgb[c] as f32;
        }
    }
    out
}

/// Signal-dependent Gaussian noise from a cheap stream: four 16-bit uniforms per draw summed
/// (Irwin-Hall), which is within 1% of a normal out to 3 sigma and costs one 64-bit draw.
struct GaussianNoise {
    rng: SplitMix64,
    read_var: f32,
    shot_gain: f32,
}

impl GaussianNoise {
    fn new(seed: u64, unit: &SensorUnit) -> Self {
        let c = &unit.camera;
        GaussianNoise {
            rng: SplitMix64::new(seed),
            read_var: (c.read_noise * c.read_noise) as f32,
            shot_gain: c.shot_gain as f32,
        }
    }

    #[inline]
    fn sample(&mut self, signal: f32) -> f32 {
        let r = self.rng.next_u64();
        let sum: u32 = (0..4).map(|k| ((r >> (16 * k)) & 0xffff) as u32).sum();
        // Mean 2 * 65535, standard deviation 65536 / sqrt(3).
        let unit_normal = (sum as f32 - 131_070.0) * (3.0f32.sqrt() / 65_536.0);
        unit_normal * (self.read_var + self.shot_gain * signal.max(0.0)).sqrt()
    }
}

/// Encodes an RGB image as PNG (fast compression: noisy images barely compress anyway).
pub fn encode_png_rgb(img: &RgbImage) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(img.len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .expect("in-memory PNG encode");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn nominal() -> (SensorUnit, Renderer) {
        let unit = SensorUnit::nominal(Sensor::default());
        let renderer = Renderer::for_crop(&unit);
        (unit, renderer)
    }

    /// Depth of a flat patch (5 degrees across) facing `target` from 1 mm under the surface
    /// along the crop pixel `(x, y)`.
    fn patch_facing(r: &Renderer, x: usize, y: usize, target: Vec3) -> Vec<f32> {
        let n = r.grid().width as usize;
        let radius = r.unit().sensor.radius_mm as f32;
        let d0 = r.directions()[y * n + x];
        let p0 = d0 * (radius - 1.0);
        let normal = (target - p0).normalize();
        r.directions()
            .iter()
            .map(|&d| {
                if d == Vec3::ZERO || d.dot(d0) < 5f32.to_radians().cos() {
                    return 0.0;
                }
                let t = normal.dot(p0) / normal.dot(d);
                (radius - t).clamp(0.0, 9.0)
            })
            .collect()
    }

    #[test]
    fn a_patch_facing_an_led_takes_its_colour_in_rgb_order() {
        let (unit, r) = nominal();
        let n = r.grid().width as usize;
        let dir = tempfile::tempdir().unwrap();
        for (channel, led) in unit.leds.iter().enumerate() {
            let led_pos = Vec3::from(led.position_mm.map(|c| c as f32));
            // The crop pixel 40 degrees from the axis towards this LED's azimuth.
            let azimuth = led_pos.y.atan2(led_pos.x) as f64;
            let target = DVec3::new(
                40f64.to_radians().sin() * azimuth.cos(),
                40f64.to_radians().sin() * azimuth.sin(),
                40f64.to_radians().cos(),
            );
            let (u, v) = unit.sensor.correspondence.pixel(target).unwrap();
            let (x0, y0) = unit.sensor.crop_origin_px();
            let (x, y) = ((u.round() as i64 - x0) as usize, (v.round() as i64 - y0) as usize);
            let depth = patch_facing(&r, x, y, led_pos);
            assert!(depth[y * n + x] > 0.5);
            // Through the PNG file, so the channel order on disk is what is checked.
            let path = dir.path().join(format!("patch{channel}.png"));
            std::fs::write(&path, encode_png_rgb(&r.render(&depth, None))).unwrap();
            let img = image::open(&path).unwrap().to_rgb8();
            let px = img.get_pixel(x as u32, y as u32).0;
            let reference = r.reference_image(1).get_pixel(x as u32, y as u32).0;
            let brightest = (0..3).max_by_key(|&c| px[c]).unwrap();
            assert_eq!(brightest, channel, "patch facing LED {channel}: {px:?} (reference {reference:?})");
            let share = |p: [u8; 3]| p[channel] as f32 / p.iter().map(|&c| c as f32).sum::<f32>();
            assert!(share(px) > share(reference), "{px:?} vs {reference:?}");
        }
    }

    #[test]
    fn no_contact_is_the_reference_and_contact_changes_only_its_neighbourhood() {
        let (_, r) = nominal();
        let n = r.grid().width as usize;
        let zeros = vec![0.0; r.grid().len()];
        assert_eq!(r.render(&zeros, None), r.reference_image(1));
        let (_, shaded) = r.radiance(&zeros);
        assert_eq!(shaded, 0, "nothing to shade without contact");

        let mut depth = zeros.clone();
        for y in 200..220 {
            for x in 300..330 {
                depth[y * n + x] = 0.5 + 0.01 * (x - 300) as f32;
            }
        }
        let img = r.render(&depth, None);
        let reference = r.reference_image(1);
        let mut changed = 0;
        for (x, y, p) in img.enumerate_pixels() {
            let near = (199..=220).contains(&y) && (299..=330).contains(&x);
            if p != reference.get_pixel(x, y) {
                assert!(near, "pixel ({x}, {y}) changed away from the contact");
                changed += 1;
            }
        }
        assert!(changed > 500, "the contact must show: {changed} pixels changed");
    }

    #[test]
    fn noise_has_the_units_spread_and_is_seeded() {
        let (unit, r) = nominal();
        let zeros = vec![0.0; r.grid().len()];
        let a = r.render(&zeros, Some(1));
        assert_eq!(a, r.render(&zeros, Some(1)));
        assert_ne!(a, r.render(&zeros, Some(2)));
        let reference = r.reference();
        let (mut sum, mut sum2, mut count) = (0f64, 0f64, 0f64);
        for (i, p) in a.pixels().enumerate() {
            let signal = reference[i][0];
            if !(40.0..200.0).contains(&signal) {
                continue;
            }
            let d = p.0[0] as f64 - signal as f64;
            let expected = (unit.camera.read_noise.powi(2) + unit.camera.shot_gain * signal as f64).sqrt();
            sum += d / expected;
            sum2 += (d / expected).powi(2);
            count += 1.0;
        }
        let (mean, sd) = (sum / count, (sum2 / count - (sum / count).powi(2)).sqrt());
        // Rounding to grey levels adds 1/12 of a level squared.
        assert!(mean.abs() < 0.02 && (sd - 1.0).abs() < 0.08, "normalised noise mean {mean}, sd {sd}");
    }

    #[test]
    fn units_see_the_same_scene_differently() {
        let a = SensorUnit::from_seed(1, 25.0);
        let b = SensorUnit::from_seed(2, 25.0);
        let (ra, rb) = (Renderer::for_crop(&a), Renderer::for_crop(&b));
        let (ia, ib) = (ra.reference_image(1), rb.reference_image(1));
        let mean_diff = ia.as_raw().iter().zip(ib.as_raw()).map(|(&p, &q)| (p as f64 - q as f64).abs()).sum::<f64>()
            / ia.as_raw().len() as f64;
        assert!(mean_diff > 5.0, "units should look different: mean difference {mean_diff} grey levels");
    }
}
