//! One triangle against rays from the origin, with exact edge signs, and the distance bounds
//! that decide which triangles a scene keeps and in what order a tile tests them.

use glam::{DVec3, Vec3, Vec3A};

/// A triangle prepared for rays from the origin.
#[derive(Clone, Copy, Debug)]
pub(super) struct OriginTriangle {
    /// Normals of the planes through the origin and each edge: (v0,v1), (v1,v2), (v2,v0).
    pub(super) e01: Vec3A,
    pub(super) e12: Vec3A,
    pub(super) e20: Vec3A,
    /// Plane normal (unnormalised) and its offset `n . v0`.
    pub(super) normal: Vec3A,
    pub(super) offset: f32,
    /// Below this magnitude an edge test's f32 sign is not certain and is recomputed exactly.
    pub(super) sign_bound: f32,
    /// Vertices on the integer grid, for the exact recomputation.
    pub(super) grid: [[i64; 3]; 3],
}

impl OriginTriangle {
    pub(super) fn new(tri: [Vec3; 3], grid_scale: f32) -> Self {
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
    pub(super) fn intersect(&self, d: Vec3A, t_max: f32) -> f32 {
        self.intersect_fast(d, t_max).unwrap_or_else(|| self.finish(self.exact_signs(d), d, t_max))
    }

    /// The f32 test: the hit distance (or infinity) when every edge sign is certain, `None`
    /// when one lies within its rounding bound of zero.
    #[inline(always)]
    pub(super) fn intersect_fast(&self, d: Vec3A, t_max: f32) -> Option<f32> {
        let s = [dot3(d, self.e01), dot3(d, self.e12), dot3(d, self.e20)];
        if s.iter().any(|x| x.abs() <= self.sign_bound) {
            return None;
        }
        Some(self.finish(s, d, t_max))
    }

    /// Hit distance from the three edge signs: inside when all agree.
    #[inline(always)]
    pub(super) fn finish(&self, [s0, s1, s2]: [f32; 3], d: Vec3A, t_max: f32) -> f32 {
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
    pub(super) fn exact_signs(&self, d: Vec3A) -> [f32; 3] {
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
pub(super) fn grid_scale(max_abs: f32) -> f32 {
    let bits = (max_abs.max(1e-3) * 2.0).log2().ceil() as i32;
    2f32.powi(23 - bits)
}

/// Whether any point of the triangle lies within `radius` of the origin: cheap answers where
/// they are certain, the exact closest distance otherwise (with a 1 nm margin: dropping must be
/// certain, keeping too much is harmless). `len2` are the vertices' squared distances from the
/// origin, worked out once per vertex since each is shared by about six triangles.
pub(super) fn may_reach(tri: [Vec3; 3], len2: [f32; 3], radius: f64) -> bool {
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
pub(super) fn near_bound(tri: [Vec3; 3]) -> f32 {
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

/// `a . b` summed in a fixed order, so that the SIMD and the single-ray paths agree bit for bit.
#[inline(always)]
pub(super) fn dot3(a: Vec3A, b: Vec3A) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
