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
        let cos =
            dirs.map(|d| glam::DVec3::from(d.to_array().map(f64::from)).normalize().dot(axis)).fold(1.0f64, f64::min)
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

    /// Whether the cone may meet a ball, seen from the origin as `view` (conservative).
    #[inline(always)]
    pub fn may_meet(&self, view: &BallView) -> bool {
        // The ball spans beta about its direction: it meets the cone if that direction is
        // within alpha + beta (< 180 degrees) of the axis.
        let cos_sum = self.cos_half_angle * view.cos_b - self.sin_half_angle * view.sin_b;
        view.dir.dot(self.axis) >= cos_sum - 1e-5
    }

    /// Whether the cone may meet the ball of `radius` about `centre` (conservative).
    pub fn may_meet_ball(&self, centre: Vec3A, radius: f32) -> bool {
        self.may_meet(&BallView::new(centre, radius))
    }

    /// Whether two cones share a direction (conservative).
    pub fn may_meet_cone(&self, other: &Cone) -> bool {
        let cos_sum = self.cos_half_angle * other.cos_half_angle - self.sin_half_angle * other.sin_half_angle;
        self.axis.dot(other.axis) >= cos_sum - 1e-5
    }
}

/// A ball as seen from the origin: its direction and the sine and cosine of the angle it spans.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BallView {
    dir: Vec3A,
    cos_b: f32,
    sin_b: f32,
}

impl BallView {
    pub fn new(centre: Vec3A, radius: f32) -> Self {
        let (c, r) = (glam::DVec3::from(centre.to_array().map(f64::from)), radius as f64 * 1.0001 + 1e-6);
        let dist = c.length();
        if dist <= r {
            // The ball holds the origin: every direction meets it (0 >= -cos(alpha) - eps).
            return BallView { dir: Vec3A::ZERO, cos_b: -1.0, sin_b: 0.0 };
        }
        let sin_b = r / dist;
        let cos_b = (1.0 - sin_b * sin_b).sqrt();
        // Widen by a hair so that f32 rounding cannot make the test reject a true meeting.
        BallView {
            dir: Vec3A::from((c / dist).as_vec3()),
            cos_b: (cos_b - 1e-6) as f32,
            sin_b: (sin_b + 1e-6).min(1.0) as f32,
        }
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
    /// Blocks of neighbouring tiles (ranges in `tiles`), cast together.
    pub blocks: Vec<std::ops::Range<usize>>,
}

impl RayBundle {
    /// Side of a square tile, in pixels.
    pub const TILE_PX: u32 = 8;
    /// Side of a square block, in tiles.
    pub const BLOCK_TILES: u32 = 8;

    pub fn new(sensor: &Sensor) -> Self {
        let n = sensor.crop_size_px;
        let mut rays = sensor.pixel_rays();
        let tile_of = |i: u32| ((i / n) / Self::TILE_PX, (i % n) / Self::TILE_PX);
        let block_of = |i: u32| {
            let (ty, tx) = tile_of(i);
            (ty / Self::BLOCK_TILES, tx / Self::BLOCK_TILES)
        };
        rays.sort_by_key(|r| (block_of(r.index), tile_of(r.index), r.index));
        let dirs: Vec<Vec3A> = rays.iter().map(|r| crate::raycast::snap_direction(Vec3A::from(r.dir))).collect();
        let mut tiles: Vec<(std::ops::Range<usize>, Cone)> = Vec::new();
        let mut blocks: Vec<std::ops::Range<usize>> = Vec::new();
        let mut start = 0;
        while start < rays.len() {
            if blocks.last().is_none_or(|b| block_of(rays[tiles[b.start].0.start].index) != block_of(rays[start].index))
            {
                blocks.push(tiles.len()..tiles.len());
            }
            blocks.last_mut().unwrap().end += 1;
            let key = tile_of(rays[start].index);
            let end = start + rays[start..].iter().take_while(|r| tile_of(r.index) == key).count();
            let cone = Cone::around_directions(dirs[start..end].iter().copied())
                .expect("a tile of neighbouring pixels spans far less than 90 degrees");
            tiles.push((start..end, cone));
            start = end;
        }
        RayBundle { dirs, indices: rays.iter().map(|r| r.index).collect(), tiles, blocks }
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
        let mut next = 0;
        for b in &rays.blocks {
            assert_eq!(b.start, next);
            assert!(b.len() <= 64);
            next = b.end;
        }
        assert_eq!(next, rays.tiles.len());
    }

    #[test]
    fn ball_and_cone_tests_are_conservative() {
        let cone =
            Cone::around_directions([Vec3A::new(0.1, 0.0, 1.0), Vec3A::new(-0.1, 0.05, 1.0)].into_iter()).unwrap();
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
