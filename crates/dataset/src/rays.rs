//! The sensor's rays, grouped into small square tiles of neighbouring pixels.
//!
//! Rays of a tile point in nearly the same direction, so one bounding cone per tile lets the
//! ray caster walk the BVH once for the whole tile and test each ray against only the few
//! triangles that cone can reach.

use glam::Vec3A;
use sensor::Sensor;

/// A cone of directions from the origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    pub axis: Vec3A,
    pub cos_half_angle: f32,
    pub sin_half_angle: f32,
}

impl Cone {
    /// Smallest cone about the mean direction containing every direction, widened by a margin
    /// far above f32 rounding; `None` if it would reach 90 degrees (such a cone is not convex).
    pub fn around_directions(dirs: impl Iterator<Item = Vec3A> + Clone) -> Option<Cone> {
        let mut sum = glam::DVec3::ZERO;
        for d in dirs.clone() {
            let d = glam::DVec3::from(d.to_array().map(f64::from));
            let len = d.length();
            if !(len > 1e-9) {
                return None;
            }
            sum += d / len;
        }
        let axis = sum.try_normalize()?;
        let cos = dirs
            .map(|d| glam::DVec3::from(d.to_array().map(f64::from)).normalize().dot(axis))
            .fold(1.0f64, f64::min)
            - 1e-5;
        (cos > 0.01).then(|| Cone {
            axis: Vec3A::from(axis.as_vec3()),
            cos_half_angle: cos as f32,
            sin_half_angle: (1.0 - cos * cos).max(0.0).sqrt() as f32,
        })
    }

    #[inline]
    pub fn contains(&self, dir: Vec3A) -> bool {
        dir.dot(self.axis) >= self.cos_half_angle
    }

    /// Whether the cone may meet the ball of `radius` about `centre` (conservative).
    #[inline]
    pub fn may_meet_ball(&self, centre: Vec3A, radius: f32) -> bool {
        let dist = centre.length();
        if dist <= radius * 1.0001 + 1e-6 {
            return true;
        }
        // The ball spans an angle beta = asin(r / d) about its centre's direction: it meets the
        // cone if that direction is within alpha + beta (< 180 degrees) of the axis.
        let sin_b = radius / dist;
        let cos_b = (1.0 - sin_b * sin_b).sqrt();
        let cos_sum = self.cos_half_angle * cos_b - self.sin_half_angle * sin_b;
        centre.dot(self.axis) >= (cos_sum - 1e-5) * dist
    }

    /// Whether two cones share a direction (conservative).
    pub fn may_meet_cone(&self, other: &Cone) -> bool {
        let cos_sum = self.cos_half_angle * other.cos_half_angle - self.sin_half_angle * other.sin_half_angle;
        self.axis.dot(other.axis) >= cos_sum - 1e-5
    }
}

/// One ray per useful pixel, ordered tile by tile.
#[derive(Clone, Debug)]
pub struct RayBundle {
    pub dirs: Vec<Vec3A>,
    /// Row-major crop index of each ray's pixel.
    pub indices: Vec<u32>,
    /// Each tile's range in `dirs` and its bounding cone.
    pub tiles: Vec<(std::ops::Range<usize>, Cone)>,
}

impl RayBundle {
    /// Side of a square tile, in pixels.
    pub const TILE_PX: u32 = 8;

    pub fn new(sensor: &Sensor) -> Self {
        let n = sensor.crop_size_px;
        let mut rays = sensor.pixel_rays();
        let tile_of = |i: u32| ((i / n) / Self::TILE_PX, (i % n) / Self::TILE_PX);
        rays.sort_by_key(|r| (tile_of(r.index), r.index));
        let dirs: Vec<Vec3A> = rays.iter().map(|r| crate::raycast::snap_direction(Vec3A::from(r.dir))).collect();
        let mut tiles = Vec::new();
        let mut start = 0;
        while start < rays.len() {
            let key = tile_of(rays[start].index);
            let end = start + rays[start..].iter().take_while(|r| tile_of(r.index) == key).count();
            let cone = Cone::around_directions(dirs[start..end].iter().copied())
                .expect("a tile of neighbouring pixels spans far less than 90 degrees");
            tiles.push((start..end, cone));
            start = end;
        }
        RayBundle { dirs, indices: rays.iter().map(|r| r.index).collect(), tiles }
    }

    pub fn len(&self) -> usize {
        self.dirs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_every_ray_once_and_their_cones_contain_them() {
        let sensor = Sensor::default();
        let rays = RayBundle::new(&sensor);
        assert_eq!(rays.len(), sensor.valid_count());
        let mut covered = 0;
        for (range, cone) in &rays.tiles {
            assert_eq!(range.start, covered);
            covered = range.end;
            assert!(range.len() <= 64);
            assert!(rays.dirs[range.clone()].iter().all(|&d| cone.contains(d)));
        }
        assert_eq!(covered, rays.len());
    }

    #[test]
    fn ball_and_cone_tests_are_conservative() {
        let cone = Cone::around_directions([Vec3A::new(0.1, 0.0, 1.0), Vec3A::new(-0.1, 0.05, 1.0)].into_iter()).unwrap();
        // A ball grazing the cone's edge from outside and one clearly away.
        let edge = Vec3A::new(0.1, 0.0, 1.0).normalize() * 20.0 + Vec3A::X * 0.5;
        assert!(cone.may_meet_ball(edge, 0.6));
        assert!(!cone.may_meet_ball(Vec3A::new(0.0, 0.0, -20.0), 1.0));
        assert!(!cone.may_meet_ball(Vec3A::new(10.0, 0.0, 1.0), 1.0));
        assert!(cone.may_meet_ball(Vec3A::new(0.3, 0.0, 0.1), 1.0), "a ball around the origin meets every cone");
        let far = Cone::around_directions([Vec3A::X].into_iter()).unwrap();
        assert!(!cone.may_meet_cone(&far));
        assert!(cone.may_meet_cone(&cone));
    }
}
