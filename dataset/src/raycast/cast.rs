//! The tiled cast: a block of tiles gathers the triangles its rays may reach (ball against
//! cone scans), each tile sorts them by distance and tests them against its rays in lanes,
//! stopping once the next lies beyond every ray's nearest hit.

use formats::dataset::CastStats;
use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use sensor::{DepthMap, Sensor};

use super::Skipping;
#[cfg(target_arch = "x86_64")]
use super::lanes::Avx2Kernel;
use super::lanes::{GroupKernel, Lanes, Portable};
use super::rays::{BallView, BallViews, BlockCones, Cone, RayBundle};
use super::triangle::{OriginTriangle, grid_scale, may_reach, near_bound};
use crate::mesh::Mesh;
#[cfg(target_arch = "x86_64")]
use crate::simd::Avx2;

/// A triangle handed to a tile: its lower distance bound (made non-negative, so that its bits
/// order as the number does) above its index, so that sorting plain integers orders candidates by
/// distance.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Candidate(u64);

impl Candidate {
    #[inline(always)]
    fn new(near: f32, triangle: u32) -> Self {
        // Adding zero turns -0 (whose sign bit would sort it last) into +0.
        let near = near.max(0.0) + 0.0;
        Candidate(((near.to_bits() as u64) << 32) | triangle as u64)
    }

    #[inline(always)]
    fn parts(self) -> (f32, u32) {
        (f32::from_bits((self.0 >> 32) as u32), self.0 as u32)
    }
}

/// Buffers reused from block to block by one worker.
#[derive(Default)]
struct Scratch {
    lists: Vec<Vec<Candidate>>,
    /// The triangles a block's cone may meet.
    near_block: Vec<u32>,
    lanes: Vec<Lanes>,
}

/// Per-triangle bounds used to gather candidates for a tile.
#[derive(Clone, Copy, Debug)]
struct TriangleBounds {
    /// Bounding ball, as seen from the origin.
    ball: BallView,
    /// Lower bound on the distance from the origin to any point of the triangle.
    near: f32,
}

/// A scene's triangles, ready to cast the sensor's rays into.
pub struct RayCaster {
    pub(super) triangles: Vec<OriginTriangle>,
    bounds: Vec<TriangleBounds>,
    /// The bounds' balls again, in the form a block's cone scans eight at a time.
    views: BallViews,
    /// The kept triangles' snapped corners, for the single-ray reference.
    pub(super) corners: Vec<[Vec3; 3]>,
    /// A BVH over `corners`, built on the single-ray reference's first use: the tiled path
    /// needs none, since a scan of every triangle's ball per block of rays costs less than
    /// building one.
    pub(super) reference_bvh: std::sync::OnceLock<obvhs::bvh2::Bvh2>,
    cones: Option<Vec<Cone>>,
    radius_mm: f32,
    skipping: Skipping,
    triangles_total: usize,
    /// How far the reference BVH's boxes are widened beyond rounding.
    pub(super) pad_mm: f32,
}

impl RayCaster {
    /// Builds the caster for a scene made of `parts` (sensor frame, mm) and a sensor of `radius_mm`.
    pub fn new(parts: &[&Mesh], radius_mm: f64, skipping: Skipping) -> Self {
        // One grid for the whole scene, whatever is dropped, so skipping cannot move a vertex.
        let max_abs = parts.iter().flat_map(|p| &p.vertices).map(|v| v.abs().max_element()).fold(0.0, f32::max);
        let scale = grid_scale(max_abs);
        let inv_scale = 1.0 / scale; // exact: a power of two
        // Round to nearest by the 1.5 * 2^23 trick: exact for |v * scale| < 2^22 (which
        // grid_scale guarantees) and far cheaper than a libm call per coordinate.
        let snap = |v: Vec3| {
            let magic = Vec3::splat(1.5 * (1u32 << 23) as f32);
            ((v * scale + magic) - magic) * inv_scale
        };
        let mut kept: Vec<([Vec3; 3], f32)> = Vec::new();
        let mut cones = Some(Vec::new());
        let mut triangles_total = 0;
        for part in parts {
            triangles_total += part.triangles.len();
            let start = kept.len();
            // Each vertex is shared by several triangles: snap it (and measure it) once.
            let verts: Vec<Vec3> = part.vertices.par_iter().with_min_len(4096).map(|&v| snap(v)).collect();
            let len2: Vec<f32> = verts.iter().map(|v| v.length_squared()).collect();
            let reaching: Vec<u32> = (0..part.triangles.len() as u32)
                .into_par_iter()
                .with_min_len(1024)
                .filter(|&i| {
                    let ids = part.triangles[i as usize];
                    skipping == Skipping::Off
                        || may_reach(ids.map(|k| verts[k as usize]), ids.map(|k| len2[k as usize]), radius_mm)
                })
                .collect();
            kept.par_extend(reaching.par_iter().with_min_len(1024).map(|&i| {
                let tri = part.triangles[i as usize].map(|k| verts[k as usize]);
                (tri, near_bound(tri))
            }));
            if skipping == Skipping::On && kept.len() > start {
                // The cone of the part's kept vertices, each counted once.
                let mut used = vec![false; verts.len()];
                for &i in &reaching {
                    for k in part.triangles[i as usize] {
                        used[k as usize] = true;
                    }
                }
                let dirs = verts.iter().zip(&used).filter(|(_, u)| **u).map(|(&v, _)| Vec3A::from(v));
                match (Cone::around_directions(dirs), cones.as_mut()) {
                    (Some(c), Some(list)) => list.push(c),
                    _ => cones = None,
                }
            }
        }
        if skipping == Skipping::Off {
            cones = None;
        }
        let triangles = kept.par_iter().with_min_len(1024).map(|(t, _)| OriginTriangle::new(*t, scale)).collect();
        let bounds: Vec<TriangleBounds> = kept
            .par_iter()
            .with_min_len(1024)
            .map(|&(t, near)| {
                let [a, b, c] = t.map(Vec3A::from);
                let centre = (a + b + c) / 3.0;
                let radius = centre.distance(a).max(centre.distance(b)).max(centre.distance(c)) * 1.0001 + 1e-6;
                TriangleBounds { ball: BallView::new(centre, radius), near }
            })
            .collect();
        RayCaster {
            triangles,
            views: BallViews::new(bounds.iter().map(|b| b.ball)),
            bounds,
            corners: kept.into_iter().map(|(t, _)| t).collect(),
            reference_bvh: std::sync::OnceLock::new(),
            cones,
            radius_mm: radius_mm as f32,
            skipping,
            triangles_total,
            pad_mm: max_abs.max(1.0) * 1e-5,
        }
    }

    pub fn triangles_kept(&self) -> usize {
        self.triangles.len()
    }

    pub(super) fn t_max(&self) -> f32 {
        if self.skipping == Skipping::On { self.radius_mm } else { f32::INFINITY }
    }

    fn wanted(&self, dir: Vec3A) -> bool {
        match &self.cones {
            Some(cones) => cones.iter().any(|c| c.contains(dir)),
            None => true,
        }
    }

    /// Hands each triangle that a block's rays may reach to the block's tiles whose cones may
    /// meet it (bit `k` of `active`: tile `k`): one SIMD scan of every triangle's ball against
    /// the block's cone, then the few that pass against the tiles' cones, 64 at once.
    /// `lists[k]` receives tile `k`'s candidates.
    #[inline(always)]
    fn gather<K: GroupKernel>(
        &self,
        kernel: K,
        block_cone: Option<&Cone>,
        active: u64,
        cones: &BlockCones,
        lists: &mut [Vec<Candidate>],
        near_block: &mut Vec<u32>,
    ) {
        near_block.clear();
        match block_cone {
            Some(cone) => kernel.scan(&self.views, cone, near_block),
            None => near_block.extend(0..self.triangles.len() as u32),
        }
        for &t in near_block.iter() {
            let b = &self.bounds[t as usize];
            let mut meets = kernel.meeting(cones, &b.ball, active);
            while meets != 0 {
                lists[meets.trailing_zeros() as usize].push(Candidate::new(b.near, t));
                meets &= meets - 1;
            }
        }
    }

    /// Casts a block of tiles (ranges into `rays`); returns how many rays were cast. Uses 8-wide
    /// AVX2 where the CPU has it (same arithmetic, so the same result bit for bit).
    fn cast_block(
        &self,
        rays: &RayBundle,
        tiles: &[(std::ops::Range<usize>, Cone)],
        block_cone: Option<&Cone>,
        hits: &mut [f32],
        scratch: &mut Scratch,
        simd: bool,
    ) -> usize {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect().filter(|_| simd) {
            // SAFETY: an `Avx2` token exists only where run-time detection found AVX2.
            return unsafe { self.cast_block_avx2(Avx2Kernel(avx2), rays, tiles, block_cone, hits, scratch) };
        }
        self.cast_block_with(Portable, rays, tiles, block_cone, hits, scratch)
    }

    /// `cast_block_with` compiled for AVX2, so that the kernel's intrinsics inline into it.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn cast_block_avx2(
        &self,
        kernel: Avx2Kernel,
        rays: &RayBundle,
        tiles: &[(std::ops::Range<usize>, Cone)],
        block_cone: Option<&Cone>,
        hits: &mut [f32],
        scratch: &mut Scratch,
    ) -> usize {
        self.cast_block_with(kernel, rays, tiles, block_cone, hits, scratch)
    }

    #[inline(always)]
    fn cast_block_with<K: GroupKernel>(
        &self,
        kernel: K,
        rays: &RayBundle,
        tiles: &[(std::ops::Range<usize>, Cone)],
        block_cone: Option<&Cone>,
        hits: &mut [f32],
        scratch: &mut Scratch,
    ) -> usize {
        let t_max = self.t_max();
        let first = tiles[0].0.start;
        let Scratch { lists, near_block, lanes } = scratch;
        lists.resize_with(tiles.len(), Vec::new);
        lanes.clear();
        let mut active = 0u64;
        for (k, (range, cone)) in tiles.iter().enumerate() {
            lists[k].clear();
            let reachable = match &self.cones {
                Some(cones) => cones.iter().any(|c| c.may_meet_cone(cone)),
                None => true,
            };
            let l = Lanes::new(&rays.dirs[range.clone()], |d| reachable && self.wanted(d), t_max);
            if l.wanted > 0 {
                active |= 1 << k;
            }
            lanes.push(l);
        }
        if active == 0 || self.triangles.is_empty() {
            return 0;
        }
        let cones = BlockCones::new(tiles.iter().map(|t| &t.1));
        self.gather(kernel, block_cone, active, &cones, lists, near_block);
        let mut cast = 0;
        let mut pending = active;
        while pending != 0 {
            let k = pending.trailing_zeros() as usize;
            pending &= pending - 1;
            let (list, l) = (&mut lists[k], &mut lanes[k]);
            list.sort_unstable();
            let mut reach = t_max;
            for &c in list.iter() {
                let (near, t) = c.parts();
                // Candidates come nearest first: once one starts beyond every ray's nearest hit,
                // so do all the rest.
                if near > reach {
                    break;
                }
                let tri = &self.triangles[t as usize];
                if l.test(kernel, tri, near) {
                    l.test_ambiguous(tri);
                }
                reach = l.reach();
            }
            let range = &tiles[k].0;
            for (i, hit) in hits[range.start - first..range.end - first].iter_mut().enumerate() {
                let best = l.best(i);
                if best >= 0.0 && best < t_max {
                    *hit = best;
                }
            }
            cast += l.wanted;
        }
        cast
    }

    /// First-hit distance of every ray of the bundle (infinity for none within reach), and how
    /// many rays were actually traversed.
    pub fn first_hits(&self, rays: &RayBundle) -> (Vec<f32>, usize) {
        self.first_hits_using(rays, true)
    }

    /// `first_hits`, with the SIMD kernel allowed or not (the portable one is then tested too).
    pub(super) fn first_hits_using(&self, rays: &RayBundle, simd: bool) -> (Vec<f32>, usize) {
        let mut hits = vec![f32::INFINITY; rays.len()];
        // Blocks are contiguous ranges of rays: hand each worker whole blocks.
        let mut work = Vec::with_capacity(rays.blocks.len());
        let mut rest = hits.as_mut_slice();
        for (block, cone) in rays.blocks.iter().zip(&rays.block_cones) {
            let tiles = &rays.tiles[block.clone()];
            let len = tiles.last().unwrap().0.end - tiles[0].0.start;
            let (head, tail) = rest.split_at_mut(len);
            work.push((tiles, cone.as_ref(), head));
            rest = tail;
        }
        let cast: usize = work
            .into_par_iter()
            .map_init(Scratch::default, |scratch, (tiles, cone, out)| {
                self.cast_block(rays, tiles, cone, out, scratch, simd)
            })
            .sum();
        (hits, cast)
    }

    /// Depth map of the sensor's useful pixels: `clamp(R - t_hit, 0, max_depth)`.
    pub fn depth_map(&self, sensor: &Sensor, rays: &RayBundle) -> (DepthMap, CastStats) {
        let radius = sensor.radius_mm as f32;
        let max_depth = sensor.max_depth_mm as f32;
        let (hits, rays_cast) = self.first_hits(rays);
        let mut depth = DepthMap::zeros(sensor.crop_size_px);
        let mut rays_hit = 0;
        for (&t, &index) in hits.iter().zip(&rays.indices) {
            if t < radius {
                rays_hit += 1;
                depth.depth_mm[index as usize] = (radius - t).clamp(0.0, max_depth);
            }
        }
        let stats = CastStats {
            triangles_total: self.triangles_total,
            triangles_kept: self.triangles.len(),
            rays_total: rays.len(),
            rays_cast,
            rays_hit,
        };
        (depth, stats)
    }
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Vec3};

    use super::*;
    use crate::shapes;

    /// The tiled path agrees with single rays and leaks nowhere on the sensor's own rays.
    #[test]
    fn tiled_casting_matches_single_rays() {
        let sensor = sensor::Sensor::default();
        let rays = RayBundle::new(&sensor);
        let meshes = [
            shapes::sphere(10.0, 64).transformed(&Affine3A::from_translation(Vec3::new(0.5, -0.3, 0.2))),
            shapes::box_mesh(Vec3::new(8.0, 9.0, 10.0)),
            shapes::shell_cap(25.75, 26.75, 3.1, &[], 40, 80),
        ];
        for mesh in &meshes {
            let caster = RayCaster::new(&[mesh], 1000.0, Skipping::Off);
            let (hits, cast) = caster.first_hits(&rays);
            assert_eq!(cast, rays.len());
            assert!(hits == caster.first_hits_using(&rays, false).0, "SIMD and portable kernels differ");
            for (h, d) in hits.iter().zip(&rays.dirs) {
                assert!(h.is_finite(), "ray {d} leaked");
                assert_eq!(*h, caster.first_hit(*d), "ray {d}");
            }
        }
    }
}
