//! Contact mechanics of the elastomer: how hard an indenter presses, from where it overlaps the
//! dome.
//!
//! The model is the one Hertz's and Boussinesq's closed forms rest on: a linear-elastic,
//! isotropic half-space under frictionless normal load. Each connected region where the scene
//! overlaps the dome gets a patch: a square grid in azimuthal-equidistant coordinates about the
//! region's centre (near it, the tangent plane), each node seeing the dome (and the indenter)
//! along its own radial ray; regions whose grids would overlap share one. The dome's curvature
//! enters only through the gap between dome and indenter, as in Hertz's theory; nodes of one
//! patch interact through Love's closed form for a uniformly loaded square, nodes of different
//! patches as point forces. The contact forces solve a complementarity problem (no pull, no
//! penetration; `lcp`).
//!
//! What a linear half-space cannot do: large strain (it is accurate while the contact stays small
//! against the dome's 25 mm radius and the indentation small against the contact), friction and
//! shear (the contact is frictionless, so every force passes through the dome's centre and the
//! torque about it vanishes), the thin-layer stiffening near the rigid mount (the hemisphere is
//! solid, so a contact on its side sees a half-space only while it stays small against the
//! distance to the base).

// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod halfspace;
mod label;
mod lcp;
mod surface;

pub use label::{Dome, ForceLabel, force_label};
pub use sensor::Wrench;

use faer::Mat;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The elastomer's material: linear elastic and isotropic.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Young's modulus (MPa, that is N/mm^2).
    pub youngs_modulus_mpa: f64,
    /// Poisson's ratio (silicone is nearly incompressible: close to 0.5).
    pub poisson_ratio: f64,
}

impl Material {
    /// The paper's P-565 silicone at 20:1, 6.5 Shore A. Gent's relation between Shore A hardness
    /// and Young's modulus gives 0.32 MPa at 6.5 (it is fitted on harder rubbers, so this is an
    /// estimate, not a measurement); a cured silicone's Poisson ratio is 0.46-0.499.
    pub const PAPER: Material = Material { youngs_modulus_mpa: 0.32, poisson_ratio: 0.48 };

    /// A material of effective modulus `e_star_mpa`: all that a frictionless contact's pressure
    /// and the pressed surface depend on (they scale with it; the contact set does not move),
    /// so this is what a unit's force labels or a force-torque sensor's readings can fit.
    pub fn with_effective_modulus(e_star_mpa: f64) -> Material {
        Material { youngs_modulus_mpa: e_star_mpa, poisson_ratio: 0.0 }
    }

    /// The plane-strain modulus a rigid indenter meets, `E / (1 - nu^2)` (MPa).
    pub fn effective_modulus_mpa(&self) -> f64 {
        self.youngs_modulus_mpa / (1.0 - self.poisson_ratio * self.poisson_ratio)
    }

    /// Checks the numbers; the error says which is wrong.
    pub fn validate(&self) -> Result<(), MechanicsError> {
        if !(self.youngs_modulus_mpa > 0.0 && self.youngs_modulus_mpa.is_finite()) {
            return Err(MechanicsError::Material(format!(
                "Young's modulus must be > 0 MPa, got {}",
                self.youngs_modulus_mpa
            )));
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return Err(MechanicsError::Material(format!(
                "Poisson's ratio must lie in (-1, 0.5), got {}",
                self.poisson_ratio
            )));
        }
        Ok(())
    }
}

/// How finely patches are gridded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridConfig {
    /// Nodes over a region's bounding box (before its margin): the spacing follows the region's
    /// size, so a small contact is not solved on two nodes.
    pub nodes_per_region: usize,
    /// Nodes over all regions' bounding boxes together: a large contact is solved coarser
    /// rather than on ten thousand nodes (the solve's cost grows with their cube).
    pub max_nodes: usize,
    /// Spacing bounds (mm).
    pub min_spacing_mm: f64,
    pub max_spacing_mm: f64,
}

impl Default for GridConfig {
    fn default() -> Self {
        GridConfig { nodes_per_region: 400, max_nodes: 300, min_spacing_mm: 0.02, max_spacing_mm: 2.0 }
    }
}

impl GridConfig {
    /// The same grids with every spacing halved (the convergence check).
    pub fn halved(self) -> Self {
        GridConfig {
            nodes_per_region: self.nodes_per_region * 4,
            max_nodes: self.max_nodes * 4,
            min_spacing_mm: self.min_spacing_mm / 2.0,
            max_spacing_mm: self.max_spacing_mm / 2.0,
        }
    }
}

/// Why a contact could not be solved.
#[derive(Debug, thiserror::Error)]
pub enum MechanicsError {
    #[error("elastomer: {0}")]
    Material(String),
    #[error("the contact's influence matrix over {nodes} nodes is not positive definite")]
    NotPositiveDefinite { nodes: usize },
    #[error("the contact over {nodes} nodes did not settle in {steps} pivoting steps")]
    NoConvergence { nodes: usize, steps: usize },
}

/// One region's grid on the dome, in azimuthal-equidistant map coordinates about `normal`
/// (distance along the dome from it, in the direction `(e1, e2)`): node `(i, j)` sits at map
/// coordinates `origin + spacing * (i, j)` and stands for that point of the dome. Near the
/// normal the map is the tangent plane; a region reaching far round the dome keeps true
/// distances along the dome from its centre, so no region projects to a plane without end.
#[derive(Clone, Debug)]
pub struct Patch {
    pub normal: DVec3,
    pub e1: DVec3,
    pub e2: DVec3,
    pub spacing_mm: f64,
    pub origin_mm: [f64; 2],
    /// Nodes along `e1` and `e2`.
    pub size: [usize; 2],
    /// How far the scene reaches inside the dome along each node's ray (mm; negative: a gap,
    /// `-inf`: nothing on the ray), row-major with `e1` fastest.
    pub interference_mm: Vec<f64>,
    /// Contact pressure at each node (kPa).
    pub pressure_kpa: Vec<f64>,
}

impl Patch {
    pub(crate) fn plane_mm(&self, i: usize, j: usize) -> [f64; 2] {
        [self.origin_mm[0] + self.spacing_mm * i as f64, self.origin_mm[1] + self.spacing_mm * j as f64]
    }

    /// Unit direction of node `(i, j)`'s ray, for a dome of `radius_mm`.
    fn direction(&self, radius_mm: f64, i: usize, j: usize) -> DVec3 {
        let [s, t] = self.plane_mm(i, j);
        from_map(self.normal, self.e1, self.e2, radius_mm, [s, t])
    }

    /// Map coordinates of the dome point along unit `dir` (None at the patch's antipode).
    fn project(&self, radius_mm: f64, dir: DVec3) -> Option<[f64; 2]> {
        to_map(self.normal, self.e1, self.e2, radius_mm, dir)
    }

    pub(crate) fn node_area_mm2(&self) -> f64 {
        self.spacing_mm * self.spacing_mm
    }
}

/// A solved contact: every region's patch with its pressures.
#[derive(Clone, Debug)]
pub struct Contact {
    pub radius_mm: f64,
    /// The plane-strain modulus the contact was solved with (MPa): what turns its forces back
    /// into the surface's displacement.
    pub effective_modulus_mpa: f64,
    pub patches: Vec<Patch>,
    /// The patch that solved each region given to [`solve`] (`None` for an empty one).
    pub region_patch: Vec<Option<usize>>,
    /// Pivoting steps the complementarity solve took.
    pub steps: usize,
}

impl Contact {
    fn nodes(&self) -> impl Iterator<Item = (DVec3, f64)> + '_ {
        self.patches.iter().flat_map(move |p| {
            (0..p.size[1]).flat_map(move |j| (0..p.size[0]).map(move |i| (p, i, j))).filter_map(move |(p, i, j)| {
                let kpa = p.pressure_kpa[j * p.size[0] + i];
                (kpa > 0.0).then(|| (p.direction(self.radius_mm, i, j), kpa * 1e-3 * p.node_area_mm2()))
            })
        })
    }

    /// The sum of the nodes' normal forces (N): what a load cell under a centred indenter reads.
    pub fn total_normal_force_n(&self) -> f64 {
        self.nodes().map(|(_, f)| f).sum()
    }

    /// The area carrying pressure (mm^2, on the patches' planes).
    pub fn contact_area_mm2(&self) -> f64 {
        self.patches
            .iter()
            .map(|p| p.pressure_kpa.iter().filter(|&&k| k > 0.0).count() as f64 * p.node_area_mm2())
            .sum()
    }

    /// Force and torque on the sensor: each node pushes the surface towards the dome's centre.
    pub fn wrench(&self) -> Wrench {
        let (mut force, mut torque) = (DVec3::ZERO, DVec3::ZERO);
        for (dir, f) in self.nodes() {
            let push = -dir * f;
            force += push;
            torque += (dir * self.radius_mm).cross(push);
        }
        Wrench { force_n: force.to_array(), torque_nmm: torque.to_array() }
    }
}

/// Solves the frictionless contact on a dome of `radius_mm`: `regions` are the directions (unit,
/// sensor frame) where the scene overlaps the dome, one list per connected region (the depth
/// map's contact pixels, for instance); `interference_mm` says how far the scene reaches inside
/// the dome along a unit direction (negative for a gap).
pub fn solve(
    radius_mm: f64,
    material: &Material,
    grid: &GridConfig,
    regions: &[Vec<DVec3>],
    interference_mm: impl Fn(DVec3) -> f64 + Sync,
) -> Result<Contact, MechanicsError> {
    material.validate()?;
    let (mut patches, region_patch) = patches_over(radius_mm, grid, regions);
    for p in &mut patches {
        let n = p.size[0] * p.size[1];
        p.interference_mm = (0..n)
            .into_par_iter()
            .with_min_len(64)
            .map(|k| interference_mm(p.direction(radius_mm, k % p.size[0], k / p.size[0])))
            .collect();
        p.pressure_kpa = vec![0.0; n];
    }
    // The candidates: nodes the scene overlaps (no other can touch, as the surface only sinks).
    let candidates: Vec<(usize, usize)> = patches
        .iter()
        .enumerate()
        .flat_map(|(pi, p)| p.interference_mm.iter().enumerate().filter(|(_, d)| **d > 0.0).map(move |(k, _)| (pi, k)))
        .collect();
    let g = influence(radius_mm, material, &patches, &candidates);
    let delta: Vec<f64> = candidates.iter().map(|&(pi, k)| patches[pi].interference_mm[k]).collect();
    // First guess: a node is in contact where it overlaps by at least half its patch's deepest
    // overlap (exact for Hertz's sphere, whose contact edge lies where the overlap is half).
    let deepest: Vec<f64> = patches.iter().map(|p| p.interference_mm.iter().fold(0f64, |m, &d| m.max(d))).collect();
    let start: Vec<bool> = candidates.iter().zip(&delta).map(|(&(pi, _), &d)| d >= 0.5 * deepest[pi]).collect();
    let (forces, steps) = lcp::solve(&g, &delta, &start)?;
    for (&(pi, k), f) in candidates.iter().zip(forces) {
        let p = &mut patches[pi];
        p.pressure_kpa[k] = f / p.node_area_mm2() * 1e3;
    }
    Ok(Contact { radius_mm, effective_modulus_mpa: material.effective_modulus_mpa(), patches, region_patch, steps })
}

/// `G[a][b]`: how far candidate `a` sinks (mm) under a unit force (N) on candidate `b`.
fn influence(radius_mm: f64, material: &Material, patches: &[Patch], candidates: &[(usize, usize)]) -> Mat<f64> {
    let c = 1.0 / (std::f64::consts::PI * material.effective_modulus_mpa());
    let at = |&(pi, k): &(usize, usize)| {
        let p = &patches[pi];
        (
            pi,
            (k % p.size[0]) as i64,
            (k / p.size[0]) as i64,
            p.direction(radius_mm, k % p.size[0], k / p.size[0]) * radius_mm,
        )
    };
    let nodes: Vec<_> = candidates.iter().map(at).collect();
    // Within a patch the coefficient depends on the index offset only: one table per patch.
    let tables: Vec<Vec<f64>> = patches
        .iter()
        .map(|p| {
            let half = p.spacing_mm / 2.0;
            let area = p.node_area_mm2();
            (0..p.size[1])
                .flat_map(|dj| (0..p.size[0]).map(move |di| (di, dj)))
                .map(|(di, dj)| {
                    c * halfspace::rectangle_integral_mm(di as f64 * p.spacing_mm, dj as f64 * p.spacing_mm, half, half)
                        / area
                })
                .collect()
        })
        .collect();
    let n = nodes.len();
    let mut g = Mat::zeros(n, n);
    for a in 0..n {
        let (pa, ia, ja, xa) = nodes[a];
        for b in a..n {
            let (pb, ib, jb, xb) = nodes[b];
            let value = if pa == pb {
                let size = patches[pa].size[0];
                tables[pa][(ja - jb).unsigned_abs() as usize * size + (ia - ib).unsigned_abs() as usize]
            } else {
                // Nodes of two patches, whose grids do not overlap: point forces.
                c / xa.distance(xb)
            };
            g[(a, b)] = value;
            g[(b, a)] = value;
        }
    }
    g
}

/// One patch per region; regions whose grids overlap are merged into one, so that no point of
/// the dome belongs to two grids. A predicted depth map shows a contact as a score of regions
/// (a frame of the quickstart's test split: 20 to 25, most a few pixels), merged one pair at a
/// time; so each group's footprint is computed again only when a merge changes it, and a group
/// whose directions all lie farther from a patch than its grid reaches is not projected onto it.
/// Both leave every decision as it was: the same patches, merged in the same order
/// (`tests::patches_are_those_of_the_plain_merge`).
fn patches_over(radius_mm: f64, grid: &GridConfig, regions: &[Vec<DVec3>]) -> (Vec<Patch>, Vec<Option<usize>>) {
    let mut groups: Vec<Vec<DVec3>> = regions.iter().filter(|r| !r.is_empty()).cloned().collect();
    // Which group each region is in.
    let mut group_of: Vec<Option<usize>> = Vec::with_capacity(regions.len());
    for r in regions {
        group_of.push((!r.is_empty()).then(|| group_of.iter().flatten().count()));
    }
    let mut footprints: Vec<Footprint> = groups.iter().map(|dirs| Footprint::of(radius_mm, dirs)).collect();
    loop {
        // Each region's own share of nodes, and the whole scene within its budget: a contact
        // that covers half the dome is solved coarser, not on ten thousand nodes.
        let total: f64 = footprints.iter().map(Footprint::area_mm2).sum();
        let coarsest = (total / grid.max_nodes.max(1) as f64).sqrt();
        let patches: Vec<Patch> = footprints
            .iter()
            .map(|f| {
                let own = (f.area_mm2() / grid.nodes_per_region.max(1) as f64).sqrt();
                f.grid(own.max(coarsest).clamp(grid.min_spacing_mm, grid.max_spacing_mm))
            })
            .collect();
        let overlap = (0..patches.len()).flat_map(|a| (a + 1..patches.len()).map(move |b| (a, b))).find(|&(a, b)| {
            let (pa, pb) = (&patches[a], &patches[b]);
            // Grids overlap when a corner or the centre of one lies in the other.
            let probe = |p: &Patch, q: &Patch| {
                let [i1, j1] = [p.size[0] - 1, p.size[1] - 1];
                [(0, 0), (i1, 0), (0, j1), (i1, j1), (i1 / 2, j1 / 2)]
                    .iter()
                    .any(|&(i, j)| q.project(radius_mm, p.direction(radius_mm, i, j)).is_some_and(|st| q.holds(st)))
            };
            probe(pa, pb)
                || probe(pb, pa)
                || (!footprints[b].beyond_reach(pa, radius_mm)
                    && groups[b].iter().any(|&d| pa.project(radius_mm, d).is_some_and(|st| pa.holds(st))))
        });
        match overlap {
            Some((a, b)) => {
                let moved = groups.remove(b);
                groups[a].extend(moved);
                footprints.remove(b);
                footprints[a] = Footprint::of(radius_mm, &groups[a]);
                for g in group_of.iter_mut().flatten() {
                    if *g == b {
                        *g = a;
                    } else if *g > b {
                        *g -= 1;
                    }
                }
            }
            None => return (patches, group_of),
        }
    }
}

/// The dome point (unit direction) at azimuthal-equidistant coordinates `st` (mm) about `normal`.
fn from_map(normal: DVec3, e1: DVec3, e2: DVec3, radius_mm: f64, [s, t]: [f64; 2]) -> DVec3 {
    let rho = s.hypot(t);
    if rho == 0.0 {
        return normal;
    }
    let angle = rho / radius_mm;
    normal * angle.cos() + (e1 * s + e2 * t) * (angle.sin() / rho)
}

/// The azimuthal-equidistant coordinates (mm) of unit `dir` about `normal` (None at the antipode).
fn to_map(normal: DVec3, e1: DVec3, e2: DVec3, radius_mm: f64, dir: DVec3) -> Option<[f64; 2]> {
    let (a, b) = (dir.dot(e1), dir.dot(e2));
    let side = (a * a + b * b).sqrt();
    let angle = angle_from(side, dir.dot(normal));
    if angle > std::f64::consts::PI - 1e-6 {
        return None;
    }
    if side == 0.0 {
        return Some([0.0, 0.0]);
    }
    let scale = radius_mm * angle / side;
    Some([a * scale, b * scale])
}

/// `atan2(side, along)` for `side >= 0` (radians, 0..pi), within 1e-8 of libm's at a fraction
/// of its cost: every pixel of a contact is mapped once per label.
fn angle_from(side: f64, along: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    if along >= side {
        if along == 0.0 { 0.0 } else { atan_unit(side / along) }
    } else if along > -side {
        FRAC_PI_2 - atan_unit(along / side)
    } else {
        PI - atan_unit(side / -along)
    }
}

/// `atan(x)` for `|x| <= 1`: arguments beyond tan(pi / 12) are moved below it by
/// `atan x = pi / 6 + atan((x sqrt 3 - 1) / (x + sqrt 3))`, where the Taylor series to x^11
/// errs by under x^13 / 13 < 3e-9.
fn atan_unit(x: f64) -> f64 {
    const TAN_PI_12: f64 = 0.267_949_192_431_122_7;
    const SQRT_3: f64 = 1.732_050_807_568_877_2;
    let (sign, x) = if x < 0.0 { (-1.0, -x) } else { (1.0, x) };
    let (base, y) =
        if x > TAN_PI_12 { (std::f64::consts::FRAC_PI_6, (x * SQRT_3 - 1.0) / (x + SQRT_3)) } else { (0.0, x) };
    let y2 = y * y;
    let series = y * (1.0 - y2 * (1.0 / 3.0 - y2 * (1.0 / 5.0 - y2 * (1.0 / 7.0 - y2 * (1.0 / 9.0 - y2 / 11.0)))));
    sign * (base + series)
}

/// Two unit axes spanning the plane normal to `normal` (continuous away from -z).
fn tangent_axes(normal: DVec3) -> (DVec3, DVec3) {
    let e1 = if normal.z > -0.9 { DVec3::Y.cross(normal) } else { DVec3::X.cross(normal) };
    let e1 = e1.try_normalize().unwrap_or(DVec3::X);
    (e1, normal.cross(e1))
}

impl Patch {
    fn holds(&self, [s, t]: [f64; 2]) -> bool {
        let end = self.plane_mm(self.size[0] - 1, self.size[1] - 1);
        (self.origin_mm[0]..=end[0]).contains(&s) && (self.origin_mm[1]..=end[1]).contains(&t)
    }
}

/// A region on its map: the map's axes and the region's bounding box on it.
struct Footprint {
    normal: DVec3,
    e1: DVec3,
    e2: DVec3,
    lo: [f64; 2],
    hi: [f64; 2],
    /// Whether every direction had map coordinates (none at the normal's antipode).
    mapped_all: bool,
}

/// The farthest a box `[lo, hi]` of map coordinates reaches from the map's origin (mm): an upper
/// bound of every point's distance in it.
fn box_reach_mm(lo: [f64; 2], hi: [f64; 2]) -> f64 {
    lo[0].abs().max(hi[0].abs()).hypot(lo[1].abs().max(hi[1].abs()))
}

impl Footprint {
    fn of(radius_mm: f64, dirs: &[DVec3]) -> Self {
        let normal = dirs.iter().copied().sum::<DVec3>().try_normalize().unwrap_or(DVec3::Z);
        let (e1, e2) = tangent_axes(normal);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let mut mapped_all = true;
        for &d in dirs {
            if let Some(st) = to_map(normal, e1, e2, radius_mm, d) {
                for k in 0..2 {
                    lo[k] = lo[k].min(st[k]);
                    hi[k] = hi[k].max(st[k]);
                }
            } else {
                mapped_all = false;
            }
        }
        if !lo[0].is_finite() {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        Footprint { normal, e1, e2, lo, hi, mapped_all }
    }

    /// Whether none of this footprint's directions can land on `patch`'s grid. A map distance is
    /// the dome's radius times the angle from the map's normal (to within the fast angle's 1e-8
    /// rad, far inside the margin), so each direction lies within `box_reach_mm` of this
    /// footprint's normal, and every point of the grid within its own box's reach of the patch's
    /// normal: directions farther apart than both reaches cannot meet it.
    fn beyond_reach(&self, patch: &Patch, radius_mm: f64) -> bool {
        const MARGIN_RAD: f64 = 1e-6;
        if !self.mapped_all {
            return false;
        }
        let end = patch.plane_mm(patch.size[0] - 1, patch.size[1] - 1);
        let apart_rad = self.normal.cross(patch.normal).length().atan2(self.normal.dot(patch.normal));
        (apart_rad - MARGIN_RAD) * radius_mm - box_reach_mm(self.lo, self.hi) > box_reach_mm(patch.origin_mm, end)
    }

    fn area_mm2(&self) -> f64 {
        ((self.hi[0] - self.lo[0]) * (self.hi[1] - self.lo[1])).max(1e-6)
    }

    /// The grid over the region at `spacing_mm`, two nodes beyond it on every side (its pixels
    /// sample the overlap, they do not bound it), centred on it.
    fn grid(&self, spacing_mm: f64) -> Patch {
        let margin = 2.0 * spacing_mm;
        let count = |k: usize| ((self.hi[k] - self.lo[k] + 2.0 * margin) / spacing_mm).ceil() as usize + 1;
        let size = [count(0), count(1)];
        let origin = |k: usize| (self.lo[k] + self.hi[k]) / 2.0 - (size[k] - 1) as f64 * spacing_mm / 2.0;
        Patch {
            normal: self.normal,
            e1: self.e1,
            e2: self.e2,
            spacing_mm,
            origin_mm: [origin(0), origin(1)],
            size,
            interference_mm: Vec::new(),
            pressure_kpa: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests;
