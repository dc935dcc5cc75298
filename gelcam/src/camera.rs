//! From a rigid depth field to the bytes a gelcam unit's camera writes.
//!
//! Supersampled grid -> membrane (Gaussian convolution of the depth) -> surface points and
//! Sobel normals -> LEDs, ambient, vignetting, soft rim, glare -> pixels (box average) ->
//! lateral chromatic aberration -> lens blur -> Bayer mosaic with shot, read and row noise and
//! PRNU -> bilinear demosaic -> tone curve -> 8 bits -> JPEG 4:2:0 or PNG.

use glam::DVec3;
use image::RgbImage;
use rayon::prelude::*;

use crate::look::{GelUnit, Rng};

/// A unit's camera on a grid of `samples` x `samples` points per frame pixel; build once,
/// render many frames.
pub struct Camera {
    unit: GelUnit,
    samples: usize,
    width: usize,
    height: usize,
    /// Unit direction of each grid point and its polar angle (`None` beyond the lens).
    rays: Vec<Option<(DVec3, f64)>>,
    /// Linear grey levels (0..255 scale) per channel of a flat, sharp frame before the sensor:
    /// the grey levels per unit of shaded light.
    exposure: f64,
    /// Per-pixel gain of the sensor (PRNU), fixed for the unit.
    gain: Vec<f32>,
}

/// Largest polar angle the lens sees (degrees).
const LENS_MAX_DEG: f64 = 96.0;

impl Camera {
    pub fn new(unit: &GelUnit, samples: u32) -> Self {
        let samples = samples.max(1) as usize;
        let s = &unit.sensor;
        let (width, height) = (s.frame_width_px as usize * samples, s.frame_height_px as usize * samples);
        let lens_max = LENS_MAX_DEG.to_radians();
        let rays = (0..width * height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let u = (x as f64 + 0.5) / samples as f64 - 0.5;
                let v = (y as f64 + 0.5) / samples as f64 - 0.5;
                s.correspondence.direction(u, v).filter(|&(_, t)| t <= lens_max)
            })
            .collect();
        let mut rng = Rng::new(unit.seed ^ 0x9a1e);
        let npx = s.frame_width_px as usize * s.frame_height_px as usize;
        let gain = (0..npx).map(|_| (1.0 + unit.look.prnu * rng.gauss()) as f32).collect();
        let mut camera = Camera { unit: unit.clone(), samples, width, height, rays, exposure: 1.0, gain };
        // Auto exposure on the no-contact frame: its 99th percentile lands at the white level.
        let flat = camera.pixels(&camera.shade(&vec![0f32; width * height]));
        let mut levels: Vec<f32> = flat.iter().map(|p| p[0].max(p[1]).max(p[2])).filter(|&v| v > 0.0).collect();
        levels.sort_by(f32::total_cmp);
        let p99 = levels.get(levels.len() * 99 / 100).copied().unwrap_or(1.0).max(1e-6) as f64;
        camera.exposure = unit.look.white_level * 255.0 / p99;
        camera
    }

    pub fn unit(&self) -> &GelUnit {
        &self.unit
    }

    /// The grid's rigid depth from a function of the ray direction (sensor frame).
    pub fn depth_from(&self, depth_mm: impl Fn(DVec3) -> f32 + Sync) -> Vec<f32> {
        self.rays.par_iter().map(|r| r.map_or(0.0, |(d, _)| depth_mm(d))).collect()
    }

    /// The grid's rigid depth from a depth map on the sensor's crop (one sample per pixel only).
    pub fn depth_from_crop(&self, crop_depth_mm: &[f32]) -> Vec<f32> {
        assert_eq!(self.samples, 1, "crop depth maps hold one sample per pixel");
        let s = &self.unit.sensor;
        let n = s.crop_size_px as usize;
        assert_eq!(crop_depth_mm.len(), n * n, "depth map is not the sensor's crop");
        let (x0, y0) = s.crop_origin_px();
        let mut out = vec![0f32; self.width * self.height];
        for (y, row) in crop_depth_mm.chunks_exact(n).enumerate() {
            let start = (y0 as usize + y) * self.width + x0 as usize;
            out[start..start + n].copy_from_slice(row);
        }
        out
    }

    /// The frame for a rigid depth on this camera's grid; noise from `noise_seed` (`None`:
    /// none). Returns the 8-bit frame before the stream's encoding.
    pub fn render(&self, rigid_depth_mm: &[f32], noise_seed: Option<u64>) -> RgbImage {
        assert_eq!(rigid_depth_mm.len(), self.width * self.height, "depth does not match the grid");
        let sigma = self.unit.look.membrane_sigma_px * self.samples as f64;
        let membrane = gaussian_blur_plane(rigid_depth_mm, self.width, self.height, sigma);
        let mut linear = self.pixels(&self.shade(&membrane));
        for v in linear.iter_mut().flatten() {
            *v *= self.exposure as f32;
        }
        let (w, h) = (self.unit.sensor.frame_width_px as usize, self.unit.sensor.frame_height_px as usize);
        let linear = self.chromatic(&linear, w, h);
        let planes: Vec<Vec<f32>> = (0..3)
            .map(|c| {
                let plane: Vec<f32> = linear.iter().map(|p| p[c]).collect();
                gaussian_blur_plane(&plane, w, h, self.unit.look.blur_px)
            })
            .collect();
        let mosaic = self.sense(&planes, w, h, noise_seed);
        let rgb = demosaic(&mosaic, w, h);
        let tone = self.unit.look.tone;
        let bytes = rgb.iter().map(|&v| (255.0 * tone.encode(v as f64 / 255.0)).round() as u8).collect();
        RgbImage::from_raw(w as u32, h as u32, bytes).expect("frame size")
    }

    /// The frame as the camera's stream delivers it: extension and bytes (JPEG with 4:2:0
    /// chroma at the unit's quality, or PNG).
    pub fn encode(&self, img: &RgbImage) -> (&'static str, Vec<u8>) {
        match self.unit.look.jpeg_quality {
            Some(q) => {
                let mut out = Vec::new();
                let mut enc = jpeg_encoder::Encoder::new(&mut out, q);
                enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_0);
                enc.encode(img.as_raw(), img.width() as u16, img.height() as u16, jpeg_encoder::ColorType::Rgb)
                    .expect("in-memory JPEG");
                ("jpg", out)
            }
            None => {
                let mut out = Vec::new();
                image::DynamicImage::ImageRgb8(img.clone())
                    .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
                    .expect("in-memory PNG");
                ("png", out)
            }
        }
    }

    /// Shaded light per grid point (relative units) of a membrane depth.
    fn shade(&self, membrane_mm: &[f32]) -> Vec<[f32; 3]> {
        let look = &self.unit.look;
        let radius = self.unit.sensor.radius_mm;
        let (w, h) = (self.width, self.height);
        let rim = self.unit.sensor.max_theta_rad;
        let soft = look.rim_soft_deg.to_radians().max(1e-4);
        let lights: Vec<(DVec3, DVec3, f64)> =
            look.lights.iter().map(|l| (DVec3::from(l.position_mm), DVec3::from(l.rgb), l.cone_exponent)).collect();
        let alpha2 = look.roughness * look.roughness;
        let point = |x: usize, y: usize| -> Option<DVec3> {
            let i = y * w + x;
            self.rays[i].map(|(d, _)| d * (radius - membrane_mm[i] as f64))
        };
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let Some((dir, theta)) = self.rays[i] else { return [0.0; 3] };
                let (x, y) = (i % w, i / w);
                let p = dir * (radius - membrane_mm[i] as f64);
                // Sobel differences of the surface points; a neighbour beyond the grid or the
                // lens is the point itself.
                let at = |dx: isize, dy: isize| {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                        return p;
                    }
                    point(nx as usize, ny as usize).unwrap_or(p)
                };
                let gx = (at(1, -1) + 2.0 * at(1, 0) + at(1, 1)) - (at(-1, -1) + 2.0 * at(-1, 0) + at(-1, 1));
                let gy = (at(-1, 1) + 2.0 * at(0, 1) + at(1, 1)) - (at(-1, -1) + 2.0 * at(0, -1) + at(1, -1));
                let mut n = gx.cross(gy);
                if n.length_squared() == 0.0 {
                    n = -dir;
                }
                let n = if n.dot(p) > 0.0 { -n.normalize() } else { n.normalize() };
                let v = -p.normalize();
                let mut light = DVec3::ZERO;
                for &(pos, rgb, m) in &lights {
                    let to = pos - p;
                    let d2 = to.length_squared();
                    let l = to / d2.sqrt();
                    let cone = 0.15 + 0.85 * (-l.z).max(0.0).powf(m);
                    let ndl = n.dot(l);
                    let diffuse = ((ndl + look.wrap) / (1.0 + look.wrap)).max(0.0);
                    let hv = (l + v).normalize_or_zero();
                    let ndh = n.dot(hv).max(0.0);
                    let dd = ndh * ndh * (alpha2 - 1.0) + 1.0;
                    let ggx = alpha2 / (std::f64::consts::PI * dd * dd);
                    let spec = if ndl > 0.0 { look.specular * ggx * ndl * 0.25 } else { 0.0 };
                    light += rgb * (cone * 600.0 / d2) * (diffuse + spec.min(4.0));
                }
                let albedo = DVec3::from(look.albedo_rgb);
                let vignette = (theta / 2.0).cos().powf(look.vignetting_power);
                let coating = 1.0 / (1.0 + ((theta - rim) / soft).exp());
                let c = (light * albedo + DVec3::from(look.ambient_rgb)) * vignette * coating;
                [c.x as f32, c.y as f32, c.z as f32]
            })
            .collect()
    }

    /// Box average of the grid's samples per frame pixel, plus the glare.
    fn pixels(&self, grid: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let s = self.samples;
        let (w, h) = (self.width / s, self.height / s);
        let norm = 1.0 / (s * s) as f32;
        let mut out: Vec<[f32; 3]> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut acc = [0f32; 3];
                for sy in 0..s {
                    for sx in 0..s {
                        let g = grid[(y * s + sy) * self.width + x * s + sx];
                        for c in 0..3 {
                            acc[c] += g[c];
                        }
                    }
                }
                acc.map(|v| v * norm)
            })
            .collect();
        let lit: Vec<&[f32; 3]> = out.iter().filter(|p| p[1] > 0.0).collect();
        let mean = lit.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).sum::<f32>() / lit.len().max(1) as f32;
        let glare = mean * self.unit.look.flare as f32;
        let c = &self.unit.sensor.correspondence;
        for (i, p) in out.iter_mut().enumerate() {
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            if c.angles(u, v).is_some_and(|(t, _)| t.to_degrees() <= LENS_MAX_DEG) {
                *p = p.map(|x| x + glare);
            }
        }
        out
    }

    /// Red magnified and blue shrunk about the optical centre (bilinear resampling).
    fn chromatic(&self, img: &[[f32; 3]], w: usize, h: usize) -> Vec<[f32; 3]> {
        let c = &self.unit.sensor.correspondence;
        let rim = c.radial.radius_of_theta(self.unit.sensor.max_theta_rad).unwrap_or(280.0);
        let look = &self.unit.look;
        let scale = [1.0 + look.chromatic_px / rim, 1.0, 1.0 - look.chromatic_blue * look.chromatic_px / rim];
        let sample = |ch: usize, u: f64, v: f64| -> f32 {
            let (u, v) = (u.clamp(0.0, (w - 1) as f64), v.clamp(0.0, (h - 1) as f64));
            let (x0, y0) = ((u as usize).min(w - 2), (v as usize).min(h - 2));
            let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
            let p = |x: usize, y: usize| img[y * w + x][ch];
            (p(x0, y0) * (1.0 - fx) + p(x0 + 1, y0) * fx) * (1.0 - fy)
                + (p(x0, y0 + 1) * (1.0 - fx) + p(x0 + 1, y0 + 1) * fx) * fy
        };
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (u, v) = ((i % w) as f64, (i / w) as f64);
                std::array::from_fn(|ch| {
                    if ch == 1 {
                        return img[i][1];
                    }
                    let k = 1.0 / scale[ch];
                    sample(ch, c.centre_u_px + (u - c.centre_u_px) * k, c.centre_v_px + (v - c.centre_v_px) * k)
                })
            })
            .collect()
    }

    /// The Bayer (RGGB) sensor: one channel per pixel, with shot noise from the full-well count,
    /// the unit's fixed gain pattern, read noise and per-row offsets. Linear grey levels.
    fn sense(&self, planes: &[Vec<f32>], w: usize, h: usize, noise_seed: Option<u64>) -> Vec<f32> {
        let look = &self.unit.look;
        let k = look.noise_scale;
        let e_per_dn = look.full_well_e / 255.0;
        (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                let mut rng = noise_seed.map(|s| Rng::new(s ^ (y as u64).wrapping_mul(0x9e37_79b9)));
                let rows: [f64; 3] = match &mut rng {
                    Some(r) => std::array::from_fn(|_| look.row_noise_dn * k * r.gauss()),
                    None => [0.0; 3],
                };
                (0..w)
                    .map(|x| {
                        let ch = bayer_channel(x, y);
                        let i = y * w + x;
                        let v = (planes[ch][i] * self.gain[i]).max(0.0) as f64;
                        match &mut rng {
                            Some(r) => {
                                let shot = (v / e_per_dn).sqrt() * k;
                                (v + shot * r.gauss() + look.read_noise_dn * k * r.gauss() + rows[ch]) as f32
                            }
                            None => v as f32,
                        }
                    })
                    .collect::<Vec<f32>>()
            })
            .collect()
    }
}

/// RGGB: red at even rows and columns, blue at odd ones, green between.
fn bayer_channel(x: usize, y: usize) -> usize {
    match (y % 2, x % 2) {
        (0, 0) => 0,
        (1, 1) => 2,
        _ => 1,
    }
}

/// Bilinear demosaicing: each missing channel the mean of its nearest samples of that channel.
fn demosaic(mosaic: &[f32], w: usize, h: usize) -> Vec<f32> {
    // Reflected about the edge pixel, which keeps each neighbour's colour in the pattern.
    let reflect = |v: isize, n: isize| {
        if v < 0 {
            -v
        } else if v >= n {
            2 * n - 2 - v
        } else {
            v
        }
    };
    let at = |x: isize, y: isize| mosaic[reflect(y, h as isize) as usize * w + reflect(x, w as isize) as usize];
    (0..w * h)
        .into_par_iter()
        .flat_map_iter(|i| {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let own = bayer_channel(x as usize, y as usize);
            let cross = (at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1)) / 4.0;
            let diag = (at(x - 1, y - 1) + at(x + 1, y - 1) + at(x - 1, y + 1) + at(x + 1, y + 1)) / 4.0;
            let horizontal = (at(x - 1, y) + at(x + 1, y)) / 2.0;
            let vertical = (at(x, y - 1) + at(x, y + 1)) / 2.0;
            let v = at(x, y);
            let rgb = match own {
                0 => [v, cross, diag],
                2 => [diag, cross, v],
                // Green on a red row has red left and right; on a blue row, above and below.
                _ if y % 2 == 0 => [horizontal, v, vertical],
                _ => [vertical, v, horizontal],
            };
            rgb.into_iter()
        })
        .collect()
}

/// Separable Gaussian convolution of one plane (edges clamped); `sigma` in samples, none below
/// a hundredth of one.
pub(crate) fn gaussian_blur_plane(plane: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    if !(sigma > 0.01) {
        return plane.to_vec();
    }
    let radius = (3.5 * sigma).ceil() as isize;
    let mut kernel: Vec<f32> =
        (-radius..=radius).map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let sum: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= sum);
    // Rows that are zero with every neighbour within reach stay zero: skip them.
    let row_busy: Vec<bool> = plane.chunks_exact(w).map(|r| r.iter().any(|&v| v != 0.0)).collect();
    let near_busy = |y: usize| {
        let (lo, hi) = (y.saturating_sub(radius as usize), (y + radius as usize).min(h - 1));
        row_busy[lo..=hi].iter().any(|&b| b)
    };
    // One tap of the kernel about `centre` along a line of `n` samples read by `at`.
    let tap = |centre: usize, n: usize, at: &dyn Fn(usize) -> f32| -> f32 {
        kernel
            .iter()
            .enumerate()
            .map(|(j, k)| k * at((centre as isize + j as isize - radius).clamp(0, n as isize - 1) as usize))
            .sum()
    };
    let horizontal: Vec<f32> = plane
        .par_chunks_exact(w)
        .enumerate()
        .flat_map_iter(|(y, row)| {
            let busy = row_busy[y];
            (0..w).map(move |x| if busy { tap(x, w, &|i| row[i]) } else { 0.0 })
        })
        .collect();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let busy = near_busy(y);
            let horizontal = &horizontal;
            (0..w).map(move |x| if busy { tap(y, h, &|i| horizontal[i * w + x]) } else { 0.0 })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_the_mean_and_spreads_a_point_by_its_sigma() {
        let (w, h) = (41, 31);
        let mut plane = vec![0f32; w * h];
        plane[15 * w + 20] = 1.0;
        let out = gaussian_blur_plane(&plane, w, h, 2.0);
        let total: f32 = out.iter().sum();
        assert!((total - 1.0).abs() < 1e-4, "{total}");
        let var: f32 = out.iter().enumerate().map(|(i, v)| v * ((i % w) as f32 - 20.0).powi(2)).sum();
        assert!((var - 4.0).abs() < 0.05, "variance along x {var}");
        assert_eq!(gaussian_blur_plane(&plane, w, h, 0.0), plane);
    }

    #[test]
    fn demosaic_returns_flat_colours_exactly() {
        let (w, h) = (8, 6);
        let colour = [40.0, 120.0, 200.0];
        let mosaic: Vec<f32> = (0..w * h).map(|i| colour[bayer_channel(i % w, i / w)]).collect();
        let rgb = demosaic(&mosaic, w, h);
        for px in rgb.chunks_exact(3) {
            assert_eq!(px, colour);
        }
    }
}
