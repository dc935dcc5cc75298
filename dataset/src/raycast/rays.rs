//! The sensor's rays, grouped into small square tiles of neighbouring pixels.
//!
//! Rays of a tile point in nearly the same direction, so one bounding cone per tile (and one
//! per block of tiles) lets the ray caster find the few triangles a tile can reach once for all
//! its rays, and test each ray against only those.

use glam::Vec3A;
use sensor::Sensor;

#[cfg(target_arch = "x86_64")]
use crate::simd::Avx2;

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
        let a = self.axis;
        meets([a.x, a.y, a.z], self.cos_half_angle, self.sin_half_angle, view.dir.to_array(), view.cos_b, view.sin_b)
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

/// The cone test itself: a cone about `axis` of half-angle alpha meets a ball seen at `dir`
/// spanning beta when `dir` lies within alpha + beta of the axis (with a margin for rounding).
/// Every scalar form calls this, and the AVX2 forms do the same operations in the same order,
/// so all of them agree bit for bit.
#[inline(always)]
fn meets(axis: [f32; 3], cos_a: f32, sin_a: f32, dir: [f32; 3], cos_b: f32, sin_b: f32) -> bool {
    let cos_sum = cos_a * cos_b - sin_a * sin_b;
    let dot = dir[0] * axis[0] + dir[1] * axis[1] + dir[2] * axis[2];
    dot >= cos_sum - 1e-5
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

/// Many balls' views in structure-of-arrays form, so that one cone is tested against eight of
/// them per instruction (`Cone::may_meet`'s test).
#[derive(Clone, Debug, Default)]
pub struct BallViews {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    cos: Vec<f32>,
    sin: Vec<f32>,
}

impl BallViews {
    pub fn new(views: impl Iterator<Item = BallView>) -> Self {
        let mut b = BallViews::default();
        for v in views {
            b.x.push(v.dir.x);
            b.y.push(v.dir.y);
            b.z.push(v.dir.z);
            b.cos.push(v.cos_b);
            b.sin.push(v.sin_b);
        }
        b
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Appends to `out` the index of every ball that `cone` may meet, in order.
    #[inline(always)]
    pub fn meeting(&self, cone: &Cone, out: &mut Vec<u32>) {
        self.meeting_from(0, cone, out)
    }

    /// `meeting` over the balls from index `start` on.
    #[inline(always)]
    fn meeting_from(&self, start: usize, cone: &Cone, out: &mut Vec<u32>) {
        let a = cone.axis;
        for i in start..self.len() {
            let dir = [self.x[i], self.y[i], self.z[i]];
            if meets([a.x, a.y, a.z], cone.cos_half_angle, cone.sin_half_angle, dir, self.cos[i], self.sin[i]) {
                out.push(i as u32);
            }
        }
    }

    /// `meeting` with AVX2 intrinsics: the same answers.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) fn meeting_avx2(&self, _: Avx2, cone: &Cone, out: &mut Vec<u32>) {
        // SAFETY: an `Avx2` token exists only where run-time detection found AVX2.
        unsafe { self.meeting_avx2_unchecked(cone, out) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn meeting_avx2_unchecked(&self, cone: &Cone, out: &mut Vec<u32>) {
        use std::arch::x86_64::*;
        let a = cone.axis;
        let (ax, ay, az) = (_mm256_set1_ps(a.x), _mm256_set1_ps(a.y), _mm256_set1_ps(a.z));
        let (ca, sa, eps) =
            (_mm256_set1_ps(cone.cos_half_angle), _mm256_set1_ps(cone.sin_half_angle), _mm256_set1_ps(1e-5));
        let whole = self.len() / 8 * 8;
        for g in (0..whole).step_by(8) {
            // SAFETY: g + 8 <= len for every array; unaligned loads.
            let load = |v: &Vec<f32>| unsafe { _mm256_loadu_ps(v.as_ptr().add(g)) };
            let cos_sum = _mm256_sub_ps(_mm256_mul_ps(ca, load(&self.cos)), _mm256_mul_ps(sa, load(&self.sin)));
            let dot = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(load(&self.x), ax), _mm256_mul_ps(load(&self.y), ay)),
                _mm256_mul_ps(load(&self.z), az),
            );
            let mut bits = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(dot, _mm256_sub_ps(cos_sum, eps))) as u32;
            while bits != 0 {
                out.push(g as u32 + bits.trailing_zeros());
                bits &= bits - 1;
            }
        }
        self.meeting_from(whole, cone, out);
    }
}

/// Most tiles a block may hold: one bit each in a `u64` mask.
pub const BLOCK_MAX_TILES: usize = 64;

/// The cones of one block's tiles in structure-of-arrays form: a ball is tested against all of
/// them at once, eight lanes per instruction, and the answer is a bit mask of the tiles that
/// may meet it. The test is `Cone::may_meet`'s.
pub struct BlockCones {
    x: [f32; BLOCK_MAX_TILES],
    y: [f32; BLOCK_MAX_TILES],
    z: [f32; BLOCK_MAX_TILES],
    cos: [f32; BLOCK_MAX_TILES],
    sin: [f32; BLOCK_MAX_TILES],
}

impl BlockCones {
    /// At most `BLOCK_MAX_TILES` cones; lanes beyond them hold zeros (and are masked off by
    /// the callers' `active` bits).
    pub fn new<'a>(cones: impl ExactSizeIterator<Item = &'a Cone>) -> Self {
        assert!(cones.len() <= BLOCK_MAX_TILES, "a block holds at most {BLOCK_MAX_TILES} tiles");
        let mut b = BlockCones {
            x: [0.0; BLOCK_MAX_TILES],
            y: [0.0; BLOCK_MAX_TILES],
            z: [0.0; BLOCK_MAX_TILES],
            cos: [0.0; BLOCK_MAX_TILES],
            sin: [0.0; BLOCK_MAX_TILES],
        };
        for (k, c) in cones.enumerate() {
            (b.x[k], b.y[k], b.z[k]) = (c.axis.x, c.axis.y, c.axis.z);
            (b.cos[k], b.sin[k]) = (c.cos_half_angle, c.sin_half_angle);
        }
        b
    }

    /// The tiles among `active` whose cones may meet `view`.
    #[inline(always)]
    pub fn meeting(&self, view: &BallView, active: u64) -> u64 {
        let mut mask = 0;
        for g in (0..BLOCK_MAX_TILES).step_by(8) {
            if (active >> g) & 0xff == 0 {
                continue;
            }
            for k in g..g + 8 {
                let axis = [self.x[k], self.y[k], self.z[k]];
                let met = meets(axis, self.cos[k], self.sin[k], view.dir.to_array(), view.cos_b, view.sin_b);
                mask |= (met as u64) << k;
            }
        }
        mask & active
    }

    /// `meeting` with AVX2 intrinsics: the same answers.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) fn meeting_avx2(&self, _: Avx2, view: &BallView, active: u64) -> u64 {
        // SAFETY: an `Avx2` token exists only where run-time detection found AVX2.
        unsafe { self.meeting_avx2_unchecked(view, active) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn meeting_avx2_unchecked(&self, view: &BallView, active: u64) -> u64 {
        use std::arch::x86_64::*;
        let (dx, dy, dz) = (_mm256_set1_ps(view.dir.x), _mm256_set1_ps(view.dir.y), _mm256_set1_ps(view.dir.z));
        let (cb, sb, eps) = (_mm256_set1_ps(view.cos_b), _mm256_set1_ps(view.sin_b), _mm256_set1_ps(1e-5));
        let mut mask = 0;
        for g in (0..BLOCK_MAX_TILES).step_by(8) {
            if (active >> g) & 0xff == 0 {
                continue;
            }
            // SAFETY: g + 8 <= BLOCK_MAX_TILES; unaligned loads.
            let load = |a: &[f32; BLOCK_MAX_TILES]| unsafe { _mm256_loadu_ps(a.as_ptr().add(g)) };
            let cos_sum = _mm256_sub_ps(_mm256_mul_ps(load(&self.cos), cb), _mm256_mul_ps(load(&self.sin), sb));
            let dot = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(dx, load(&self.x)), _mm256_mul_ps(dy, load(&self.y))),
                _mm256_mul_ps(dz, load(&self.z)),
            );
            let meets = _mm256_cmp_ps::<_CMP_GE_OQ>(dot, _mm256_sub_ps(cos_sum, eps));
            mask |= (_mm256_movemask_ps(meets) as u32 as u64) << g;
        }
        mask & active
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
    /// Each block's bounding cone (`None` where one would reach 90 degrees).
    pub block_cones: Vec<Option<Cone>>,
}

impl RayBundle {
    /// The dome as these rays see it, for the contact model: force labels then read the same
    /// directions as the depth maps cast along them.
    pub fn dome(&self, sensor: &Sensor) -> mechanics::Dome {
        mechanics::Dome::of_rays(sensor, self.indices.iter().zip(&self.dirs).map(|(&i, &d)| (i, d.into())))
    }

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
        let dirs: Vec<Vec3A> = rays.iter().map(|r| super::triangle::snap_direction(Vec3A::from(r.dir))).collect();
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
        let block_cones = blocks
            .iter()
            .map(|b| Cone::around_directions(dirs[tiles[b.start].0.start..tiles[b.end - 1].0.end].iter().copied()))
            .collect();
        RayBundle { dirs, indices: rays.iter().map(|r| r.index).collect(), tiles, blocks, block_cones }
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
            assert!(b.len() <= BLOCK_MAX_TILES);
            next = b.end;
        }
        assert_eq!(next, rays.tiles.len());
        for (b, cone) in rays.blocks.iter().zip(&rays.block_cones) {
            let cone = cone.expect("a block spans less than 90 degrees");
            let dirs = &rays.dirs[rays.tiles[b.start].0.start..rays.tiles[b.end - 1].0.end];
            assert!(dirs.iter().all(|&d| cone.contains(d)));
        }
    }

    /// The SIMD tests of many balls against one cone, and of one ball against a block's cones,
    /// answer exactly as `Cone::may_meet` does, one pair at a time.
    #[test]
    fn batched_cone_tests_agree_with_single_ones() {
        let mut rng = formats::SplitMix64::new(11);
        let mut dir = || Vec3A::new(rng.normal() as f32, rng.normal() as f32, rng.normal() as f32).normalize();
        let mut cones = Vec::new();
        while cones.len() < BLOCK_MAX_TILES {
            let axis = dir();
            let spread: Vec<Vec3A> = (0..4).map(|_| (axis * 3.0 + dir()).normalize()).collect();
            cones.extend(Cone::around_directions(spread.into_iter()));
        }
        let balls: Vec<BallView> =
            (0..203).map(|i| BallView::new(dir() * (1.0 + i as f32 * 0.1), 0.05 + (i % 7) as f32 * 0.3)).collect();
        let views = BallViews::new(balls.iter().copied());
        let block = BlockCones::new(cones.iter());
        let active = 0xf0f0_ffff_0000_ff0f_u64;
        for cone in &cones {
            let want: Vec<u32> = (0..balls.len() as u32).filter(|&i| cone.may_meet(&balls[i as usize])).collect();
            let mut got = Vec::new();
            views.meeting(cone, &mut got);
            assert_eq!(got, want);
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = Avx2::detect() {
                got.clear();
                views.meeting_avx2(avx2, cone, &mut got);
                assert_eq!(got, want);
            }
        }
        let mut met = 0;
        for ball in &balls {
            let want = (0..BLOCK_MAX_TILES)
                .filter(|&k| active >> k & 1 == 1 && cones[k].may_meet(ball))
                .fold(0u64, |m, k| m | 1 << k);
            assert_eq!(block.meeting(ball, active), want);
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = Avx2::detect() {
                assert_eq!(block.meeting_avx2(avx2, ball, active), want);
            }
            met += want.count_ones();
        }
        assert!(met > 0 && met < balls.len() as u32 * active.count_ones(), "the cases meet some and miss some");
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
