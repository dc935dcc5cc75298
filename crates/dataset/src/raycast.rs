//! Ray-cast ground truth: depth of the pressed surface along every useful pixel's ray.
//!
//! All rays start at the sphere's centre (the sensor frame's origin). That lets each triangle
//! precompute its three edge-plane normals through the origin: a ray hits the triangle when its
//! direction lies on the same side of all three planes, and the distance follows from one more
//! dot product. Each edge test's sign is exact: vertices are snapped to a power-of-two grid
//! (a few nanometres) and ray directions to multiples of 2^-24, so that where the fast f32 test
//! is within its rounding bound of zero the sign is recomputed in integers. Exact signs are
//! consistent between neighbouring triangles, so no ray leaks through a shared edge or vertex.
//!
//! Rays are cast a tile at a time, tiles a block at a time: a SIMD scan of every triangle's
//! bounding ball against the block's cone, then of the survivors against all 64 tile cones at
//! once, gathers the triangles any of a tile's rays can reach; sorted by their distance from the
//! centre, each ray tests them in that order and stops once the next one lies beyond its nearest
//! hit. No BVH is built (the scan costs less than building one); the single-ray reference path
//! builds one on first use.
//!
//! Skipping (on by default) changes nothing in the result and is tested for that:
//! - a triangle whose nearest point to the centre lies beyond the radius can never be the first
//!   hit inside the sphere, so it is dropped;
//! - a ray (or a whole tile) outside the bounding cone of every part's remaining triangles
//!   cannot hit any of them, so it is not traversed;
//! - rays stop at the radius (`tmax = R`): anything farther gives depth 0 anyway.

use glam::{DVec3, Vec3, Vec3A};
use obvhs::{
    BvhBuildParams, bvh2::Bvh2, bvh2::builder::build_bvh2_from_tris, ray::Ray, ray::RayHit, triangle::Triangle,
};
use rayon::prelude::*;
use sensor::{DepthMap, Sensor};

use crate::mesh::Mesh;
use crate::rays::{BallView, BallViews, BlockCones, Cone, RayBundle};

/// A triangle prepared for rays from the origin.
#[derive(Clone, Copy, Debug)]
struct OriginTriangle {
    /// Normals of the planes through the origin and each edge: (v0,v1), (v1,v2), (v2,v0).
    e01: Vec3A,
    e12: Vec3A,
    e20: Vec3A,
    /// Plane normal (unnormalised) and its offset `n . v0`.
    normal: Vec3A,
    offset: f32,
    /// Below this magnitude an edge test's f32 sign is not certain and is recomputed exactly.
    sign_bound: f32,
    /// Vertices on the integer grid, for the exact recomputation.
    grid: [[i64; 3]; 3],
}

impl OriginTriangle {
    fn new(tri: [Vec3; 3], grid_scale: f32) -> Self {
        let grid = tri.map(|v| (v * grid_scale).to_array().map(|x| x as i64));
        let [a, b, c] = grid;
        let exact = [cross_i64(a, b), cross_i64(b, c), cross_i64(c, a)];
        // Edge normals rounded once from their exact values (in grid units).
        let [e01, e12, e20] = exact.map(|n| Vec3A::new(n[0] as f32, n[1] as f32, n[2] as f32));
        let norm1 = |e: Vec3A| e.abs().element_sum();
        let largest = norm1(e01).max(norm1(e12)).max(norm1(e20));
        let (a, b, c) = (Vec3A::from(tri[0]), Vec3A::from(tri[1]), Vec3A::from(tri[2]));
        let normal = (b - a).cross(c - a);
        OriginTriangle {
            e01,
            e12,
            e20,
            normal,
            offset: normal.dot(a),
            // Rounding of the edge normal (1 ulp) plus the dot product's (3 ulp), doubled.
            sign_bound: largest * 8.0 * f32::EPSILON,
            grid,
        }
    }

    /// Distance along unit direction `d` (on the 2^-24 grid) to the triangle, if hit within
    /// `[0, t_max]`; infinity otherwise.
    #[inline(always)]
    fn intersect(&self, d: Vec3A, t_max: f32) -> f32 {
        self.intersect_fast(d, t_max).unwrap_or_else(|| self.finish(self.exact_signs(d), d, t_max))
    }

    /// The f32 test: the hit distance (or infinity) when every edge sign is certain, `None`
    /// when one lies within its rounding bound of zero.
    #[inline(always)]
    fn intersect_fast(&self, d: Vec3A, t_max: f32) -> Option<f32> {
        let s = [dot3(d, self.e01), dot3(d, self.e12), dot3(d, self.e20)];
        if s.iter().any(|x| x.abs() <= self.sign_bound) {
            return None;
        }
        Some(self.finish(s, d, t_max))
    }

    /// Hit distance from the three edge signs: inside when all agree.
    #[inline(always)]
    fn finish(&self, [s0, s1, s2]: [f32; 3], d: Vec3A, t_max: f32) -> f32 {
        let inside = (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0);
        let den = dot3(d, self.normal);
        if inside && den != 0.0 {
            let t = self.offset / den;
            if t >= 0.0 && t <= t_max {
                return t;
            }
        }
        f32::INFINITY
    }

    /// Signs (as -1, 0, 1) of the three edge tests in exact integer arithmetic.
    #[cold]
    fn exact_signs(&self, d: Vec3A) -> [f32; 3] {
        let di = d.to_array().map(|x| (x * DIR_GRID) as i128);
        let [a, b, c] = self.grid;
        [cross_i64(a, b), cross_i64(b, c), cross_i64(c, a)].map(|n| {
            let s: i128 = (0..3).map(|k| di[k] * n[k] as i128).sum();
            s.signum() as f32
        })
    }
}

fn cross_i64(a: [i64; 3], b: [i64; 3]) -> [i64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Ray directions are snapped to multiples of 2^-24 (exact in f32, at most 6e-8 rad away).
const DIR_GRID: f32 = (1u32 << 24) as f32;

#[inline]
pub fn snap_direction(d: Vec3A) -> Vec3A {
    (d * DIR_GRID).round() / DIR_GRID
}

/// Power-of-two scale that puts every coordinate (|x| < `max_abs`) on an integer grid of at
/// most 24 bits, so that snapped vertices are exact both as f32 and as integers.
fn grid_scale(max_abs: f32) -> f32 {
    let bits = (max_abs.max(1e-3) * 2.0).log2().ceil() as i32;
    2f32.powi(23 - bits)
}

/// Whether any point of the triangle lies within `radius` of the origin: cheap answers where
/// they are certain, the exact closest distance otherwise (with a 1 nm margin: dropping must be
/// certain, keeping too much is harmless). `len2` are the vertices' squared distances from the
/// origin, worked out once per vertex since each is shared by about six triangles.
fn may_reach(tri: [Vec3; 3], len2: [f32; 3], radius: f64) -> bool {
    let r = radius as f32;
    if len2.iter().any(|&l2| l2 <= r * r * (1.0 - 1e-5)) {
        return true;
    }
    // Every point of the triangle is within its longest edge from each vertex, so a vertex
    // farther out than that edge beyond the sphere rules the triangle out (no square root
    // but the vertex's own).
    let far = r * (1.0 + 1e-5);
    for k in 0..3 {
        let gap = len2[k].sqrt() - far;
        if gap > 0.0 {
            let edge2 = tri[k].distance_squared(tri[(k + 1) % 3]).max(tri[k].distance_squared(tri[(k + 2) % 3]));
            if gap * gap > edge2 * 1.0002 {
                return false;
            }
        }
    }
    let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
    let spread = tri.iter().map(|v| v.distance(centre)).fold(0.0, f32::max);
    if centre.length() - spread * 1.0001 > far {
        return false;
    }
    origin_distance(tri.map(Vec3::as_dvec3)) <= radius + 1e-6
}

/// A cheap lower bound on the distance from the origin to the triangle, for ordering
/// candidates: the larger of its plane's distance and its bounding ball's nearest point.
fn near_bound(tri: [Vec3; 3]) -> f32 {
    let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
    let spread = tri.iter().map(|v| v.distance(centre)).fold(0.0, f32::max);
    let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
    let len = normal.length();
    let plane = if len > 0.0 { normal.dot(tri[0]).abs() / len } else { 0.0 };
    // Rounded down so that the early exit stays conservative.
    (plane.max(centre.length() - spread) * (1.0 - 1e-5) - 1e-6).max(0.0)
}

/// Closest distance from the origin to triangle `[a, b, c]` (Ericson's region test, in f64).
pub fn origin_distance([a, b, c]: [DVec3; 3]) -> f64 {
    let p = DVec3::ZERO;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a.length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b.length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (a + ab * (d1 / (d1 - d3))).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c.length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (a + ac * (d2 / (d2 - d6))).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))).length();
    }
    let denom = 1.0 / (va + vb + vc);
    (a + ab * (vb * denom) + ac * (vc * denom)).length()
}

/// Counts that show what skipping saved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct CastStats {
    pub triangles_total: usize,
    pub triangles_kept: usize,
    pub rays_total: usize,
    pub rays_cast: usize,
    pub rays_hit: usize,
}

/// Whether to skip what cannot change the depth map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Skipping {
    /// Drop unreachable triangles, bound rays by cones, stop rays at the radius.
    On,
    /// Cast every ray against every triangle to infinity: the reference, and the fair peer
    /// comparison with a general-purpose ray caster.
    Off,
}

/// Rays of one tile in structure-of-arrays form, in groups of eight, so that testing a
/// triangle against them compiles to 8-wide SIMD arithmetic without bounds checks.
const LANES: usize = 64;
/// Lanes tested together: one AVX2 register of f32.
const GROUP: usize = 8;
const GROUPS: usize = LANES / GROUP;

struct Lanes {
    x: [[f32; GROUP]; GROUPS],
    y: [[f32; GROUP]; GROUPS],
    z: [[f32; GROUP]; GROUPS],
    /// Nearest hit so far; -1 for lanes that cast nothing (unwanted rays, padding).
    best: [[f32; GROUP]; GROUPS],
    /// The largest `best` of each group.
    group_reach: [f32; GROUPS],
    wanted: usize,
}

/// Largest of eight values, as a tree of plain comparisons (a fold with `f32::max` is a serial
/// chain of NaN-aware steps; our values are never NaN).
#[inline(always)]
fn max8(v: &[f32; 8]) -> f32 {
    let m = |a: f32, b: f32| if a > b { a } else { b };
    m(m(m(v[0], v[4]), m(v[2], v[6])), m(m(v[1], v[5]), m(v[3], v[7])))
}

impl Lanes {
    fn new(dirs: &[Vec3A], wanted: impl Fn(Vec3A) -> bool, t_max: f32) -> Self {
        assert!(dirs.len() <= LANES && !dirs.is_empty());
        let d0 = dirs[0];
        let mut l = Lanes {
            x: [[d0.x; GROUP]; GROUPS],
            y: [[d0.y; GROUP]; GROUPS],
            z: [[d0.z; GROUP]; GROUPS],
            best: [[-1.0; GROUP]; GROUPS],
            group_reach: [-1.0; GROUPS],
            wanted: 0,
        };
        for (i, d) in dirs.iter().enumerate() {
            let (g, k) = (i / GROUP, i % GROUP);
            (l.x[g][k], l.y[g][k], l.z[g][k]) = (d.x, d.y, d.z);
            if wanted(*d) {
                l.best[g][k] = t_max;
                l.group_reach[g] = t_max;
                l.wanted += 1;
            }
        }
        l
    }

    fn best(&self, i: usize) -> f32 {
        self.best[i / GROUP][i % GROUP]
    }

    /// The farthest any lane still looks.
    #[inline(always)]
    fn reach(&self) -> f32 {
        max8(&self.group_reach)
    }

    /// Tests every lane against `tri` with the f32 edge tests, a group at a time, skipping
    /// groups whose rays all hit something nearer than `near`. Lanes where an edge test is within
    /// its rounding bound of zero are left alone and reported (true) for the exact pass.
    #[inline(always)]
    fn test<K: GroupKernel>(&mut self, tri: &OriginTriangle, near: f32) -> bool {
        let mut ambiguous = false;
        for g in 0..GROUPS {
            if self.group_reach[g] < near {
                continue;
            }
            ambiguous |= K::test_group(self, g, tri);
            self.group_reach[g] = max8(&self.best[g]);
        }
        ambiguous
    }

    /// The lanes `test` left alone, one at a time with exact signs.
    #[cold]
    fn test_ambiguous(&mut self, tri: &OriginTriangle) {
        for i in 0..LANES {
            let (g, k) = (i / GROUP, i % GROUP);
            let d = Vec3A::new(self.x[g][k], self.y[g][k], self.z[g][k]);
            let best = self.best[g][k];
            // Only the lanes the fast test could not decide.
            if best >= 0.0 && tri.intersect_fast(d, best).is_none() {
                let t = tri.finish(tri.exact_signs(d), d, best);
                if t <= best {
                    self.best[g][k] = t;
                    self.group_reach[g] = max8(&self.best[g]);
                }
            }
        }
    }
}

/// Tests eight rays against one triangle: updates `best` where the f32 edge tests are certain,
/// and returns whether any lane was too close to an edge plane to tell.
trait GroupKernel {
    fn test_group(lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool;
    /// The tiles among `active` whose cones may meet `view` (`BlockCones::meeting`).
    fn meeting(cones: &BlockCones, view: &BallView, active: u64) -> u64;
    /// The balls `cone` may meet (`BallViews::meeting`).
    fn scan(views: &BallViews, cone: &Cone, out: &mut Vec<u32>);
}

/// Plain Rust, for any CPU.
struct Portable;

impl GroupKernel for Portable {
    #[inline(always)]
    fn test_group(lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool {
        let mut ambiguous = false;
        for i in 0..GROUP {
            let d = Vec3A::new(lanes.x[g][i], lanes.y[g][i], lanes.z[g][i]);
            let best = &mut lanes.best[g][i];
            match tri.intersect_fast(d, *best) {
                Some(t) if t <= *best => *best = t,
                Some(_) => {}
                None => ambiguous = true,
            }
        }
        ambiguous
    }

    #[inline(always)]
    fn meeting(cones: &BlockCones, view: &BallView, active: u64) -> u64 {
        cones.meeting(view, active)
    }

    #[inline(always)]
    fn scan(views: &BallViews, cone: &Cone, out: &mut Vec<u32>) {
        views.meeting(cone, out)
    }
}

/// AVX2: the same arithmetic (multiplies then adds in `dot3`'s order, no fused multiply-add),
/// eight lanes per instruction, so results match `Portable` bit for bit.
#[cfg(target_arch = "x86_64")]
struct Avx2;

#[cfg(target_arch = "x86_64")]
impl GroupKernel for Avx2 {
    #[inline(always)]
    fn test_group(lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool {
        // SAFETY: only instantiated inside `cast_block_avx2`, which runs after AVX2 was detected.
        unsafe { avx2_test_group(&lanes.x[g], &lanes.y[g], &lanes.z[g], &mut lanes.best[g], tri) }
    }

    #[inline(always)]
    fn meeting(cones: &BlockCones, view: &BallView, active: u64) -> u64 {
        // SAFETY: as above.
        unsafe { cones.meeting_avx2(view, active) }
    }

    #[inline(always)]
    fn scan(views: &BallViews, cone: &Cone, out: &mut Vec<u32>) {
        // SAFETY: as above.
        unsafe { views.meeting_avx2(cone, out) }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn avx2_test_group(
    x: &[f32; GROUP],
    y: &[f32; GROUP],
    z: &[f32; GROUP],
    best: &mut [f32; GROUP],
    tri: &OriginTriangle,
) -> bool {
    use std::arch::x86_64::*;
    // SAFETY: the arrays hold exactly eight f32; unaligned loads and stores are used.
    unsafe {
        let (xv, yv, zv) = (_mm256_loadu_ps(x.as_ptr()), _mm256_loadu_ps(y.as_ptr()), _mm256_loadu_ps(z.as_ptr()));
        let dot = |e: Vec3A| {
            let xy = _mm256_add_ps(_mm256_mul_ps(xv, _mm256_set1_ps(e.x)), _mm256_mul_ps(yv, _mm256_set1_ps(e.y)));
            _mm256_add_ps(xy, _mm256_mul_ps(zv, _mm256_set1_ps(e.z)))
        };
        let (s0, s1, s2) = (dot(tri.e01), dot(tri.e12), dot(tri.e20));
        let zero = _mm256_setzero_ps();
        let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
        let bound = _mm256_set1_ps(tri.sign_bound);
        let near_zero = |s| _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_and_ps(s, abs_mask), bound);
        let amb = _mm256_or_ps(_mm256_or_ps(near_zero(s0), near_zero(s1)), near_zero(s2));
        let ge = |s| _mm256_cmp_ps::<_CMP_GE_OQ>(s, zero);
        let le = |s| _mm256_cmp_ps::<_CMP_LE_OQ>(s, zero);
        let pos = _mm256_and_ps(_mm256_and_ps(ge(s0), ge(s1)), ge(s2));
        let neg = _mm256_and_ps(_mm256_and_ps(le(s0), le(s1)), le(s2));
        let den = dot(tri.normal);
        let t = _mm256_div_ps(_mm256_set1_ps(tri.offset), den);
        let bv = _mm256_loadu_ps(best.as_ptr());
        let ok = _mm256_and_ps(
            _mm256_andnot_ps(amb, _mm256_or_ps(pos, neg)),
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_NEQ_UQ>(den, zero),
                _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(t, zero), _mm256_cmp_ps::<_CMP_LE_OQ>(t, bv)),
            ),
        );
        _mm256_storeu_ps(best.as_mut_ptr(), _mm256_blendv_ps(bv, t, ok));
        _mm256_movemask_ps(amb) != 0
    }
}

/// `a . b` summed in a fixed order, so that the SIMD and the single-ray paths agree bit for bit.
#[inline(always)]
fn dot3(a: Vec3A, b: Vec3A) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z
}

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
    triangles: Vec<OriginTriangle>,
    bounds: Vec<TriangleBounds>,
    /// The bounds' balls again, in the form a block's cone scans eight at a time.
    views: BallViews,
    /// The kept triangles' snapped corners, for the single-ray reference.
    corners: Vec<[Vec3; 3]>,
    /// A BVH over `corners`, built on the single-ray reference's first use: the tiled path
    /// needs none, since a scan of every triangle's ball per block of rays costs less than
    /// building one.
    reference_bvh: std::sync::OnceLock<Bvh2>,
    cones: Option<Vec<Cone>>,
    radius_mm: f32,
    skipping: Skipping,
    triangles_total: usize,
    /// How far the reference BVH's boxes are widened beyond rounding.
    pad_mm: f32,
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

    fn t_max(&self) -> f32 {
        if self.skipping == Skipping::On { self.radius_mm } else { f32::INFINITY }
    }

    /// Distance to the first hit along unit direction `dir`, or infinity (none, or none within
    /// reach): one ray through the BVH on its own, the reference for the tiled path.
    pub fn first_hit(&self, dir: Vec3A) -> f32 {
        if self.triangles.is_empty() {
            return f32::INFINITY;
        }
        let bvh = self.reference_bvh.get_or_init(|| {
            let tris: Vec<Triangle> =
                self.corners.iter().map(|t| Triangle { v0: t[0].into(), v1: t[1].into(), v2: t[2].into() }).collect();
            let mut bvh = build_bvh2_from_tris(&tris, BvhBuildParams::fastest_build(), &mut Default::default());
            // Pad the boxes: a ray lying exactly in a box's face plane (an axis-aligned ray
            // through an edge on the axis) must not be rejected by the slab test's rounding.
            for node in &mut bvh.nodes {
                node.aabb.min -= Vec3A::splat(self.pad_mm);
                node.aabb.max += Vec3A::splat(self.pad_mm);
            }
            bvh
        });
        let dir = snap_direction(dir);
        let ray = Ray::new(Vec3A::ZERO, dir, 0.0, self.t_max());
        let mut hit = RayHit::none();
        let (tris, order) = (&self.triangles, &bvh.primitive_indices);
        bvh.ray_traverse(ray, &mut hit, |r, id| tris[order[id] as usize].intersect(dir, r.tmax));
        if hit.t < self.t_max() { hit.t } else { f32::INFINITY }
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
        block_cone: Option<&Cone>,
        active: u64,
        cones: &BlockCones,
        lists: &mut [Vec<Candidate>],
        near_block: &mut Vec<u32>,
    ) {
        near_block.clear();
        match block_cone {
            Some(cone) => K::scan(&self.views, cone, near_block),
            None => near_block.extend(0..self.triangles.len() as u32),
        }
        for &t in near_block.iter() {
            let b = &self.bounds[t as usize];
            let mut meets = K::meeting(cones, &b.ball, active);
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
        if simd && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { self.cast_block_avx2(rays, tiles, block_cone, hits, scratch) };
        }
        self.cast_block_with::<Portable>(rays, tiles, block_cone, hits, scratch)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn cast_block_avx2(
        &self,
        rays: &RayBundle,
        tiles: &[(std::ops::Range<usize>, Cone)],
        block_cone: Option<&Cone>,
        hits: &mut [f32],
        scratch: &mut Scratch,
    ) -> usize {
        self.cast_block_with::<Avx2>(rays, tiles, block_cone, hits, scratch)
    }

    #[inline(always)]
    fn cast_block_with<K: GroupKernel>(
        &self,
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
        self.gather::<K>(block_cone, active, &cones, lists, near_block);
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
                if l.test::<K>(tri, near) {
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
    fn first_hits_using(&self, rays: &RayBundle, simd: bool) -> (Vec<f32>, usize) {
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
    use super::*;
    use crate::shapes;
    use glam::Affine3A;

    fn rng_dirs(n: usize, seed: u64) -> Vec<Vec3A> {
        let mut s = seed;
        let mut next = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            let v = DVec3::new(next(), next(), next());
            if v.length_squared() > 1e-6 && v.length_squared() <= 1.0 {
                out.push(Vec3A::from(v.normalize().as_vec3()));
            }
        }
        out
    }

    #[test]
    fn closest_distance_matches_brute_force() {
        let tris = [
            [DVec3::new(1.0, 1.0, 5.0), DVec3::new(-1.0, 1.0, 5.0), DVec3::new(0.0, -1.0, 5.0)],
            [DVec3::new(3.0, 0.0, 0.0), DVec3::new(4.0, 1.0, 0.0), DVec3::new(4.0, -1.0, 2.0)],
            [DVec3::new(-2.0, 3.0, 1.0), DVec3::new(2.0, 3.0, 1.0), DVec3::new(0.0, 3.0, 4.0)],
        ];
        for t in tris {
            let mut best = f64::INFINITY;
            for i in 0..=200 {
                for j in 0..=(200 - i) {
                    let (u, v) = (i as f64 / 200.0, j as f64 / 200.0);
                    best = best.min((t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v).length());
                }
            }
            let d = origin_distance(t);
            assert!(d <= best + 1e-12 && best - d < 1e-3, "{d} vs {best}");
        }
    }

    proptest::proptest! {
        /// Dropping a triangle is certain: whatever `may_reach` rules out lies beyond the
        /// sphere, long slivers crossing it with every vertex outside included.
        #[test]
        fn dropped_triangles_lie_beyond_the_sphere(
            a in proptest::array::uniform3(-60f32..60.0),
            b in proptest::array::uniform3(-60f32..60.0),
            c in proptest::array::uniform3(-3f32..3.0),
            radius in 5f64..40.0,
        ) {
            // The third vertex near the middle of the first two: thin triangles across the sphere.
            let (a, b) = (Vec3::from(a), Vec3::from(b));
            let tri = [a, b, (a + b) * 0.5 + Vec3::from(c)];
            let exact = origin_distance(tri.map(Vec3::as_dvec3));
            let reaches = may_reach(tri, tri.map(|v| v.length_squared()), radius);
            proptest::prop_assert!(reaches || exact > radius, "dropped at {exact} mm, radius {radius}");
            // And it keeps only what comes close: no more than a margin beyond the sphere.
            proptest::prop_assert!(!reaches || exact <= radius * (1.0 + 1e-3) + 1e-3 || tri.iter().any(|v| (v.length() as f64) < radius), "kept at {exact}");
        }
    }

    /// Random rays from inside closed meshes always hit: no leaks at shared edges or vertices.
    #[test]
    fn closed_meshes_are_watertight() {
        // (mesh, polar angle below which rays must hit): the shell cap is open below 3.1 rad.
        let meshes = [
            (shapes::sphere(10.0, 64), 4.0),
            (shapes::box_mesh(Vec3::new(8.0, 9.0, 10.0)), 4.0),
            (shapes::cylinder(6.0, 12.0, 48).transformed(&Affine3A::from_translation(Vec3::new(0.0, 0.0, -6.0))), 4.0),
            (shapes::shell_cap(25.75, 26.75, 3.1, &[], 40, 80), 3.09),
        ];
        for (mesh, theta_max) in &meshes {
            let caster = RayCaster::new(&[mesh], 1000.0, Skipping::Off);
            // Aim rays straight at vertices too: the hardest case for leaks.
            let mut dirs = rng_dirs(100_000, 7);
            dirs.extend(mesh.vertices.iter().filter_map(|v| Vec3A::from(*v).try_normalize()));
            dirs.retain(|d| d.z.clamp(-1.0, 1.0).acos() < *theta_max);
            let leaks = dirs.iter().filter(|&&d| !caster.first_hit(d).is_finite()).count();
            assert_eq!(leaks, 0, "{leaks} of {} rays leaked", dirs.len());
        }
    }

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

    #[test]
    fn sphere_hit_distance_is_exact() {
        let caster = RayCaster::new(&[&shapes::sphere(10.0, 256)], 1000.0, Skipping::Off);
        for d in rng_dirs(1000, 3) {
            let t = caster.first_hit(d);
            // The tessellated sphere lies inside the true one by at most the chord sagitta.
            assert!(t <= 10.0 + 1e-5 && t > 10.0 * (std::f32::consts::PI / 128.0).cos() - 1e-4, "{t}");
        }
    }
}
