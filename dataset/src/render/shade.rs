//! Shading the coating: Lambert plus a Blinn-Phong lobe from each of the three LEDs, with
//! normals from central differences of the pressed surface's points.

use glam::Vec3A;

use super::Renderer;
#[cfg(target_arch = "x86_64")]
use crate::simd::Avx2;
use crate::unit::SensorUnit;

impl Renderer {
    /// Shades the elastomer samples `indices` into `out` (one value per index, in order),
    /// `LANES` at a time: the gathers are
    /// scalar, the lighting runs on arrays that the compiler turns into SIMD.
    pub(super) fn shade_elastomer(&self, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            return self.shade_elastomer_avx2(avx2, depth_mm, indices, out);
        }
        self.shade_elastomer_lanes(depth_mm, indices, out)
    }

    /// The same arithmetic compiled for AVX2 (Rust does not contract into FMA, so the bits are
    /// the same as the baseline build's).
    #[cfg(target_arch = "x86_64")]
    fn shade_elastomer_avx2(&self, _: Avx2, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
        #[target_feature(enable = "avx2")]
        fn lanes(r: &Renderer, depth_mm: &[f32], indices: &[u32], out: &mut [[f32; 3]]) {
            r.shade_elastomer_lanes(depth_mm, indices, out)
        }
        // SAFETY: an `Avx2` token exists only where run-time detection found AVX2.
        unsafe { lanes(self, depth_mm, indices, out) }
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
                let point = |j: usize| self.geometry.dirs[j] * (radius - depth_mm[j]);
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
}

/// A unit's lights and coating in the renderer's single-precision form.
#[derive(Clone, Debug)]
pub(super) struct Lighting {
    leds: [(Vec3A, Vec3A, f32); 3],
    albedo: f32,
    specular: f32,
    shininess: f32,
}

impl Lighting {
    pub(super) fn new(unit: &SensorUnit) -> Self {
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
