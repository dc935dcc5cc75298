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
//! Skipping (on by default) changes nothing in the result and is tested for that:
//! - a triangle whose nearest point to the centre lies beyond the radius can never be the first
//!   hit inside the sphere, so it is dropped;
//! - a ray outside the bounding cone of every part's remaining triangles cannot hit any of them,
//!   so it is not traversed;
//! - rays stop at the radius (`tmax = R`): anything farther gives depth 0 anyway.

use glam::{DVec3, Vec3, Vec3A};
use obvhs::{BvhBuildParams, cwbvh::CwBvh, cwbvh::builder::build_cwbvh_from_tris, ray::Ray, ray::RayHit, triangle::Triangle};
use rayon::prelude::*;
use sensor::{DepthMap, Sensor};

use crate::mesh::Mesh;
use crate::rays::RayBundle;

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
        let mut s0 = d.dot(self.e01);
        let mut s1 = d.dot(self.e12);
        let mut s2 = d.dot(self.e20);
        let bound = self.sign_bound;
        if s0.abs() <= bound || s1.abs() <= bound || s2.abs() <= bound {
            [s0, s1, s2] = self.exact_signs(d);
        }
        let inside = (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0);
        let den = d.dot(self.normal);
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
fn snap_direction(d: Vec3A) -> Vec3A {
    (d * DIR_GRID).round() / DIR_GRID
}

/// Power-of-two scale that puts every coordinate (|x| < `max_abs`) on an integer grid of at
/// most 24 bits, so that snapped vertices are exact both as f32 and as integers.
fn grid_scale(max_abs: f32) -> f32 {
    let bits = (max_abs.max(1e-3) * 2.0).log2().ceil() as i32;
    2f32.powi(23 - bits)
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

/// A cone of directions from the origin that contains a set of points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    pub axis: Vec3A,
    pub cos_half_angle: f32,
}

impl Cone {
    /// Bounding cone of `points`, or `None` when it would be 90 degrees or wider (a cone that
    /// wide is not convex, so containing the vertices no longer implies containing the triangles).
    pub fn bounding(points: impl Iterator<Item = Vec3> + Clone) -> Option<Cone> {
        let mut sum = DVec3::ZERO;
        for p in points.clone() {
            let p = p.as_dvec3();
            let len = p.length();
            if !(len > 1e-9) {
                return None;
            }
            sum += p / len;
        }
        let axis = sum.try_normalize()?;
        let cos = points.map(|p| p.as_dvec3().normalize().dot(axis)).fold(1.0f64, f64::min);
        // A margin far above f32 rounding keeps the test conservative.
        let cos = cos - 1e-5;
        (cos > 0.01).then(|| Cone { axis: Vec3A::from(axis.as_vec3()), cos_half_angle: cos as f32 })
    }

    #[inline]
    pub fn contains(&self, dir: Vec3A) -> bool {
        dir.dot(self.axis) >= self.cos_half_angle
    }
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

/// A scene's triangles, ready to cast the sensor's rays into.
pub struct RayCaster {
    bvh: CwBvh,
    /// Triangles in BVH primitive order (no indirection in the hot loop).
    triangles: Vec<OriginTriangle>,
    cones: Option<Vec<Cone>>,
    radius_mm: f32,
    skipping: Skipping,
    triangles_total: usize,
}

impl RayCaster {
    /// Builds the caster for a scene made of `parts` (sensor frame, mm) and a sensor of `radius_mm`.
    pub fn new(parts: &[&Mesh], radius_mm: f64, skipping: Skipping) -> Self {
        // One grid for the whole scene, whatever is dropped, so skipping cannot move a vertex.
        let max_abs = parts.iter().flat_map(|p| &p.vertices).map(|v| v.abs().max_element()).fold(0.0, f32::max);
        let scale = grid_scale(max_abs);
        let snap = |v: Vec3| (v * scale).round() / scale;
        let mut kept: Vec<[Vec3; 3]> = Vec::new();
        let mut cones = Some(Vec::new());
        let mut triangles_total = 0;
        for part in parts {
            triangles_total += part.triangles.len();
            let start = kept.len();
            for i in 0..part.triangles.len() {
                let tri = part.triangle(i).map(snap);
                // Keep a 1 nm margin: dropping must be certain, keeping too much is harmless.
                if skipping == Skipping::Off || origin_distance(tri.map(Vec3::as_dvec3)) <= radius_mm + 1e-6 {
                    kept.push(tri);
                }
            }
            if skipping == Skipping::On && kept.len() > start {
                let cone = Cone::bounding(kept[start..].iter().flatten().copied());
                match (cone, cones.as_mut()) {
                    (Some(c), Some(list)) => list.push(c),
                    _ => cones = None,
                }
            }
        }
        if skipping == Skipping::Off {
            cones = None;
        }
        let tris: Vec<Triangle> =
            kept.iter().map(|t| Triangle { v0: t[0].into(), v1: t[1].into(), v2: t[2].into() }).collect();
        let (bvh, triangles) = if tris.is_empty() {
            (CwBvh::default(), Vec::new())
        } else {
            let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Default::default());
            let ordered = bvh.primitive_indices.iter().map(|&i| OriginTriangle::new(kept[i as usize], scale)).collect();
            (bvh, ordered)
        };
        RayCaster { bvh, triangles, cones, radius_mm: radius_mm as f32, skipping, triangles_total }
    }

    pub fn triangles_kept(&self) -> usize {
        self.triangles.len()
    }

    /// Distance to the first hit along unit direction `dir`, or infinity.
    #[inline]
    pub fn first_hit(&self, dir: Vec3A) -> f32 {
        if self.triangles.is_empty() {
            return f32::INFINITY;
        }
        let dir = snap_direction(dir);
        let t_max = if self.skipping == Skipping::On { self.radius_mm } else { f32::INFINITY };
        let ray = Ray::new(Vec3A::ZERO, dir, 0.0, t_max);
        let mut hit = RayHit::none();
        let tris = &self.triangles;
        self.bvh.ray_traverse(ray, &mut hit, |r, id| tris[id].intersect(dir, r.tmax));
        hit.t
    }

    fn wanted(&self, dir: Vec3A) -> bool {
        match &self.cones {
            Some(cones) => cones.iter().any(|c| c.contains(dir)),
            None => true,
        }
    }

    /// Depth map of the sensor's useful pixels: `clamp(R - t_hit, 0, max_depth)`.
    pub fn depth_map(&self, sensor: &Sensor, rays: &RayBundle) -> (DepthMap, CastStats) {
        let radius = sensor.radius_mm as f32;
        let max_depth = sensor.max_depth_mm as f32;
        let mut depth = DepthMap::zeros(sensor.crop_size_px);
        let mut hits = vec![f32::INFINITY; rays.len()];
        let cast: usize = hits
            .par_chunks_mut(RayBundle::TILE_RAYS)
            .zip(rays.dirs.par_chunks(RayBundle::TILE_RAYS))
            .map(|(out, dirs)| {
                let mut n = 0;
                for (o, &d) in out.iter_mut().zip(dirs) {
                    if self.wanted(d) {
                        *o = self.first_hit(d);
                        n += 1;
                    }
                }
                n
            })
            .sum();
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
            rays_cast: cast,
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

    #[test]
    fn sphere_hit_distance_is_exact() {
        let caster = RayCaster::new(&[&shapes::sphere(10.0, 256)], 1000.0, Skipping::Off);
        for d in rng_dirs(1000, 3) {
            let t = caster.first_hit(d);
            // The tessellated sphere lies inside the true one by at most the chord sagitta.
            assert!(t <= 10.0 + 1e-5 && t > 10.0 * (std::f32::consts::PI / 128.0).cos() - 1e-4, "{t}");
        }
    }

    #[test]
    fn cone_bounds_its_points() {
        let pts = [Vec3::new(1.0, 0.0, 5.0), Vec3::new(-1.0, 0.5, 4.0), Vec3::new(0.0, -2.0, 6.0)];
        let cone = Cone::bounding(pts.iter().copied()).unwrap();
        for p in pts {
            assert!(cone.contains(Vec3A::from(p.normalize())));
        }
        assert!(!cone.contains(Vec3A::Z * -1.0));
        // Points all around the origin admit no convex cone.
        assert!(Cone::bounding([Vec3::X, -Vec3::X, Vec3::Z].into_iter()).is_none());
    }
}
