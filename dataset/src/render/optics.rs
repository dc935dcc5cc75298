//! What stands between the shaded membrane and the recorded bytes: the lens' blur, the camera's
//! tone curve and its JPEG stream.
//!
//! The blur works only where a frame differs from the unit's no-contact image (the rows the
//! change touches grown by its radius), so a frame with a small contact costs little more than
//! one without.

/// A Gaussian point spread, truncated at one and a half standard deviations (at least one
/// sample) and normalised, applied separably with zero padding (so it is linear: blurring the
/// reference once and each frame's change to it gives the blurred frame).
#[derive(Clone, Debug)]
pub(crate) struct LensBlur {
    weights: Vec<f32>,
}

impl LensBlur {
    /// `None` for a sharp lens.
    pub(crate) fn new(sigma_steps: f64) -> Option<Self> {
        if !(sigma_steps.is_finite() && sigma_steps > 0.05) {
            return None;
        }
        let radius = (1.5 * sigma_steps).ceil().max(1.0) as i32;
        let raw: Vec<f64> = (-radius..=radius).map(|k| (-0.5 * (k as f64 / sigma_steps).powi(2)).exp()).collect();
        let sum: f64 = raw.iter().sum();
        Some(LensBlur { weights: raw.iter().map(|w| (w / sum) as f32).collect() })
    }

    fn radius(&self) -> usize {
        self.weights.len() / 2
    }

    /// Blurs the whole RGB `image` of `width` samples a row.
    pub(crate) fn whole(&self, image: &[[f32; 3]], width: usize) -> Vec<[f32; 3]> {
        let height = image.len() / width;
        self.rows(image, 0, width, height).1
    }

    /// Blurs `rows` (whole rows of a `width` x `height` grid, the first being row `y0`; zero
    /// everywhere else): returns the first row the blur reaches and the blurred rows from there
    /// (the given ones grown by the kernel's radius, within the grid).
    pub(super) fn rows(&self, rows: &[[f32; 3]], y0: usize, width: usize, height: usize) -> (usize, Vec<[f32; 3]>) {
        crate::simd::avx2_where_present(
            #[inline(always)]
            || self.rows_inline(rows, y0, width, height),
        )
    }

    #[inline(always)]
    fn rows_inline(&self, rows: &[[f32; 3]], y0: usize, width: usize, height: usize) -> (usize, Vec<[f32; 3]>) {
        let r = self.radius();
        let n = rows.len() / width;
        let row_len = 3 * width;
        // Along each row, on the interleaved values (a tap is three values away per sample).
        let mut across = vec![0f32; rows.len() * 3];
        for (dst, src) in across.chunks_exact_mut(row_len).zip(rows.as_flattened().chunks_exact(row_len)) {
            for (k, &w) in self.weights.iter().enumerate() {
                // Output sample x reads input sample x + k - r.
                let shift = 3 * k.abs_diff(r);
                if shift >= row_len {
                    continue;
                }
                let (d, s) = if k >= r {
                    (&mut dst[..row_len - shift], &src[shift..])
                } else {
                    (&mut dst[shift..], &src[..row_len - shift])
                };
                for (d, s) in d.iter_mut().zip(s) {
                    *d += w * s;
                }
            }
        }
        // Then down the columns, whole rows at a time.
        let (first, last) = (y0.saturating_sub(r), (y0 + n + r).min(height));
        let mut out = vec![[0f32; 3]; (last - first) * width];
        for (y, dst) in (first..last).zip(out.as_flattened_mut().chunks_exact_mut(row_len)) {
            for (k, &w) in self.weights.iter().enumerate() {
                // Output row y reads row y + k - r, if it is one of the given rows.
                let Some(src_row) = (y + k).checked_sub(r + y0).filter(|&j| j < n) else {
                    continue;
                };
                for (d, s) in dst.iter_mut().zip(&across[src_row * row_len..][..row_len]) {
                    *d += w * s;
                }
            }
        }
        (first, out)
    }
}

/// The camera's tone curve from linear grey levels to 8 bits, as a table over sixteenths of a
/// level (a power law costs too much per value; the table's rounding is at most 1/32 level
/// before the curve).
#[derive(Clone, Debug)]
pub(super) struct Tone {
    table: Vec<u8>,
}

/// Table entries per grey level.
pub(super) const TONE_STEPS: f32 = 16.0;

/// Bytes after the table's last entry, so that a 32-bit gather at any entry stays inside.
const TONE_PADDING: usize = 3;

impl Tone {
    /// `None` for a linear camera (gamma 1), which rounds directly.
    pub(super) fn new(gamma: f64) -> Option<Self> {
        if (gamma - 1.0).abs() < 1e-9 {
            return None;
        }
        let n = (255.0 * TONE_STEPS) as usize + 1;
        let table = (0..n)
            .map(|k| {
                let v = k as f64 / TONE_STEPS as f64 / 255.0;
                (255.0 * v.powf(1.0 / gamma)).round().clamp(0.0, 255.0) as u8
            })
            .chain([0; TONE_PADDING])
            .collect();
        Some(Tone { table })
    }

    /// The table, entry `k` for the linear level `k / TONE_STEPS`, followed by
    /// `TONE_PADDING` bytes that no level reads.
    pub(super) fn padded_table(&self) -> &[u8] {
        &self.table
    }

    /// One linear value to 8 bits (NaN becomes 0, as in [`super::noise::quantise`]).
    #[inline(always)]
    pub(super) fn apply(&self, v: f32) -> u8 {
        self.table[(v.clamp(0.0, 255.0) * TONE_STEPS + 0.5) as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blur keeps a constant image constant away from the borders, keeps the total, and
    /// blurring a change gives what blurring the whole image does.
    #[test]
    fn blur_is_normalised_and_linear() {
        let blur = LensBlur::new(0.8).unwrap();
        let sum: f32 = blur.weights.iter().sum();
        assert!((sum - 1.0).abs() < 1e-6);
        let (w, h) = (30, 20);
        let flat = vec![[10.0f32, 20.0, 30.0]; w * h];
        let out = blur.whole(&flat, w);
        let mid = out[10 * w + 15];
        assert!((mid[0] - 10.0).abs() < 1e-4 && (mid[2] - 30.0).abs() < 1e-4, "{mid:?}");
        // A point spreads into the kernel's outer product; blurring only the rows that hold the
        // change gives what blurring the whole image does.
        let mut delta = vec![[0f32; 3]; w * h];
        delta[8 * w + 12] = [1.0, 2.0, 4.0];
        delta[9 * w + 3] = [-1.0, 0.5, 0.0];
        let whole = blur.whole(&delta, w);
        let (first, rows) = blur.rows(&delta[8 * w..10 * w], 8, w, h);
        assert_eq!(first, 8 - blur.radius());
        let mut rebuilt = vec![[0f32; 3]; w * h];
        rebuilt[first * w..][..rows.len()].copy_from_slice(&rows);
        for (a, b) in rebuilt.iter().zip(&whole) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-6, "{a:?} vs {b:?}");
            }
        }
        let r = blur.radius();
        let wk = |k: i32| blur.weights[(k + r as i32) as usize];
        let got = whole[(8 + 1) * w + 12 - 1][2];
        assert!((got - 4.0 * wk(1) * wk(-1)).abs() < 1e-6);
        assert!(LensBlur::new(0.0).is_none());
    }

    #[test]
    fn tone_curve_brightens_darks_and_keeps_the_ends() {
        let tone = Tone::new(2.0).unwrap();
        assert_eq!(tone.apply(0.0), 0);
        assert_eq!(tone.apply(255.0), 255);
        assert_eq!(tone.apply(1e9), 255);
        assert_eq!(tone.apply(f32::NAN), 0);
        // 255 * sqrt(64 / 255) = 127.75
        assert_eq!(tone.apply(64.0), 128);
        let mut last = 0;
        for k in 0..=2550 {
            let v = tone.apply(k as f32 / 10.0);
            assert!(v >= last);
            last = v;
        }
        assert!(Tone::new(1.0).is_none());
    }
}
