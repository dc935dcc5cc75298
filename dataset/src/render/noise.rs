//! Camera noise: signal-dependent Gaussian noise added to linear grey levels, rounded to 8 bits.

use formats::SplitMix64;

use super::optics::Tone;
#[cfg(target_arch = "x86_64")]
use crate::simd::Avx2;
use crate::unit::SensorUnit;

/// A grey level rounded to 8 bits (non-negative after the clamp, so adding a half and
/// truncating rounds; NaN becomes 0).
#[inline(always)]
pub(super) fn quantise(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

/// How the camera turns a noisy linear grey level into its byte.
#[derive(Clone, Copy)]
pub(super) enum Finish<'a> {
    /// A linear camera: rounded.
    Round,
    /// Through the camera's tone curve.
    Tone(&'a Tone),
}

impl Finish<'_> {
    #[inline(always)]
    fn apply(self, v: f32) -> u8 {
        match self {
            Finish::Round => quantise(v),
            Finish::Tone(tone) => tone.apply(v),
        }
    }
}

/// Length of the shared table of standard normals: more values than an 800x600 RGB frame has,
/// so a frame never meets the same value twice.
pub(super) const NOISE_TABLE_LEN: usize = 1 << 21;

/// Standard normals (Box-Muller from a fixed stream), computed once per process.
fn noise_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = SplitMix64::new(0x6e01_5e7a_b1e5);
        (0..NOISE_TABLE_LEN).map(|_| rng.normal() as f32).collect()
    })
}

/// Signal-dependent Gaussian noise (read noise plus shot noise). Each frame reads the shared
/// table of normals from its own seeded offset: values within a frame are independent, frames
/// get different noise, and adding it is a plain vectorised pass (film-grain synthesis does the
/// same).
pub(super) struct GaussianNoise {
    table: &'static [f32],
    pub(super) pos: usize,
    level: NoiseLevel,
}

/// How strong a unit's noise is at each grey level.
#[derive(Clone, Copy)]
struct NoiseLevel {
    read_var: f32,
    shot_gain: f32,
}

impl NoiseLevel {
    /// Standard deviation of the noise at grey level `v`: read noise plus shot noise.
    #[inline(always)]
    fn sigma(self, v: f32) -> f32 {
        (self.read_var + self.shot_gain * v.max(0.0)).sqrt()
    }

    /// The portable kernel: each value plus its normal times the noise's spread, finished.
    #[inline(always)]
    fn add_finished(self, values: &[f32], normals: &[f32], out: &mut [u8], finish: Finish) {
        for ((b, &v), &z) in out.iter_mut().zip(values).zip(normals) {
            *b = finish.apply(v + z * self.sigma(v));
        }
    }
}

impl GaussianNoise {
    pub(super) fn new(seed: u64, unit: &SensorUnit) -> Self {
        let c = &unit.camera;
        GaussianNoise {
            table: noise_table(),
            pos: (SplitMix64::new(seed).next_u64() as usize) % NOISE_TABLE_LEN,
            level: NoiseLevel { read_var: (c.read_noise * c.read_noise) as f32, shot_gain: c.shot_gain as f32 },
        }
    }

    /// Adds noise to interleaved RGB values and finishes them to bytes.
    pub(super) fn add_finished(&mut self, values: &[f32], out: &mut [u8], finish: Finish) {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            return self.add_finished_avx2(avx2, values, out, finish);
        }
        self.add_finished_portable(values, out, finish)
    }

    pub(super) fn add_finished_portable(&mut self, values: &[f32], out: &mut [u8], finish: Finish) {
        let level = self.level;
        self.add_finished_runs(values, out, |v, z, o| level.add_finished(v, z, o, finish))
    }

    /// The portable kernel's arithmetic in AVX2 intrinsics: the same bytes.
    #[cfg(target_arch = "x86_64")]
    pub(super) fn add_finished_avx2(&mut self, _: Avx2, values: &[f32], out: &mut [u8], finish: Finish) {
        // SAFETY: an `Avx2` token exists only where run-time detection found AVX2.
        unsafe { self.add_finished_avx2_unchecked(values, out, finish) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn add_finished_avx2_unchecked(&mut self, values: &[f32], out: &mut [u8], finish: Finish) {
        use std::arch::x86_64::*;
        let level = self.level;
        let (read_var, shot_gain) = (_mm256_set1_ps(level.read_var), _mm256_set1_ps(level.shot_gain));
        let (zero, top, half) = (_mm256_setzero_ps(), _mm256_set1_ps(255.0), _mm256_set1_ps(0.5));
        let (steps, low_byte) = (_mm256_set1_ps(super::optics::TONE_STEPS), _mm256_set1_epi32(0xff));
        self.add_finished_runs(values, out, |values, normals, out| {
            let whole = values.len() / 8 * 8;
            for k in (0..whole).step_by(8) {
                // SAFETY: k + 8 <= len of all three slices; unaligned loads and an 8-byte store;
                // the gather reads 4 bytes at an entry of at most 255 * TONE_STEPS, which the
                // padded table holds.
                unsafe {
                    let v = _mm256_loadu_ps(values.as_ptr().add(k));
                    let z = _mm256_loadu_ps(normals.as_ptr().add(k));
                    // `sigma`, then `quantise` or `Tone::apply`, step for step (a NaN ends as
                    // 0 either way, since max_ps answers its second operand for one).
                    let sigma =
                        _mm256_sqrt_ps(_mm256_add_ps(read_var, _mm256_mul_ps(shot_gain, _mm256_max_ps(v, zero))));
                    let noisy = _mm256_add_ps(v, _mm256_mul_ps(z, sigma));
                    let clamped = _mm256_min_ps(_mm256_max_ps(noisy, zero), top);
                    let ints = match finish {
                        Finish::Round => _mm256_cvttps_epi32(_mm256_add_ps(clamped, half)),
                        Finish::Tone(tone) => {
                            let entry = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(clamped, steps), half));
                            let table = tone.padded_table().as_ptr() as *const i32;
                            _mm256_and_si256(_mm256_i32gather_epi32::<1>(table, entry), low_byte)
                        }
                    };
                    let words = _mm_packus_epi32(_mm256_castsi256_si128(ints), _mm256_extracti128_si256::<1>(ints));
                    _mm_storel_epi64(out.as_mut_ptr().add(k) as *mut __m128i, _mm_packus_epi16(words, words));
                }
            }
            level.add_finished(&values[whole..], &normals[whole..], &mut out[whole..], finish);
        })
    }

    /// Hands `kernel` contiguous runs of values with their normals, wrapping at the table's end.
    #[inline(always)]
    fn add_finished_runs(&mut self, values: &[f32], out: &mut [u8], kernel: impl Fn(&[f32], &[f32], &mut [u8])) {
        self.runs(values.len(), |range, normals| kernel(&values[range.clone()], normals, &mut out[range]))
    }

    /// Splits `len` values into contiguous runs, each with as many normals from the table,
    /// wrapping at the table's end: `each(run's range, its normals)`.
    #[inline(always)]
    fn runs(&mut self, len: usize, mut each: impl FnMut(std::ops::Range<usize>, &[f32])) {
        let mut done = 0;
        while done < len {
            let n = (len - done).min(NOISE_TABLE_LEN - self.pos);
            each(done..done + n, &self.table[self.pos..self.pos + n]);
            self.pos = (self.pos + n) % NOISE_TABLE_LEN;
            done += n;
        }
    }

    #[inline]
    pub(super) fn add_to(&mut self, px: [f32; 3]) -> [f32; 3] {
        let out = std::array::from_fn(|c| {
            let z = self.table[(self.pos + c) % NOISE_TABLE_LEN];
            px[c] + z * self.level.sigma(px[c])
        });
        self.pos = (self.pos + 3) % NOISE_TABLE_LEN;
        out
    }
}
