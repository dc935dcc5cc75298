//! A sample's force labels from its depth map: the contact solved where the map says the scene
//! overlaps the dome, its pressure resampled onto the map's own pixels.

use std::sync::Arc;

use glam::{DVec3, Vec3};
use sensor::{DepthMap, PNG_UM_PER_STEP, PixelGrid, Sensor};

use super::{Contact, GridConfig, Material, MechanicsError, Wrench};

/// The dome as a pixel grid's samples see it (the depth map's crop, or a renderer's grid),
/// prepared once per sensor and grid.
pub struct Dome {
    radius_mm: f64,
    grid: PixelGrid,
    /// Unit direction of each grid sample (zero where it sees no elastomer).
    dirs: Arc<[Vec3]>,
    sensor: Sensor,
    /// Millimetres of the surface between two neighbouring samples at the grid's centre.
    mm_per_step: f64,
}

impl Dome {
    /// The dome as the sensor's crop sees it, one sample per pixel, through the lens' own
    /// directions (`Sensor::pixel_rays`).
    pub fn new(sensor: &Sensor) -> Self {
        Dome::of_rays(sensor, sensor.pixel_rays().into_iter().map(|r| (r.index, r.dir)))
    }

    /// The dome as the sensor's crop sees it, from each useful crop pixel's index and unit
    /// direction (the ray caster's, which snaps them to its grid, so that labels and depth
    /// maps see the same rays).
    pub fn of_rays(sensor: &Sensor, rays: impl IntoIterator<Item = (u32, Vec3)>) -> Self {
        let n = sensor.crop_size_px as usize;
        let mut dirs = vec![Vec3::ZERO; n * n];
        for (i, d) in rays {
            dirs[i as usize] = d;
        }
        Dome::on_grid(sensor, PixelGrid::crop(sensor), dirs.into())
    }

    /// The dome as `grid`'s samples see it: `dirs` holds each sample's unit direction, zero
    /// where the sample sees no elastomer.
    pub fn on_grid(sensor: &Sensor, grid: PixelGrid, dirs: Arc<[Vec3]>) -> Self {
        assert_eq!(dirs.len(), grid.len(), "one direction per grid sample");
        // The sample nearest the optical centre and its right-hand neighbour, through the lens.
        let (u, v) = (sensor.correspondence.centre_u_px, sensor.correspondence.centre_v_px);
        let at = |du: f64| sensor.correspondence.direction(u + du, v).map(|(d, _)| d);
        let mm_per_step = match (at(0.0), at(grid.step_px)) {
            (Some(a), Some(b)) => (a.angle_between(b) * sensor.radius_mm).max(1e-6),
            _ => 1e-6,
        };
        Dome { radius_mm: sensor.radius_mm, grid, dirs, sensor: sensor.clone(), mm_per_step }
    }

    /// Unit direction of grid sample `i` (zero where it sees no elastomer).
    pub(crate) fn dir(&self, i: usize) -> DVec3 {
        self.dirs[i].as_dvec3()
    }

    /// Each grid sample's unit direction (zero where it sees no elastomer).
    pub(crate) fn dirs(&self) -> &[Vec3] {
        &self.dirs
    }

    /// Millimetres of the surface between two neighbouring samples at the optical centre.
    pub(crate) fn mm_per_step(&self) -> f64 {
        self.mm_per_step
    }

    pub(crate) fn grid(&self) -> &PixelGrid {
        &self.grid
    }

    /// Grid coordinates (samples, fractional) where unit `dir` is seen, if the lens sees it.
    pub(crate) fn grid_position(&self, dir: DVec3) -> Option<(f64, f64)> {
        let (u, v) = self.sensor.correspondence.pixel(dir)?;
        let g = &self.grid;
        Some(((u - g.origin_u_px) / g.step_px, (v - g.origin_v_px) / g.step_px))
    }

    /// The depth at the grid position where unit `dir` is seen, bilinear between the four
    /// samples around it (mm; -1 where it leaves the grid).
    fn depth_along(&self, depth_mm: &[f32], dir: DVec3) -> f64 {
        let Some((x, y)) = self.grid_position(dir) else { return -1.0 };
        let w = self.grid.width as usize;
        bilinear([w, self.grid.height as usize], x, y, |i, j| depth_mm[j * w + i] as f64).unwrap_or(-1.0)
    }

    /// Solves the contact that `depth_mm` (on this grid) shows: its samples above zero, one
    /// region per 4-connected group. Returns each sample's region (`u32::MAX`: none) beside it.
    pub fn solve(
        &self,
        depth_mm: &[f32],
        material: &Material,
        grid: &GridConfig,
    ) -> Result<(Contact, Vec<u32>), MechanicsError> {
        assert_eq!(depth_mm.len(), self.grid.len(), "the depth map is on the dome's grid");
        // A region's outline bounds it: the patches need no more.
        let (outlines, region_of) = outlines(depth_mm, self.grid.width as usize);
        let regions =
            outlines.into_iter().map(|r| r.into_iter().map(|i| self.dir(i as usize)).collect()).collect::<Vec<_>>();
        let contact = super::solve(self.radius_mm, material, grid, &regions, |dir| {
            let d = self.depth_along(depth_mm, dir);
            if d > 0.0 { d } else { -1.0 }
        })?;
        Ok((contact, region_of))
    }
}

/// The lattice step (crop pixels) at which each patch's map coordinates are computed exactly.
const STRIDE: usize = 4;

/// One sample's force labels.
pub struct ForceLabel {
    /// Contact pressure on the depth map's pixels (kPa, row-major crop; 0 off contact).
    pub pressure_kpa: Vec<f32>,
    pub wrench: Wrench,
    pub contact: Contact,
}

/// Solves the contact that `depth` shows (its pixels above zero, one region per 4-connected
/// group) and resamples the pressure onto its pixels.
pub fn force_label(
    dome: &Dome,
    depth: &DepthMap,
    material: &Material,
    grid: &GridConfig,
) -> Result<ForceLabel, MechanicsError> {
    let n = depth.size_px as usize;
    assert_eq!(dome.grid, PixelGrid::crop(&dome.sensor), "force labels are made on the crop");
    let (contact, region_of) = dome.solve(&depth.depth_mm, material, grid)?;
    let mut pressure_kpa = vec![0f32; n * n];
    // Only pixels near a loaded node can read a pressure: the crop's box around those nodes and
    // their neighbours (the bilinear lookup's reach).
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let (x0, y0) = dome.sensor.crop_to_frame(0, 0);
    for p in &contact.patches {
        let [w, h] = p.size;
        for j in 0..h {
            for i in 0..w {
                if !(p.pressure_kpa[j * w + i] > 0.0) {
                    continue;
                }
                for (a, b) in [(i.saturating_sub(1), j.saturating_sub(1)), ((i + 1).min(w - 1), (j + 1).min(h - 1))] {
                    for (ii, jj) in [(a, b), (a, j), (i, b)] {
                        if let Some((u, v)) = dome.sensor.correspondence.pixel(p.direction(dome.radius_mm, ii, jj)) {
                            for (k, c) in [u - x0, v - y0].into_iter().enumerate() {
                                lo[k] = lo[k].min(c);
                                hi[k] = hi[k].max(c);
                            }
                        }
                    }
                }
            }
        }
    }
    if lo[0].is_finite() {
        let clip = |v: f64| (v.max(0.0) as usize).min(n - 1);
        let (xa, xb, ya, yb) = (clip(lo[0] - 2.0), clip(hi[0] + 2.0), clip(lo[1] - 2.0), clip(hi[1] + 2.0));
        // Each patch's map coordinates on a lattice of every STRIDE-th pixel of the box,
        // interpolated in between: the map is smooth on the crop, and one exact mapping per
        // pixel was the label's largest cost on broad contacts.
        let (cols, rows) = ((xb - xa) / STRIDE + 2, (yb - ya) / STRIDE + 2);
        let lattice: Vec<Vec<Option<[f64; 2]>>> = contact
            .patches
            .iter()
            .map(|p| {
                (0..rows * cols)
                    .map(|k| {
                        let (x, y) = (xa + (k % cols) * STRIDE, ya + (k / cols) * STRIDE);
                        let (u, v) = dome.sensor.crop_to_frame(x as u32, y as u32);
                        let (dir, _) = dome.sensor.correspondence.direction(u, v)?;
                        p.project(dome.radius_mm, dir)
                    })
                    .collect()
            })
            .collect();
        for y in ya..=yb {
            for x in xa..=xb {
                let i = y * n + x;
                // Each pixel reads the patch its region was solved on; one whose depth the 16-bit
                // PNG stores as zero reads none, so that the two maps agree on disk.
                if !(depth.depth_mm[i] * 1000.0 / PNG_UM_PER_STEP > 0.5) {
                    continue;
                }
                let Some(Some(k)) = contact.region_patch.get(region_of[i] as usize) else { continue };
                let (cx, cy) = ((x - xa) / STRIDE, (y - ya) / STRIDE);
                let (ax, ay) = (((x - xa) % STRIDE) as f64 / STRIDE as f64, ((y - ya) % STRIDE) as f64 / STRIDE as f64);
                let table = &lattice[*k];
                let corners = [
                    table[cy * cols + cx],
                    table[cy * cols + cx + 1],
                    table[(cy + 1) * cols + cx],
                    table[(cy + 1) * cols + cx + 1],
                ];
                let st = match corners {
                    [Some(a), Some(b), Some(c), Some(d)] => {
                        let mix = |m: usize| {
                            (1.0 - ay) * ((1.0 - ax) * a[m] + ax * b[m]) + ay * ((1.0 - ax) * c[m] + ax * d[m])
                        };
                        Some([mix(0), mix(1)])
                    }
                    // Beyond the lens' model at a corner: the pixel's own mapping.
                    _ => contact.patches[*k].project(dome.radius_mm, dome.dir(i)),
                };
                if let Some(st) = st {
                    pressure_kpa[i] = contact.patches[*k].pressure_at(st) as f32;
                }
            }
        }
    }
    Ok(ForceLabel { pressure_kpa, wrench: contact.wrench(), contact })
}

/// The outline of each 4-connected group of samples with depth above zero (its samples with a
/// neighbour outside it, grid indices) on a grid `width` wide, and each sample's group
/// (`u32::MAX`: none).
fn outlines(depth_mm: &[f32], width: usize) -> (Vec<Vec<u32>>, Vec<u32>) {
    let inside = |k: usize| depth_mm[k] > 0.0;
    let (len, n) = (depth_mm.len(), width);
    let mut seen = vec![false; len];
    let mut group = vec![u32::MAX; len];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..len {
        if seen[start] || !inside(start) {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut outline = Vec::new();
        while let Some(i) = stack.pop() {
            group[i] = out.len() as u32;
            let (x, y) = (i % n, i / n);
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < n).then(|| i + 1),
                (y > 0).then(|| i - n),
                (i + n < len).then(|| i + n),
            ];
            let mut edge = false;
            for k in neighbours {
                match k {
                    Some(k) if inside(k) => {
                        if !seen[k] {
                            seen[k] = true;
                            stack.push(k);
                        }
                    }
                    _ => edge = true,
                }
            }
            if edge {
                outline.push(i as u32);
            }
        }
        out.push(outline);
    }
    (out, group)
}

impl Contact {
    /// The pressure (kPa) where unit `dir` meets the dome: bilinear between the nodes of the
    /// patch whose grid holds it, 0 outside every patch.
    pub fn pressure_along(&self, dir: DVec3) -> f64 {
        (0..self.patches.len()).map(|k| self.pressure_on(k, dir)).find(|&p| p > 0.0).unwrap_or(0.0)
    }

    /// The pressure (kPa) that patch `k` puts where unit `dir` meets the dome (0 off its grid).
    pub fn pressure_on(&self, k: usize, dir: DVec3) -> f64 {
        let p = &self.patches[k];
        p.project(self.radius_mm, dir).map_or(0.0, |st| p.pressure_at(st))
    }
}

impl super::Patch {
    /// The pressure (kPa) at map coordinates `[s, t]`: bilinear between nodes, 0 off the grid.
    pub fn pressure_at(&self, [s, t]: [f64; 2]) -> f64 {
        let (x, y) = ((s - self.origin_mm[0]) / self.spacing_mm, (t - self.origin_mm[1]) / self.spacing_mm);
        bilinear(self.size, x, y, |i, j| self.pressure_kpa[j * self.size[0] + i]).unwrap_or(0.0)
    }
}

/// The value at `(x, y)` (grid units) between the four nodes around it of a `size` grid read by
/// `at(i, j)`; `None` unless all four exist. The depth map and the patches' grids both use it.
pub(super) fn bilinear(size: [usize; 2], x: f64, y: f64, at: impl Fn(usize, usize) -> f64) -> Option<f64> {
    let (fx, fy) = (x.floor(), y.floor());
    if !(fx >= 0.0 && fy >= 0.0 && fx + 1.0 < size[0] as f64 && fy + 1.0 < size[1] as f64) {
        return None;
    }
    let (i, j) = (fx as usize, fy as usize);
    let (ax, ay) = (x - fx, y - fy);
    Some(
        (1.0 - ay) * ((1.0 - ax) * at(i, j) + ax * at(i + 1, j))
            + ay * ((1.0 - ax) * at(i, j + 1) + ax * at(i + 1, j + 1)),
    )
}
