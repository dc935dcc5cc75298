//! A tile's rays in structure-of-arrays lanes, and the kernels that test a triangle against
//! eight of them at once: portable Rust, and AVX2 with the same arithmetic in the same order.

use glam::Vec3A;

use super::rays::{BallView, BallViews, BlockCones, Cone};
use super::triangle::OriginTriangle;
#[cfg(target_arch = "x86_64")]
use crate::simd::Avx2;

/// Rays of one tile in structure-of-arrays form, in groups of eight, so that testing a
/// triangle against them compiles to 8-wide SIMD arithmetic without bounds checks.
pub(super) const LANES: usize = 64;
/// Lanes tested together: one AVX2 register of f32.
const GROUP: usize = 8;
const GROUPS: usize = LANES / GROUP;

pub(super) struct Lanes {
    x: [[f32; GROUP]; GROUPS],
    y: [[f32; GROUP]; GROUPS],
    z: [[f32; GROUP]; GROUPS],
    /// Nearest hit so far; -1 for lanes that cast nothing (unwanted rays, padding).
    best: [[f32; GROUP]; GROUPS],
    /// The largest `best` of each group.
    group_reach: [f32; GROUPS],
    pub(super) wanted: usize,
}

/// Largest of eight values, as a tree of plain comparisons (a fold with `f32::max` is a serial
/// chain of NaN-aware steps; our values are never NaN).
#[inline(always)]
fn max8(v: &[f32; 8]) -> f32 {
    let m = |a: f32, b: f32| if a > b { a } else { b };
    m(m(m(v[0], v[4]), m(v[2], v[6])), m(m(v[1], v[5]), m(v[3], v[7])))
}

impl Lanes {
    pub(super) fn new(dirs: &[Vec3A], wanted: impl Fn(Vec3A) -> bool, t_max: f32) -> Self {
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

    pub(super) fn best(&self, i: usize) -> f32 {
        self.best[i / GROUP][i % GROUP]
    }

    /// The farthest any lane still looks.
    #[inline(always)]
    pub(super) fn reach(&self) -> f32 {
        max8(&self.group_reach)
    }

    /// Tests every lane against `tri` with the f32 edge tests, a group at a time, skipping
    /// groups whose rays all hit something nearer than `near`. Lanes where an edge test is within
    /// its rounding bound of zero are left alone and reported (true) for the exact pass.
    #[inline(always)]
    pub(super) fn test<K: GroupKernel>(&mut self, kernel: K, tri: &OriginTriangle, near: f32) -> bool {
        let mut ambiguous = false;
        for g in 0..GROUPS {
            if self.group_reach[g] < near {
                continue;
            }
            ambiguous |= kernel.test_group(self, g, tri);
            self.group_reach[g] = max8(&self.best[g]);
        }
        ambiguous
    }

    /// The lanes `test` left alone, one at a time with exact signs.
    #[cold]
    pub(super) fn test_ambiguous(&mut self, tri: &OriginTriangle) {
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
pub(super) trait GroupKernel: Copy {
    fn test_group(self, lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool;
    /// The tiles among `active` whose cones may meet `view` (`BlockCones::meeting`).
    fn meeting(self, cones: &BlockCones, view: &BallView, active: u64) -> u64;
    /// The balls `cone` may meet (`BallViews::meeting`).
    fn scan(self, views: &BallViews, cone: &Cone, out: &mut Vec<u32>);
}

/// Plain Rust, for any CPU.
#[derive(Clone, Copy)]
pub(super) struct Portable;

impl GroupKernel for Portable {
    #[inline(always)]
    fn test_group(self, lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool {
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
    fn meeting(self, cones: &BlockCones, view: &BallView, active: u64) -> u64 {
        cones.meeting(view, active)
    }

    #[inline(always)]
    fn scan(self, views: &BallViews, cone: &Cone, out: &mut Vec<u32>) {
        views.meeting(cone, out)
    }
}

/// AVX2: the same arithmetic (multiplies then adds in `dot3`'s order, no fused multiply-add),
/// eight lanes per instruction, so results match `Portable` bit for bit.
/// Made only from an [`Avx2`] token, so only on CPUs that have AVX2.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct Avx2Kernel(pub(super) Avx2);

#[cfg(target_arch = "x86_64")]
impl GroupKernel for Avx2Kernel {
    #[inline(always)]
    fn test_group(self, lanes: &mut Lanes, g: usize, tri: &OriginTriangle) -> bool {
        // SAFETY: an `Avx2Kernel` holds an `Avx2` token, which exists only where run-time
        // detection found AVX2.
        unsafe { avx2_test_group(&lanes.x[g], &lanes.y[g], &lanes.z[g], &mut lanes.best[g], tri) }
    }

    #[inline(always)]
    fn meeting(self, cones: &BlockCones, view: &BallView, active: u64) -> u64 {
        cones.meeting_avx2(self.0, view, active)
    }

    #[inline(always)]
    fn scan(self, views: &BallViews, cone: &Cone, out: &mut Vec<u32>) {
        views.meeting_avx2(self.0, cone, out)
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
