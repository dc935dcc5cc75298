//! The single-ray reference: one ray at a time through a BVH over the kept triangles, with the
//! same exact triangle test. The tiled cast is tested against it.

use glam::Vec3A;
use obvhs::{BvhBuildParams, bvh2::builder::build_bvh2_from_tris, ray::Ray, ray::RayHit, triangle::Triangle};

use super::cast::RayCaster;
use super::triangle::snap_direction;

impl RayCaster {
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
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, DVec3, Vec3, Vec3A};

    use super::super::{RayCaster, Skipping};
    use crate::shapes;

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
}
