//! The camera image a sensor unit would record of a pressed surface.
//!
//! Each pixel sees the coating at `(R - depth) * dir` along its true ray. Surface normals come
//! from central differences of those points over the pixel grid, so they follow the depth map's
//! own resolution. The three LEDs light the coating (Lambert plus a Blinn-Phong lobe); because
//! they stand at different azimuths, a surface tilted towards one LED turns that LED's colour,
//! which is how the real sensor encodes the normal in colour. Vignetting, the housing beyond the
//! elastomer's rim and sensor noise follow; the result is 8-bit RGB.
//!
//! The shaded surface is the membrane's, not the indenter's: the contact model's solved surface
//! (`mechanics::Contact::sink_mm`), pushed in by the indenter where it touches, sagging around
//! it and bridging what the gel cannot follow. The lens blurs, the camera adds noise in its
//! linear sensor, applies its tone curve and may compress to JPEG. Each of these is the unit's
//! (`SensorUnit`).
//!
//! Only what changes is shaded: the no-contact image of the unit is cached, and a frame re-shades
//! just the pixels whose membrane (or a neighbour's, through the normal) has moved: none
//! without contact, the sag's reach (down to a micrometre) with one.

use std::borrow::Cow;
use std::sync::Arc;

use glam::Vec3;
use image::RgbImage;
use sensor::frame::Chroma;

use crate::mechanics::{Contact, Dome, GridConfig};
use crate::unit::SensorUnit;

#[allow(unsafe_code)] // the AVX2 noise and finishing pass
mod noise;
pub(crate) mod optics;
#[allow(unsafe_code)] // AVX2 shading lanes
mod shade;
mod subgrid;

use noise::{Finish, GaussianNoise, quantise};
use optics::{LensBlur, Tone};
pub use sensor::PixelGrid;
use shade::Lighting;
use subgrid::Spread;

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

/// A frame as a unit's camera delivers it.
#[derive(Clone, Debug, PartialEq)]
pub enum Capture {
    /// Uncompressed 8-bit RGB.
    Raw(RgbImage),
    /// The camera's JPEG stream: the bytes as encoded.
    Jpeg(Vec<u8>),
}

impl Capture {
    /// The pixels (a JPEG decoded).
    pub fn into_image(self) -> RgbImage {
        match self {
            Capture::Raw(img) => img,
            Capture::Jpeg(bytes) => image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
                .expect("the encoder's own JPEG decodes")
                .to_rgb8(),
        }
    }

    /// What a dataset stores: the file extension and its bytes (a raw frame as PNG).
    pub fn file(&self) -> (&'static str, std::borrow::Cow<'_, [u8]>) {
        match self {
            Capture::Raw(img) => ("png", sensor::frame::encode_png_rgb(img).into()),
            Capture::Jpeg(bytes) => ("jpg", bytes.into()),
        }
    }
}

/// What a unit's geometry fixes on a pixel grid, whatever its look: shared by the renderers of
/// one unit's looks.
struct Geometry {
    grid: PixelGrid,
    dirs: Vec<Vec3>,
    seen: Vec<Seen>,
    /// Each sample's polar angle (clamped at the lens' edge) over the useful disk's.
    theta_ratio: Vec<f32>,
    /// Which of the left, right, upper and lower neighbours (bits 0..4) of each sample the
    /// normal's differences use: one outside the grid or off the elastomer is replaced by the
    /// sample itself (a one-sided difference). Bits, not indices, to keep the table small.
    neighbours: Vec<u8>,
    /// The elastomer as this grid sees it, for the contact model's surface.
    dome: Dome,
    /// Millimetres of the surface between two neighbouring samples at the grid's centre.
    mm_per_step: f64,
}

/// Renders images of one unit on one pixel grid; build once, render many frames.
pub struct Renderer {
    unit: SensorUnit,
    geometry: Arc<Geometry>,
    vignette: Vec<f32>,
    lighting: Lighting,
    /// The no-contact radiance as the lens delivers it (blurred).
    reference: Radiance,
    /// The same before the lens' blur (empty for a sharp lens): a frame's change is shaded
    /// against it and then blurred alone.
    sharp_reference: Radiance,
    blur: Option<LensBlur>,
    tone: Option<Tone>,
    /// How finely a contact this renderer solves itself is gridded.
    solve_grid: GridConfig,
}

impl Renderer {
    pub fn new(unit: &SensorUnit, grid: PixelGrid) -> Self {
        let (mut dirs, mut seen, mut theta_ratio) = (Vec::new(), Vec::new(), Vec::new());
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
            theta_ratio.push((theta.min(unit.camera.lens_max_theta_rad) / s.max_theta_rad) as f32);
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
        let elastomer_dirs: Vec<Vec3> =
            dirs.iter().zip(&seen).map(|(&d, &k)| if k == Seen::Elastomer { d } else { Vec3::ZERO }).collect();
        let dome = Dome::on_grid(s, grid, elastomer_dirs.into());
        let centre = (h / 2) * w + w / 2;
        let mm_per_step =
            (dirs[centre].angle_between(dirs[(centre + 1).min(grid.len() - 1)]) as f64 * s.radius_mm).max(1e-6);
        Renderer::dress(unit, Arc::new(Geometry { grid, dirs, seen, theta_ratio, neighbours, dome, mm_per_step }))
    }

    /// The same unit's geometry under another look (`looks::random_look`): lights, coating,
    /// gel and camera from `look`, the rays and pixel classes reused. Panics if `look`'s
    /// sensor or lens is not this renderer's.
    pub fn restyled(&self, look: &SensorUnit) -> Renderer {
        assert!(
            look.sensor == self.unit.sensor && look.camera.lens_max_theta_rad == self.unit.camera.lens_max_theta_rad,
            "a look keeps the unit's geometry"
        );
        Renderer::dress(look, self.geometry.clone())
    }

    /// A renderer of `unit`'s look on `geometry` (computed for `unit`'s sensor and lens).
    fn dress(unit: &SensorUnit, geometry: Arc<Geometry>) -> Renderer {
        let g = &*geometry;
        let vignetting = unit.camera.vignetting as f32;
        let vignette: Vec<f32> = g.theta_ratio.iter().map(|&t| (1.0 - vignetting * t * t).max(0.0)).collect();
        let w = g.grid.width as usize;
        let lighting = Lighting::new(unit);
        let housing = unit.camera.housing_level as f32;
        let reference = (0..g.grid.len())
            .map(|i| match g.seen[i] {
                Seen::Housing => [housing * vignette[i]; 3],
                _ => [0.0; 3],
            })
            .collect();
        let step_px = g.grid.step_px;
        let mut renderer = Renderer {
            unit: unit.clone(),
            geometry,
            vignette,
            lighting,
            reference,
            sharp_reference: Vec::new(),
            blur: LensBlur::new(unit.camera.blur_px / step_px),
            tone: Tone::new(unit.camera.gamma),
            solve_grid: GridConfig::default(),
        };
        let elastomer: Vec<u32> = (0..renderer.geometry.grid.len())
            .filter(|&i| renderer.geometry.seen[i] == Seen::Elastomer)
            .map(|i| i as u32)
            .collect();
        let mut shaded = vec![[0.0; 3]; elastomer.len()];
        renderer.shade_elastomer(&vec![0.0; renderer.geometry.grid.len()], &elastomer, &mut shaded);
        for (&i, v) in elastomer.iter().zip(shaded) {
            renderer.reference[i as usize] = v;
        }
        if let Some(blur) = &renderer.blur {
            let blurred = blur.whole(&renderer.reference, w);
            renderer.sharp_reference = std::mem::replace(&mut renderer.reference, blurred);
        }
        renderer
    }

    /// The same renderer solving the contacts it is not given on `grid` (a finer grid for a
    /// scene whose detail the default's nodes would not resolve, such as the saw-tooth's teeth).
    pub fn with_solve_grid(mut self, grid: GridConfig) -> Self {
        self.solve_grid = grid;
        self
    }

    /// Renderer for the crop of `sensor`, which must be the unit's own geometry.
    pub fn for_crop(unit: &SensorUnit) -> Self {
        Renderer::new(unit, PixelGrid::crop(&unit.sensor))
    }

    pub fn grid(&self) -> &PixelGrid {
        &self.geometry.grid
    }

    pub fn unit(&self) -> &SensorUnit {
        &self.unit
    }

    /// Unit ray direction of every sample point (zero beyond the lens).
    pub fn directions(&self) -> &[Vec3] {
        &self.geometry.dirs
    }

    /// The no-contact radiance through the lens, before noise.
    pub fn reference(&self) -> &Radiance {
        &self.reference
    }

    /// Radiance through the lens of a frame whose indenter stands `depth_mm` deep at each sample
    /// point: the reference, with what the membrane changes shaded again. Returns the
    /// radiance and how many samples differ from the reference.
    pub fn radiance(&self, depth_mm: &[f32]) -> (Radiance, usize) {
        let (indices, shaded) = self.frame_changes(depth_mm, None);
        let mut out = self.reference.clone();
        for (&i, v) in indices.iter().zip(shaded) {
            out[i as usize] = v;
        }
        (out, indices.len())
    }

    /// Left, right, upper and lower neighbour of sample `i` (itself where one is not used).
    #[inline(always)]
    fn neighbours_of(&self, i: usize) -> [usize; 4] {
        let bits = self.geometry.neighbours[i];
        let w = self.geometry.grid.width as usize;
        let pick = |k: u8, j: usize| if bits & (1 << k) != 0 { j } else { i };
        [pick(0, i.wrapping_sub(1)), pick(1, i + 1), pick(2, i.wrapping_sub(w)), pick(3, i + w)]
    }

    /// The membrane over the rigid `depth_mm`: the surface the contact model solves (`contact`
    /// if the caller has solved it on this depth, else solved here), on the indenter wherever
    /// the indenter's detail between two nodes stands deeper, and in the gaps beside that
    /// detail lowered by its excess spread over the solve's node spacing (`subgrid`), so that
    /// the surface does not step back to the coarse solution. It never lies above the indenter.
    pub fn membrane<'a>(&self, depth_mm: &'a [f32], contact: Option<&Contact>) -> Cow<'a, [f32]> {
        if self.unit.elastomer.rigid_membrane || !depth_mm.iter().any(|&d| d > 0.0) {
            return Cow::Borrowed(depth_mm);
        }
        let solved;
        let contact = match contact {
            Some(c) => c,
            None => {
                let material = self.unit.elastomer.material();
                match self.geometry.dome.solve(depth_mm, &material, &self.solve_grid) {
                    Ok((c, _)) => {
                        solved = c;
                        &solved
                    }
                    Err(e) => {
                        // A scene the contact model cannot settle still has an image: the rigid
                        // surface's, said on stderr.
                        eprintln!("warning: rendering the indenter's surface, not the membrane's: {e}");
                        return Cow::Borrowed(depth_mm);
                    }
                }
            }
        };
        let mut sink = contact.sink_mm(&self.geometry.dome);
        let excess: Vec<f32> = depth_mm.iter().zip(&sink).map(|(&d, &s)| (d - s).max(0.0)).collect();
        let spacing_mm = contact
            .patches
            .iter()
            .filter(|p| p.pressure_kpa.iter().any(|&k| k > 0.0))
            .map(|p| p.spacing_mm)
            .fold(0f64, f64::max);
        let width = self.geometry.grid.width as usize;
        let spread = Spread::new(spacing_mm, self.geometry.mm_per_step).map(|s| s.apply(&excess, width).into_owned());
        for (i, (s, &d)) in sink.iter_mut().zip(depth_mm).enumerate() {
            // Where the indenter reaches the coarse surface the membrane lies on it; in the gaps
            // the surface is the solution plus what the unresolved contact next to it adds.
            *s = if *s <= d { d } else { *s + spread.as_ref().map_or(0.0, |e| e[i]) };
        }
        Cow::Owned(sink)
    }

    /// The saw-tooth shot's membrane over the rigid `depth_mm`: beyond each drop it falls off as
    /// `exp(-distance / drape_mm)` from the edge's depth (`subgrid::Spread`, the same spread the
    /// solved membrane uses below its grid).
    pub(crate) fn draped<'a>(&self, depth_mm: &'a [f32], drape_mm: f64) -> Cow<'a, [f32]> {
        match Spread::new(drape_mm, self.geometry.mm_per_step) {
            Some(spread) => spread.apply(depth_mm, self.geometry.grid.width as usize),
            None => Cow::Borrowed(depth_mm),
        }
    }

    /// The samples (grid order) where the frame's radiance through the lens differs from the
    /// reference, and their values: the membrane over the rigid depth, shaded, and the change
    /// blurred.
    fn frame_changes(&self, depth_mm: &[f32], contact: Option<&Contact>) -> (Vec<u32>, Radiance) {
        assert_eq!(depth_mm.len(), self.geometry.grid.len(), "depth map does not match the render grid");
        let width = self.geometry.grid.width as usize;
        let shape = self.membrane(depth_mm, contact);
        let (indices, shaded) = self.changes(&shape);

        let Some(blur) = &self.blur else {
            return (indices, shaded);
        };
        let (Some(&first), Some(&last)) = (indices.first(), indices.last()) else {
            return (indices, shaded);
        };
        // The change against the sharp reference on the rows it touches, blurred alone, plus
        // the blurred reference.
        let (y0, y1) = (first as usize / width, last as usize / width + 1);
        let base = y0 * width;
        let mut delta = vec![[0f32; 3]; (y1 - y0) * width];
        for (&i, v) in indices.iter().zip(&shaded) {
            let r = self.sharp_reference[i as usize];
            delta[i as usize - base] = [v[0] - r[0], v[1] - r[1], v[2] - r[2]];
        }
        let (first_row, mut values) = blur.rows(&delta, y0, width, self.geometry.grid.height as usize);
        let start = first_row * width;
        let reference = self.reference[start..start + values.len()].as_flattened();
        for (v, r) in values.as_flattened_mut().iter_mut().zip(reference) {
            *v += r;
        }
        let indices = (start as u32..(start + values.len()) as u32).collect();
        (indices, values)
    }

    /// The samples whose shading `depth_mm` (checked by the caller to fit the grid) changes, in
    /// grid order, and their sharp values.
    fn changes(&self, depth_mm: &[f32]) -> (Vec<u32>, Radiance) {
        let indices = self.dirty_elastomer(depth_mm);
        let mut shaded = vec![[0.0; 3]; indices.len()];
        self.shade_elastomer(depth_mm, &indices, &mut shaded);
        (indices, shaded)
    }

    /// The elastomer samples (grid order) whose shading a contact `depth_mm` changes: those
    /// pressed and the neighbours their normals read. A branch-free stencil over a padded byte
    /// mask, so that it vectorises: scattering each pressed sample onto its neighbours took 2.1
    /// ms a generated sample (both renderers), this 0.9 ms.
    fn dirty_elastomer(&self, depth_mm: &[f32]) -> Vec<u32> {
        const SELF: u8 = 1 << 4;
        const BLOCK: usize = 64;
        let (n, w) = (depth_mm.len(), self.geometry.grid.width as usize);
        // mask[pad + i]: the neighbour bits sample i's normal reads if it is pressed, and SELF
        // if it is a pressed elastomer sample. A zero border of a row and one either side keeps
        // the stencil's reads inside.
        let pad = w + 1;
        let mut mask = vec![0u8; n + 2 * pad];
        for (((m, &d), &bits), &seen) in
            mask[pad..pad + n].iter_mut().zip(depth_mm).zip(&self.geometry.neighbours).zip(&self.geometry.seen)
        {
            let own = if seen == Seen::Elastomer { SELF } else { 0 };
            *m = if d != 0.0 { bits | own } else { 0 };
        }
        // Sample j changes if it is pressed itself or a pressed neighbour reads it: j's right
        // neighbour reads its left (bit 0), its left one its right (bit 1), the one below its
        // upper (bit 2), the one above its lower (bit 3). A neighbour bit is only set towards an
        // elastomer sample, so the housing never shows up.
        let mut indices = Vec::new();
        let mut dirty = [0u8; BLOCK];
        for start in (0..n).step_by(BLOCK) {
            let len = BLOCK.min(n - start);
            let j0 = pad + start;
            let at = |off: usize| &mask[off..off + len];
            let (own, right, left, below, above) = (at(j0), at(j0 + 1), at(j0 - 1), at(j0 + w), at(j0 - w));
            for k in 0..len {
                dirty[k] = (own[k] & SELF) | (right[k] & 1) | (left[k] & 2) | (below[k] & 4) | (above[k] & 8);
            }
            if dirty[..len].iter().fold(0, |a, &d| a | d) != 0 {
                indices.extend((0..len).filter(|&k| dirty[k] != 0).map(|k| (start + k) as u32));
            }
        }
        indices
    }

    /// 8-bit image of a radiance on this grid (`samples`^2 samples averaged per pixel), with
    /// noise drawn from `noise_seed` (`None`: no noise).
    pub fn to_image(&self, radiance: &Radiance, samples: u32, noise_seed: Option<u64>) -> RgbImage {
        let s = samples as usize;
        let (w, h) = (self.geometry.grid.width / samples, self.geometry.grid.height / samples);
        let mut noise = noise_seed.map(|seed| GaussianNoise::new(seed, &self.unit));
        let mut finish = |px: [f32; 3]| -> [u8; 3] {
            let px = match &mut noise {
                Some(noise) => noise.add_to(px),
                None => px,
            };
            match &self.tone {
                Some(tone) => px.map(|v| tone.apply(v)),
                None => px.map(quantise),
            }
        };
        let mut img = RgbImage::new(w, h);
        let gw = self.geometry.grid.width as usize;
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
        self.stream(img).into_image()
    }

    /// What the camera's stream does to a finished frame.
    fn stream(&self, img: RgbImage) -> Capture {
        match self.unit.camera.jpeg_quality {
            Some(quality) => {
                let chroma = if self.unit.camera.chroma_420 { Chroma::Sub420 } else { Chroma::Full };
                Capture::Jpeg(sensor::frame::encode_jpeg_rgb_with(&img, quality, chroma))
            }
            None => Capture::Raw(img),
        }
    }

    /// The unit's no-contact image on this grid, without noise.
    pub fn reference_image(&self, samples: u32) -> RgbImage {
        self.to_image(&self.reference, samples, None)
    }

    /// One frame (one sample per pixel) with noise drawn from `noise_seed` (`None`: no noise).
    /// The reference and the re-shaded samples are merged block by block on the way to 8 bits,
    /// so no full-size copy of the reference is made.
    pub fn render(&self, depth_mm: &[f32], noise_seed: Option<u64>) -> RgbImage {
        self.capture(depth_mm, noise_seed).into_image()
    }

    /// [`Renderer::render`] as the camera delivers it: for a unit that streams JPEG, the JPEG's
    /// bytes, which a dataset stores as they are (as a rig logs its camera's stream).
    pub fn capture(&self, depth_mm: &[f32], noise_seed: Option<u64>) -> Capture {
        self.capture_solved(depth_mm, None, noise_seed)
    }

    /// [`Renderer::capture`] with the contact of `depth_mm` already solved (on any grid of the
    /// same sensor): the generator solves it once for the pressure label and the image.
    pub fn capture_solved(&self, depth_mm: &[f32], contact: Option<&Contact>, noise_seed: Option<u64>) -> Capture {
        const BLOCK: usize = 64;
        let (indices, shaded) = self.frame_changes(depth_mm, contact);
        let mut noise = noise_seed.map(|seed| GaussianNoise::new(seed, &self.unit));
        let mut bytes = vec![0u8; self.geometry.grid.len() * 3];
        let mut block = [[0f32; 3]; BLOCK];
        let mut next = 0;
        for (b, out) in bytes.chunks_mut(3 * BLOCK).enumerate() {
            let (start, len) = (b * BLOCK, out.len() / 3);
            block[..len].copy_from_slice(&self.reference[start..start + len]);
            while next < indices.len() && (indices[next] as usize) < start + len {
                block[indices[next] as usize - start] = shaded[next];
                next += 1;
            }
            let values = block[..len].as_flattened_mut();
            match (&mut noise, &self.tone) {
                (Some(noise), tone) => {
                    noise.add_finished(values, out, tone.as_ref().map_or(Finish::Round, Finish::Tone))
                }
                (None, None) => out.iter_mut().zip(values).for_each(|(o, v)| *o = quantise(*v)),
                (None, Some(tone)) => out.iter_mut().zip(values).for_each(|(o, v)| *o = tone.apply(*v)),
            }
        }
        self.stream(RgbImage::from_raw(self.geometry.grid.width, self.geometry.grid.height, bytes).expect("grid size"))
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use sensor::Sensor;
    use sensor::frame::encode_png_rgb;

    use super::noise::NOISE_TABLE_LEN;
    use super::*;
    use crate::unit::Camera;

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

    /// How many pixels of `r`'s noiseless frame of `depth` differ from its reference image, and
    /// the box (x0, y0, x1, y1, inclusive) they lie in.
    fn changed_pixels(r: &Renderer, depth: &[f32]) -> (usize, [u32; 4]) {
        let img = r.render(depth, None);
        let reference = r.reference_image(1);
        let mut b = [u32::MAX, u32::MAX, 0, 0];
        let mut changed = 0;
        for (x, y, p) in img.enumerate_pixels() {
            if p != reference.get_pixel(x, y) {
                b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
                changed += 1;
            }
        }
        (changed, b)
    }

    /// A ramp 30 x 20 pixels wide (x 300..330, y 200..220), 0.5..0.8 mm deep.
    fn ramp(r: &Renderer) -> Vec<f32> {
        let n = r.grid().width as usize;
        let mut depth = vec![0.0; r.grid().len()];
        for y in 200..220 {
            for x in 300..330 {
                depth[y * n + x] = 0.5 + 0.01 * (x - 300) as f32;
            }
        }
        depth
    }

    fn unit_with(blur_px: f64, gamma: f64, jpeg_quality: Option<u8>) -> SensorUnit {
        let mut unit = SensorUnit::nominal(Sensor::default());
        unit.camera = Camera { blur_px, gamma, jpeg_quality, ..unit.camera };
        unit
    }

    #[test]
    fn the_first_image_model_is_the_rigid_sharp_linear_camera() {
        let unit = SensorUnit::from_seed(1, 25.0).with_first_image_model();
        assert_eq!((unit.elastomer.rigid_membrane, unit.camera.blur_px, unit.camera.gamma), (true, 0.0, 1.0));
        assert_eq!(unit.camera.jpeg_quality, None);
        let r = Renderer::for_crop(&unit);
        assert!(r.blur.is_none() && r.tone.is_none());
        let depth = ramp(&r);
        assert!(matches!(r.membrane(&depth, None), Cow::Borrowed(_)), "the first model's membrane is the indenter");
    }

    #[test]
    fn no_contact_is_the_reference_and_a_rigid_contact_changes_only_its_neighbourhood() {
        // A membrane that follows the indenter, a sharp linear camera: the normals' one-pixel
        // reach is all.
        let r = Renderer::for_crop(&SensorUnit::nominal(Sensor::default()).with_first_image_model());
        let zeros = vec![0.0; r.grid().len()];
        assert_eq!(r.render(&zeros, None), r.reference_image(1));
        let (_, shaded) = r.radiance(&zeros);
        assert_eq!(shaded, 0, "nothing to shade without contact");
        let (changed, b) = changed_pixels(&r, &ramp(&r));
        assert!(changed > 500, "the contact must show: {changed} pixels changed");
        assert!(b[0] >= 299 && b[1] >= 199 && b[2] <= 330 && b[3] <= 220, "changed pixels in {b:?}");
    }

    /// The branch-free stencil marks exactly what scattering each pressed sample onto itself and
    /// the neighbours its normal reads marks, on blobs that cross the grid's edges, the housing
    /// and the lens' rim, and with no contact at all.
    #[test]
    fn the_dirty_stencil_matches_the_scatter_form() {
        let (_, r) = nominal();
        let (w, h) = (r.grid().width as usize, r.grid().height as usize);
        let scatter = |depth: &[f32]| -> Vec<u32> {
            let mut dirty = vec![false; depth.len()];
            for i in (0..depth.len()).filter(|&i| depth[i] != 0.0) {
                dirty[i] = true;
                r.neighbours_of(i).into_iter().for_each(|j| dirty[j] = true);
            }
            (0..depth.len()).filter(|&i| dirty[i] && r.geometry.seen[i] == Seen::Elastomer).map(|i| i as u32).collect()
        };
        let mut rng = formats::SplitMix64::new(7);
        for blobs in [0, 1, 5, 40] {
            let mut depth = vec![0f32; w * h];
            for _ in 0..blobs {
                let (cx, cy, rad) = (rng.below(w), rng.below(h), 1 + rng.below(60));
                for y in cy.saturating_sub(rad)..(cy + rad).min(h) {
                    for x in cx.saturating_sub(rad)..(cx + rad).min(w) {
                        if rng.unit() < 0.8 {
                            depth[y * w + x] = rng.range(0.01, 3.0) as f32;
                        }
                    }
                }
            }
            // A pressed sample in every corner and on every edge's middle.
            for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1), (w / 2, 0), (0, h / 2), (w - 1, h / 2)] {
                depth[y * w + x] = 1.0;
            }
            let want = scatter(&depth);
            assert_eq!(r.dirty_elastomer(&depth), want, "{blobs} blobs");
        }
        assert!(r.dirty_elastomer(&vec![0.0; w * h]).is_empty());
    }

    /// The solved membrane sags beyond the contact's edge, never lies above the indenter and
    /// follows it where it presses; the sag and the blur show beyond the edge, the solved
    /// surface's reach farther than a rigid membrane's; with a tone curve and JPEG, no contact
    /// still gives the reference image exactly.
    #[test]
    fn the_solved_membrane_sags_beyond_the_contact_and_the_lens_blurs() {
        let sharp = Renderer::for_crop(&SensorUnit::nominal(Sensor::default()).with_first_image_model());
        for unit in [unit_with(0.0, 1.0, None), unit_with(0.8, 1.8, None)] {
            let r = Renderer::for_crop(&unit);
            let depth = ramp(&r);
            let (_, untouched) = r.radiance(&vec![0.0; r.grid().len()]);
            assert_eq!(untouched, 0);
            let membrane = r.membrane(&depth, None);
            assert!(membrane.iter().zip(&depth).all(|(m, d)| m >= d), "the indenter never pierces the membrane");
            let n = r.grid().width as usize;
            // Beside the ramp the surface has sunk; 10 pixels out, less than at its edge.
            let (edge, out) = (membrane[210 * n + 331], membrane[210 * n + 340]);
            assert!(edge > 0.1 && out > 0.01 && out < edge, "sag beside the edge {edge} mm, 10 px out {out} mm");
            let (changed, b) = changed_pixels(&r, &depth);
            assert!(b[0] + 10 < 300 && b[1] + 10 < 200 && b[2] > 340 && b[3] > 230, "the sag must show: {b:?}");
            assert!(changed > changed_pixels(&sharp, &depth).0);
            // The truth is untouched: the same depth map rendered twice gives the same frame.
            assert_eq!(r.render(&depth, Some(3)), r.render(&depth, Some(3)));
        }
        let r = Renderer::for_crop(&unit_with(0.8, 1.8, Some(85)));
        assert_eq!(r.render(&vec![0.0; r.grid().len()], None), r.reference_image(1));
        let (changed, _) = changed_pixels(&r, &ramp(&r));
        assert!(changed > 500);
    }

    /// A contact solved elsewhere (the generator's, for the pressure label) gives the image the
    /// renderer's own solve gives.
    #[test]
    fn a_contact_solved_for_the_label_renders_as_the_renderers_own() {
        let (_, r) = nominal();
        let depth = ramp(&r);
        let (contact, _) =
            r.geometry.dome.solve(&depth, &r.unit().elastomer.material(), &GridConfig::default()).unwrap();
        assert_eq!(r.capture_solved(&depth, Some(&contact), Some(5)), r.capture(&depth, Some(5)));
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

    /// The AVX2 noise kernel rounds, and looks up a tone curve, exactly as the portable one, out
    /// of range and NaN included, across the table's wrap-around.
    #[test]
    fn simd_noise_matches_the_portable_kernel() {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = crate::simd::Avx2::detect() {
            let (unit, _) = nominal();
            let mut values: Vec<f32> = (0..4099).map(|i| (i as f32 * 0.731).sin() * 300.0 + 100.0).collect();
            values.extend([f32::NAN, -0.0, -1e9, 1e9, 254.6, 255.4, 0.49, f32::INFINITY, f32::NEG_INFINITY]);
            let (mut a, mut b) = (vec![0u8; values.len()], vec![0u8; values.len()]);
            let mut portable = GaussianNoise::new(5, &unit);
            let mut simd = GaussianNoise::new(5, &unit);
            // Start near the table's end, so that a run wraps.
            portable.pos = NOISE_TABLE_LEN - 1001;
            simd.pos = NOISE_TABLE_LEN - 1001;
            portable.add_finished_portable(&values, &mut a, Finish::Round);
            simd.add_finished_avx2(avx2, &values, &mut b, Finish::Round);
            assert_eq!(a, b);
            assert_eq!(portable.pos, simd.pos);
            assert!(a.contains(&0) && a.contains(&255) && a.iter().any(|&x| x > 0 && x < 255));
            // Through a tone curve: the table's ends (0 and 255 * TONE_STEPS) included.
            let tone = Tone::new(1.8).unwrap();
            portable.add_finished_portable(&values, &mut a, Finish::Tone(&tone));
            simd.add_finished_avx2(avx2, &values, &mut b, Finish::Tone(&tone));
            assert_eq!(a, b);
            assert!(a.contains(&0) && a.contains(&255));
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

    #[test]
    fn a_restyled_renderer_is_a_renderer_of_its_look() {
        let unit = SensorUnit::from_seed(9, 25.0);
        let base = Renderer::for_crop(&unit);
        let look = crate::looks::random_look(&unit, 4);
        let styled = base.restyled(&look);
        let fresh = Renderer::for_crop(&look);
        let n = base.grid().len();
        let mut depth = vec![0.0; n];
        let w = base.grid().width as usize;
        for (i, d) in depth.iter_mut().enumerate() {
            let (x, y) = ((i % w) as f32 - 300.0, (i / w) as f32 - 260.0);
            *d = (1.2 - (x * x + y * y) / 3000.0).max(0.0);
        }
        assert_eq!(styled.capture(&depth, Some(3)), fresh.capture(&depth, Some(3)));
        assert_eq!(styled.reference_image(1), fresh.reference_image(1));
        // Restyling with the unit's own look gives the unit's renderer back.
        assert_eq!(base.restyled(&unit).capture(&depth, Some(3)), base.capture(&depth, Some(3)));
        assert_ne!(styled.reference_image(1), base.reference_image(1), "another look shows another image");
    }
}
