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

use glam::{Vec3, Vec3A};
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
    /// Which of the left, right, upper and lower neighbours (bits 0..4) of each sample the
    /// normal's differences use: one outside the grid or off the elastomer is replaced by the
    /// sample itself (a one-sided difference). Bits, not indices, to keep the table small.
    neighbours: Vec<u8>,
    lighting: Lighting,
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
        let (w, h) = (grid.width as usize, grid.height as usize);
        let neighbours = (0..grid.len())
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let candidates =
                    [(x > 0, i.wrapping_sub(1)), (x + 1 < w, i + 1), (y > 0, i.wrapping_sub(w)), (y + 1 < h, i + w)];
                let mut bits = 0u8;
                for (k, (inside, j)) in candidates.into_iter().enumerate() {
                    if inside && seen[j] == Seen::Elastomer {
                        bits |= 1 << k;
                    }
                }
                bits
            })
            .collect();
        let lighting = Lighting::new(unit);
        let housing = unit.camera.housing_level as f32;
        let reference = (0..grid.len())
            .map(|i| match seen[i] {
                Seen::Housing => [housing * vignette[i]; 3],
                _ => [0.0; 3],
            })
            .collect();
        let mut renderer = Renderer { unit: unit.clone(), grid, dirs, seen, vignette, neighbours, lighting, reference };
        let elastomer: Vec<u32> =
            (0..grid.len()).filter(|&i| renderer.seen[i] == Seen::Elastomer).map(|i| i as u32).collect();
        let mut shaded = vec![[0.0; 3]; elastomer.len()];
        renderer.shade_elastomer(&vec![0.0; grid.len()], &elastomer, &mut shaded);
        for (&i, v) in elastomer.iter().zip(shaded) {
            renderer.reference[i as usize] = v;
        }
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
        let (indices, shaded) = self.changes(depth_mm);
        let mut out = self.reference.clone();
        for (&i, v) in indices.iter().zip(shaded) {
            out[i as usize] = v;
        }
        (out, indices.len())
    }

    /// Left, right, upper and lower neighbour of sample `i` (itself where one is not used).
    #[inline(always)]
    fn neighbours_of(&self, i: usize) -> [usize; 4] {
        let bits = self.neighbours[i];
        let w = self.grid.width as usize;
        let pick = |k: u8, j: usize| if bits & (1 << k) != 0 { j } else { i };
        [pick(0, i.wrapping_sub(1)), pick(1, i + 1), pick(2, i.wrapping_sub(w)), pick(3, i + w)]
    }

    /// The samples whose radiance differs from the reference (in grid order) and their values.
    fn changes(&self, depth_mm: &[f32]) -> (Vec<u32>, Radiance) {
        assert_eq!(depth_mm.len(), self.grid.len(), "depth map does not match the render grid");
        let mut dirty = vec![false; self.grid.len()];
        for (i, &d) in depth_mm.iter().enumerate() {
            if d != 0.0 {
                dirty[i] = true;
                for j in self.neighbours_of(i) {
                    dirty[j] = true;
                }
            }
        }
        // The housing and what lies beyond the lens look the same whatever is pressed.
        let indices: Vec<u32> =
            (0..dirty.len()).filter(|&i| dirty[i] && self.seen[i] == Seen::Elastomer).map(|i| i as u32).collect();
        let mut shaded = vec![[0.0; 3]; indices.len()];
        self.shade_elastomer(depth_mm, &indices, &mut shaded);
        (indices, shaded)
    }

    /// Shades the elastomer samples `indices` into `out` (one value per index, in order),
    /// `LANES` at a time: the gathers are
    /// scalar, the lighting runs on arrays that the compiler turns into SIMD.
    fn shade_elastomer(&self, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2. Rust does not contract into FMA, so the bits are the
            // same as the baseline build's.
            return unsafe { self.shade_elastomer_avx2(depth_mm, indices, out) };
        }
        self.shade_elastomer_lanes(depth_mm, indices, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn shade_elastomer_avx2(&self, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
        self.shade_elastomer_lanes(depth_mm, indices, out)
    }

    #[inline(always)]
    fn shade_elastomer_lanes(&self, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
        const LANES: usize = 16;
        let radius = self.unit.sensor.radius_mm as f32;
        let cam = &self.unit.camera;
        let (exposure, ambient) = (cam.exposure as f32, cam.ambient_level as f32);
        let light = &self.lighting;
        for (chunk, out_chunk) in indices.chunks(LANES).zip(out.chunks_mut(LANES)) {
            let mut p = [[0f32; LANES]; 3];
            let mut du = [[0f32; LANES]; 3];
            let mut dv = [[0f32; LANES]; 3];
            let mut vig = [0f32; LANES];
            for (k, &i) in chunk.iter().enumerate() {
                let i = i as usize;
                let point = |j: usize| self.dirs[j] * (radius - depth_mm[j]);
                // Named one by one: `array::map` here was left as a call per sample.
                let [l, r, u, d] = self.neighbours_of(i);
                let (left, right, up, down) = (point(l), point(r), point(u), point(d));
                let (centre, across, along) = (point(i), right - left, down - up);
                for c in 0..3 {
                    p[c][k] = centre[c];
                    du[c][k] = across[c];
                    dv[c][k] = along[c];
                }
                vig[k] = self.vignette[i];
            }
            let mut rgb = [[0f32; LANES]; 3];
            for k in 0..LANES {
                let (px, py, pz) = (p[0][k], p[1][k], p[2][k]);
                let inv_p = 1.0 / (px * px + py * py + pz * pz).sqrt();
                let (vx, vy, vz) = (-px * inv_p, -py * inv_p, -pz * inv_p);
                let nx = du[1][k] * dv[2][k] - du[2][k] * dv[1][k];
                let ny = du[2][k] * dv[0][k] - du[0][k] * dv[2][k];
                let nz = du[0][k] * dv[1][k] - du[1][k] * dv[0][k];
                let n2 = nx * nx + ny * ny + nz * nz;
                // The camera sees the coating from inside: the normal faces the centre. A
                // degenerate normal falls back to the sphere's.
                let facing = if nx * px + ny * py + nz * pz > 0.0 { -1.0 } else { 1.0 };
                let inv_n = facing / n2.sqrt();
                let (nx, ny, nz) = if n2 > 0.0 { (nx * inv_n, ny * inv_n, nz * inv_n) } else { (vx, vy, vz) };
                let mut acc = [0f32; 3];
                for &(pos, colour, inv_half_d2) in &light.leds {
                    let (tx, ty, tz) = (pos.x - px, pos.y - py, pos.z - pz);
                    let d2 = tx * tx + ty * ty + tz * tz;
                    let inv_d = 1.0 / d2.sqrt();
                    let (lx, ly, lz) = (tx * inv_d, ty * inv_d, tz * inv_d);
                    let lambert = nx * lx + ny * ly + nz * lz;
                    let (hx, hy, hz) = (lx + vx, ly + vy, lz + vz);
                    let cos_h = ((nx * hx + ny * hy + nz * hz) / (hx * hx + hy * hy + hz * hz).sqrt()).max(0.0);
                    // Schlick's rational form of cos^s: the same lobe as powf, far cheaper.
                    let s = light.shininess;
                    let spec = light.specular * cos_h / (s - s * cos_h + cos_h);
                    let amount = (light.albedo * lambert + spec) / (1.0 + d2 * inv_half_d2);
                    let amount = if lambert > 0.0 { amount } else { 0.0 };
                    acc[0] += colour.x * amount;
                    acc[1] += colour.y * amount;
                    acc[2] += colour.z * amount;
                }
                for c in 0..3 {
                    rgb[c][k] = (acc[c] * exposure + ambient) * vig[k];
                }
            }
            for (k, o) in out_chunk.iter_mut().enumerate() {
                *o = [rgb[0][k], rgb[1][k], rgb[2][k]];
            }
        }
    }

    /// 8-bit image of a radiance on this grid (`samples`^2 samples averaged per pixel), with
    /// noise drawn from `noise_seed` (`None`: no noise).
    pub fn to_image(&self, radiance: &Radiance, samples: u32, noise_seed: Option<u64>) -> RgbImage {
        let s = samples as usize;
        let (w, h) = (self.grid.width / samples, self.grid.height / samples);
        let mut noise = noise_seed.map(|seed| GaussianNoise::new(seed, &self.unit));
        let mut finish = |px: [f32; 3]| -> [u8; 3] {
            let px = match &mut noise {
                Some(noise) => noise.add_to(px),
                None => px,
            };
            px.map(quantise)
        };
        let mut img = RgbImage::new(w, h);
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
            px.0 = finish(sum.map(|v| v * norm));
        }
        img
    }

    /// The unit's no-contact image on this grid, without noise.
    pub fn reference_image(&self, samples: u32) -> RgbImage {
        self.to_image(&self.reference, samples, None)
    }

    /// One frame (one sample per pixel) with noise drawn from `noise_seed` (`None`: no noise).
    /// The reference and the re-shaded samples are merged block by block on the way to 8 bits,
    /// so no full-size copy of the reference is made.
    pub fn render(&self, depth_mm: &[f32], noise_seed: Option<u64>) -> RgbImage {
        const BLOCK: usize = 64;
        let (indices, shaded) = self.changes(depth_mm);
        let mut noise = noise_seed.map(|seed| GaussianNoise::new(seed, &self.unit));
        let mut bytes = vec![0u8; self.grid.len() * 3];
        let mut block = [[0f32; 3]; BLOCK];
        let mut next = 0;
        for (b, out) in bytes.chunks_mut(3 * BLOCK).enumerate() {
            let (start, len) = (b * BLOCK, out.len() / 3);
            block[..len].copy_from_slice(&self.reference[start..start + len]);
            while next < indices.len() && (indices[next] as usize) < start + len {
                block[indices[next] as usize - start] = shaded[next];
                next += 1;
            }
            let values = block[..len].as_flattened();
            match &mut noise {
                Some(noise) => noise.add_quantised(values, out),
                None => out.iter_mut().zip(values).for_each(|(o, &v)| *o = quantise(v)),
            }
        }
        RgbImage::from_raw(self.grid.width, self.grid.height, bytes).expect("grid size")
    }
}

/// A grey level rounded to 8 bits (non-negative after the clamp, so adding a half and
/// truncating rounds; NaN becomes 0).
#[inline(always)]
fn quantise(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

/// A unit's lights and coating in the renderer's single-precision form.
#[derive(Clone, Debug)]
struct Lighting {
    leds: [(Vec3A, Vec3A, f32); 3],
    albedo: f32,
    specular: f32,
    shininess: f32,
}

impl Lighting {
    fn new(unit: &SensorUnit) -> Self {
        let v = |a: [f64; 3]| Vec3A::from(a.map(|c| c as f32));
        Lighting {
            leds: std::array::from_fn(|i| {
                let led = &unit.leds[i];
                (v(led.position_mm), v(led.colour_rgb), (1.0 / (led.half_distance_mm * led.half_distance_mm)) as f32)
            }),
            albedo: unit.coating.albedo as f32,
            specular: unit.coating.specular as f32,
            shininess: unit.coating.shininess as f32,
        }
    }
}

/// Length of the shared table of standard normals: more values than an 800x600 RGB frame has,
/// so a frame never meets the same value twice.
const NOISE_TABLE_LEN: usize = 1 << 21;

/// Standard normals (Box-Muller from a fixed stream), computed once per process.
fn noise_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = SplitMix64::new(0x6e01_5e7a_b1e5);
        (0..NOISE_TABLE_LEN).map(|_| rng.normal() as f32).collect()
    })
}

/// Signal-dependent Gaussian noise (read noise plus shot noise). Each frame reads the shared
/// table of normals from its own seeded offset: values within a frame are independent, frames
/// get different noise, and adding it is a plain vectorised pass (film-grain synthesis does the
/// same).
struct GaussianNoise {
    table: &'static [f32],
    pos: usize,
    level: NoiseLevel,
}

/// How strong a unit's noise is at each grey level.
#[derive(Clone, Copy)]
struct NoiseLevel {
    read_var: f32,
    shot_gain: f32,
}

impl NoiseLevel {
    /// Standard deviation of the noise at grey level `v`: read noise plus shot noise.
    #[inline(always)]
    fn sigma(self, v: f32) -> f32 {
        (self.read_var + self.shot_gain * v.max(0.0)).sqrt()
    }

    /// The portable kernel: each value plus its normal times the noise's spread, rounded.
    #[inline(always)]
    fn add_quantised(self, values: &[f32], normals: &[f32], out: &mut [u8]) {
        for ((b, &v), &z) in out.iter_mut().zip(values).zip(normals) {
            *b = quantise(v + z * self.sigma(v));
        }
    }
}

impl GaussianNoise {
    fn new(seed: u64, unit: &SensorUnit) -> Self {
        let c = &unit.camera;
        GaussianNoise {
            table: noise_table(),
            pos: (SplitMix64::new(seed).next_u64() as usize) % NOISE_TABLE_LEN,
            level: NoiseLevel { read_var: (c.read_noise * c.read_noise) as f32, shot_gain: c.shot_gain as f32 },
        }
    }

    /// Adds noise to interleaved RGB values and rounds them to grey levels.
    fn add_quantised(&mut self, values: &[f32], out: &mut [u8]) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2; the arithmetic is the baseline's, bit for bit.
            return unsafe { self.add_quantised_avx2(values, out) };
        }
        self.add_quantised_portable(values, out)
    }

    fn add_quantised_portable(&mut self, values: &[f32], out: &mut [u8]) {
        let level = self.level;
        self.add_quantised_runs(values, out, |v, z, o| level.add_quantised(v, z, o))
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn add_quantised_avx2(&mut self, values: &[f32], out: &mut [u8]) {
        use std::arch::x86_64::*;
        let level = self.level;
        let (read_var, shot_gain) = (_mm256_set1_ps(level.read_var), _mm256_set1_ps(level.shot_gain));
        let (zero, top, half) = (_mm256_setzero_ps(), _mm256_set1_ps(255.0), _mm256_set1_ps(0.5));
        self.add_quantised_runs(values, out, |values, normals, out| {
            let whole = values.len() / 8 * 8;
            for k in (0..whole).step_by(8) {
                // SAFETY: k + 8 <= len of all three slices; unaligned loads and an 8-byte store.
                unsafe {
                    let v = _mm256_loadu_ps(values.as_ptr().add(k));
                    let z = _mm256_loadu_ps(normals.as_ptr().add(k));
                    // `sigma` and `quantise` step for step (a NaN ends as 0 either way, since
                    // max_ps answers its second operand for one).
                    let sigma =
                        _mm256_sqrt_ps(_mm256_add_ps(read_var, _mm256_mul_ps(shot_gain, _mm256_max_ps(v, zero))));
                    let noisy = _mm256_add_ps(v, _mm256_mul_ps(z, sigma));
                    let level = _mm256_add_ps(_mm256_min_ps(_mm256_max_ps(noisy, zero), top), half);
                    let ints = _mm256_cvttps_epi32(level);
                    let words = _mm_packus_epi32(_mm256_castsi256_si128(ints), _mm256_extracti128_si256::<1>(ints));
                    _mm_storel_epi64(out.as_mut_ptr().add(k) as *mut __m128i, _mm_packus_epi16(words, words));
                }
            }
            level.add_quantised(&values[whole..], &normals[whole..], &mut out[whole..]);
        })
    }

    /// Hands `kernel` contiguous runs of values with their normals, wrapping at the table's end.
    #[inline(always)]
    fn add_quantised_runs(&mut self, values: &[f32], out: &mut [u8], kernel: impl Fn(&[f32], &[f32], &mut [u8])) {
        let mut done = 0;
        while done < values.len() {
            let n = (values.len() - done).min(NOISE_TABLE_LEN - self.pos);
            kernel(&values[done..done + n], &self.table[self.pos..self.pos + n], &mut out[done..done + n]);
            self.pos = (self.pos + n) % NOISE_TABLE_LEN;
            done += n;
        }
    }

    #[inline]
    fn add_to(&mut self, px: [f32; 3]) -> [f32; 3] {
        let out = std::array::from_fn(|c| {
            let z = self.table[(self.pos + c) % NOISE_TABLE_LEN];
            px[c] + z * self.level.sigma(px[c])
        });
        self.pos = (self.pos + 3) % NOISE_TABLE_LEN;
        out
    }
}

pub use sensor::io::encode_png_rgb;

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

    /// The AVX2 noise kernel rounds exactly as the portable one, out of range and NaN included,
    /// across the table's wrap-around.
    #[test]
    fn simd_noise_matches_the_portable_kernel() {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            let (unit, _) = nominal();
            let mut values: Vec<f32> = (0..4099).map(|i| (i as f32 * 0.731).sin() * 300.0 + 100.0).collect();
            values.extend([f32::NAN, -0.0, -1e9, 1e9, 254.6, 255.4, 0.49, f32::INFINITY, f32::NEG_INFINITY]);
            let (mut a, mut b) = (vec![0u8; values.len()], vec![0u8; values.len()]);
            let mut portable = GaussianNoise::new(5, &unit);
            let mut simd = GaussianNoise::new(5, &unit);
            // Start near the table's end, so that a run wraps.
            portable.pos = NOISE_TABLE_LEN - 1001;
            simd.pos = NOISE_TABLE_LEN - 1001;
            portable.add_quantised_portable(&values, &mut a);
            // SAFETY: AVX2 was detected above.
            unsafe { simd.add_quantised_avx2(&values, &mut b) };
            assert_eq!(a, b);
            assert_eq!(portable.pos, simd.pos);
            assert!(a.contains(&0) && a.contains(&255) && a.iter().any(|&x| x > 0 && x < 255));
        }
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
