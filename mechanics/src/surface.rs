//! The elastomer's surface under a solved contact: what the camera sees of the membrane.
//!
//! The half-space that solved the contact carries its forces to every other point of the
//! surface: a node's force `F` sinks the surface at distance `r` by `F / (pi E* r)` (Love's
//! element integral near the node, as in the solve). The surface does not depend on the modulus:
//! the forces scale with `E*`, the sink per newton with `1 / E*`. So a unit's stiffness shows in
//! its pressure labels, never in its images.
//!
//! Each sample sums two parts. Far from a patch, the patch's load acts as one point force at its
//! centre of load (inside the loaded area the point force is replaced by a uniform ball's smooth
//! potential, so that it stays finite there). Near a patch, what that lumping misses is computed
//! exactly on the patch's grid extended by half its size on every side, and faded out over the
//! extension's outer half, where it has fallen to a few per cent of the sink (the loads' second
//! moment over the cube of the distance).

use glam::DVec3;
use rayon::prelude::*;

use super::label::{Dome, bilinear};
use super::{Contact, Patch, from_map, halfspace};

/// Below this sink (mm) a sample off the contact keeps the no-contact surface: a micrometre over
/// the millimetres between samples tilts the normal far below a grey level.
pub const SINK_FLOOR_MM: f32 = 1e-3;

/// The most nodes a patch's extended grid holds (the exact sum costs nodes x loaded nodes).
const MAX_EXTENDED_NODES: usize = 12_000;

/// The widest lattice step (samples) on which the sink is summed exactly: 4 crop pixels are
/// about 0.55 mm, finer than the coarsest nodes' 2 mm.
const MAX_STRIDE: usize = 4;

/// One patch's load lumped at its centre: exact `c F / d` beyond `reach_mm`, a uniform ball's
/// potential `c F (3 - d^2 / reach^2) / (2 reach)` within it (equal in value and slope there).
struct Lump {
    centre: DVec3,
    force_n: f64,
    reach_mm: f64,
}

impl Lump {
    /// The sink (mm) per unit of compliance `c` at point `y`.
    fn at(&self, y: DVec3) -> f64 {
        let d2 = y.distance_squared(self.centre);
        let r2 = self.reach_mm * self.reach_mm;
        if d2 >= r2 { self.force_n / d2.sqrt() } else { self.force_n * (3.0 - d2 / r2) / (2.0 * self.reach_mm) }
    }
}

/// What the lumps miss near one patch, faded out towards the edge of its extended grid.
struct Near {
    patch: usize,
    origin_mm: [f64; 2],
    size: [usize; 2],
    values_mm: Vec<f64>,
    /// The grid samples whose rays can meet the extended grid: `[x0, y0, x1, y1]`, inclusive.
    window: [usize; 4],
}

/// One loaded node: its patch, its grid position, its point on the dome (mm) and its force (N).
struct Load {
    patch: usize,
    ij: [usize; 2],
    point: DVec3,
    force_n: f64,
}

impl Contact {
    /// How far the surface sinks (mm, inwards along each ray) at every sample of `dome`'s grid
    /// that sees elastomer; 0 elsewhere and where the sink stays under [`SINK_FLOOR_MM`].
    pub fn sink_mm(&self, dome: &Dome) -> Vec<f32> {
        let grid = *dome.grid();
        let mut out = vec![0f32; grid.len()];
        let r = self.radius_mm;
        let loads: Vec<Load> = self
            .patches
            .iter()
            .enumerate()
            .flat_map(|(k, p)| {
                (0..p.size[1]).flat_map(move |j| (0..p.size[0]).map(move |i| (k, p, i, j))).filter_map(
                    move |(k, p, i, j)| {
                        let kpa = p.pressure_kpa[j * p.size[0] + i];
                        (kpa > 0.0).then(|| Load {
                            patch: k,
                            ij: [i, j],
                            point: p.direction(r, i, j) * r,
                            force_n: kpa * 1e-3 * p.node_area_mm2(),
                        })
                    },
                )
            })
            .collect();
        if loads.is_empty() {
            return out;
        }
        let c = 1.0 / (std::f64::consts::PI * self.effective_modulus_mpa);
        let lumps: Vec<Lump> = (0..self.patches.len())
            .filter_map(|k| {
                let own = loads.iter().filter(|l| l.patch == k);
                let force_n: f64 = own.clone().map(|l| l.force_n).sum();
                (force_n > 0.0).then(|| {
                    let centre = own.clone().map(|l| l.point * l.force_n).sum::<DVec3>() / force_n;
                    let spread = own.map(|l| l.point.distance(centre)).fold(0f64, f64::max);
                    Lump { centre, force_n, reach_mm: spread + self.patches[k].spacing_mm }
                })
            })
            .collect();
        let lumped = |y: DVec3| c * lumps.iter().map(|l| l.at(y)).sum::<f64>();
        let near: Vec<Near> = (0..self.patches.len())
            .filter(|&k| loads.iter().any(|l| l.patch == k))
            .map(|k| self.near(k, &loads, c, &lumped, dome))
            .collect();
        let width = grid.width as usize;
        let height = grid.height as usize;
        // The sink at sample (x, y), or None where it sees no elastomer.
        let exact = |x: usize, y: usize| -> Option<f64> {
            let dir = dome.dir(y * width + x);
            if dir == DVec3::ZERO {
                return None;
            }
            let mut sink = lumped(dir * r);
            for n in &near {
                let [x0, y0, x1, y1] = n.window;
                if x < x0 || x > x1 || y < y0 || y > y1 {
                    continue;
                }
                let p = &self.patches[n.patch];
                if let Some([s, t]) = p.project(r, dir) {
                    let (gx, gy) = ((s - n.origin_mm[0]) / p.spacing_mm, (t - n.origin_mm[1]) / p.spacing_mm);
                    sink += bilinear(n.size, gx, gy, |a, b| n.values_mm[b * n.size[0] + a]).unwrap_or(0.0);
                }
            }
            Some(sink)
        };
        // Exact on a lattice of every `stride`-th sample (the last row and column included),
        // bilinear in between: the surface is smooth on the scale of the solve's nodes, and one
        // exact sum per sample was most of a frame's cost. A sample with a corner off the
        // elastomer gets its own sum.
        let finest_mm = near.iter().map(|n| self.patches[n.patch].spacing_mm).fold(f64::INFINITY, f64::min);
        let stride = ((finest_mm / dome.mm_per_step()).floor() as usize).clamp(1, MAX_STRIDE);
        // Lattice lines at whole multiples of the stride in frame pixels (and the grid's edges),
        // so that a crop and the whole frame place them alike and render the same press the same.
        let axis = |len: usize, origin_px: f64| -> Vec<usize> {
            let first = (origin_px / grid.step_px).round() as i64;
            let mut at: Vec<usize> = (0..len)
                .filter(|&v| v == 0 || v == len - 1 || (first + v as i64).rem_euclid(stride as i64) == 0)
                .collect();
            at.dedup();
            at
        };
        let (xs, ys) = (axis(width, grid.origin_u_px), axis(height, grid.origin_v_px));
        let lattice: Vec<Option<f64>> = (0..xs.len() * ys.len())
            .into_par_iter()
            .with_min_len(64)
            .map(|k| exact(xs[k % xs.len()], ys[k / xs.len()]))
            .collect();
        let cell = |v: usize, at: &[usize]| -> (usize, f64) {
            let k = (at.partition_point(|&a| a <= v) - 1).min(at.len() - 2);
            (k, (v - at[k]) as f64 / (at[k + 1] - at[k]) as f64)
        };
        // Each column's and row's lattice cell and weight, once.
        let cells = |len: usize, at: &[usize]| -> Vec<(usize, usize, f64)> {
            (0..len)
                .map(|v| {
                    if at.len() < 2 {
                        return (0, 0, 0.0);
                    }
                    let (k, f) = cell(v, at);
                    (k, k + 1, f)
                })
                .collect()
        };
        let (cols, rows) = (cells(width, &xs), cells(height, &ys));
        out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
            let (j0, j1, fy) = rows[y];
            let (above, below) = (&lattice[j0 * xs.len()..][..xs.len()], &lattice[j1 * xs.len()..][..xs.len()]);
            let seen = &dome.dirs()[y * width..][..width];
            for (x, o) in row.iter_mut().enumerate() {
                if seen[x] == glam::Vec3::ZERO {
                    continue;
                }
                let (i0, i1, fx) = cols[x];
                let sink = match (above[i0], above[i1], below[i0], below[i1]) {
                    (Some(a), Some(b), Some(c), Some(d)) => {
                        (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d)
                    }
                    _ => exact(x, y).unwrap_or(0.0),
                };
                let sink = sink as f32;
                *o = if sink >= SINK_FLOOR_MM { sink } else { 0.0 };
            }
        });
        out
    }

    /// Patch `k`'s grid extended by half its size on every side: the exact sink at each node
    /// (its own loads through Love's element integral, the others' as point forces) less the
    /// lumped one, faded to zero at the edge.
    fn near(&self, k: usize, loads: &[Load], c: f64, lumped: &(impl Fn(DVec3) -> f64 + Sync), dome: &Dome) -> Near {
        let p: &Patch = &self.patches[k];
        let r = self.radius_mm;
        let mut margin = p.size[0].max(p.size[1]).div_ceil(2).max(2);
        while margin > 2 && (p.size[0] + 2 * margin) * (p.size[1] + 2 * margin) > MAX_EXTENDED_NODES {
            margin -= 1;
        }
        let size = [p.size[0] + 2 * margin, p.size[1] + 2 * margin];
        let h = p.spacing_mm;
        let origin_mm = [p.origin_mm[0] - margin as f64 * h, p.origin_mm[1] - margin as f64 * h];
        // The own loads' sink per newton depends on the index offset only (as in the solve).
        let area = p.node_area_mm2();
        let table: Vec<f64> = (0..size[0] * size[1])
            .map(|o| {
                c * halfspace::rectangle_integral_mm(
                    (o % size[0]) as f64 * h,
                    (o / size[0]) as f64 * h,
                    h / 2.0,
                    h / 2.0,
                ) / area
            })
            .collect();
        let fade_nodes = (margin as f64 / 2.0).max(1.0);
        let values_mm: Vec<f64> = (0..size[0] * size[1])
            .into_par_iter()
            .with_min_len(64)
            .map(|o| {
                let (a, b) = (o % size[0], o / size[0]);
                let st = [origin_mm[0] + a as f64 * h, origin_mm[1] + b as f64 * h];
                let y = from_map(p.normal, p.e1, p.e2, r, st) * r;
                let exact: f64 = loads
                    .iter()
                    .map(|l| {
                        if l.patch == k {
                            let (di, dj) = (
                                (a as i64 - margin as i64 - l.ij[0] as i64).unsigned_abs() as usize,
                                (b as i64 - margin as i64 - l.ij[1] as i64).unsigned_abs() as usize,
                            );
                            l.force_n * table[dj * size[0] + di]
                        } else {
                            c * l.force_n / y.distance(l.point).max(1e-9)
                        }
                    })
                    .sum();
                let edge = a.min(b).min(size[0] - 1 - a).min(size[1] - 1 - b) as f64;
                let f = (edge / fade_nodes).min(1.0);
                (exact - lumped(y)) * f * f * (3.0 - 2.0 * f)
            })
            .collect();
        // The grid samples that can see the extended grid: its outline's nodes through the lens,
        // a sample beyond on every side; the whole grid where part of it is out of the lens' view.
        let g = dome.grid();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let mut whole = false;
        for o in 0..size[0] * size[1] {
            let (a, b) = (o % size[0], o / size[0]);
            if a != 0 && b != 0 && a != size[0] - 1 && b != size[1] - 1 {
                continue;
            }
            let st = [origin_mm[0] + a as f64 * h, origin_mm[1] + b as f64 * h];
            match dome.grid_position(from_map(p.normal, p.e1, p.e2, r, st)) {
                Some((x, y)) => {
                    lo = [lo[0].min(x), lo[1].min(y)];
                    hi = [hi[0].max(x), hi[1].max(y)];
                }
                None => whole = true,
            }
        }
        let clip = |v: f64, n: u32| (v.max(0.0) as usize).min(n as usize - 1);
        let window = if whole || !lo[0].is_finite() {
            [0, 0, g.width as usize - 1, g.height as usize - 1]
        } else {
            [
                clip(lo[0] - 1.0, g.width),
                clip(lo[1] - 1.0, g.height),
                clip(hi[0] + 2.0, g.width),
                clip(hi[1] + 2.0, g.height),
            ]
        };
        Near { patch: k, origin_mm, size, values_mm, window }
    }
}
