//! Resizing single-channel float planes (depth in millimetres) without clamping.
//!
//! The `image` crate's resize clamps float pixels to [0, 1], which silently cuts depth maps at
//! 1 mm; this separable triangle filter keeps every value. Pixel centres are aligned (half-pixel
//! convention) and the filter widens when shrinking, so it averages the pixels it replaces.

/// Weights of a 1-D triangle resampling from `n_src` to `n_dst` samples: per output sample, the
/// first input index and its weights (summing to one). Public for the ONNX export, which
/// writes the same resampling as matrices.
pub fn triangle_weights(n_src: usize, n_dst: usize) -> Vec<(usize, Vec<f32>)> {
    let scale = n_src as f64 / n_dst as f64;
    let radius = scale.max(1.0);
    (0..n_dst)
        .map(|i| {
            let centre = (i as f64 + 0.5) * scale - 0.5;
            let lo = ((centre - radius).floor() as i64 + 1).max(0) as usize;
            let hi = ((centre + radius).ceil() as i64 - 1).min(n_src as i64 - 1).max(lo as i64) as usize;
            let mut w: Vec<f64> = (lo..=hi).map(|j| (1.0 - (j as f64 - centre).abs() / radius).max(0.0)).collect();
            let sum: f64 = w.iter().sum();
            if sum > 0.0 {
                w.iter_mut().for_each(|v| *v /= sum);
            } else {
                // Only possible at the very edge: take the nearest sample.
                w = vec![0.0; hi - lo + 1];
                let nearest = (centre.round().clamp(lo as f64, hi as f64) as usize) - lo;
                w[nearest] = 1.0;
            }
            (lo, w.into_iter().map(|v| v as f32).collect())
        })
        .collect()
}

/// Resizes a row-major `[height, width]` plane to `[new_height, new_width]`.
pub fn resize_plane(values: &[f32], [height, width]: [usize; 2], [new_height, new_width]: [usize; 2]) -> Vec<f32> {
    assert_eq!(values.len(), height * width, "plane size");
    let (wx, wy) = (triangle_weights(width, new_width), triangle_weights(height, new_height));
    let mut rows = vec![0f32; height * new_width];
    for y in 0..height {
        let src = &values[y * width..(y + 1) * width];
        for (x, (lo, w)) in wx.iter().enumerate() {
            rows[y * new_width + x] = w.iter().zip(&src[*lo..]).map(|(a, b)| a * b).sum();
        }
    }
    let mut out = vec![0f32; new_height * new_width];
    for (y, (lo, w)) in wy.iter().enumerate() {
        for (k, wk) in w.iter().enumerate() {
            let src = &rows[(lo + k) * new_width..(lo + k + 1) * new_width];
            for (o, s) in out[y * new_width..(y + 1) * new_width].iter_mut().zip(src) {
                *o += wk * s;
            }
        }
    }
    out
}

/// Which pixels of a `[height, width]` grid lie wholly on true pixels of a square `side` x
/// `side` mask: the network output pixels a masked loss trains (training and inference share it).
pub fn covered_mask(mask: &[bool], side: usize, [height, width]: [usize; 2]) -> Vec<bool> {
    let full: Vec<f32> = mask.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect();
    resize_plane(&full, [side, side], [height, width]).into_iter().map(|v| v > 0.999).collect()
}

/// Replaces the values of pixels outside a mask with the mean of their already-known
/// 8-neighbours, ring by ring outwards, so that resampling near the mask's edge mixes in only
/// extrapolated values, never whatever lies outside (an untrained network's border, say).
/// Pixels that no ring reaches (an empty mask) keep their values. The rings depend on the mask
/// alone, so they are worked out once and replayed on every plane.
#[derive(Clone, Debug)]
pub struct FillPlan {
    len: usize,
    /// In ring order: a pixel and the neighbours known before its ring.
    steps: Vec<(usize, Vec<usize>)>,
    /// Where each ring ends in `steps`.
    ring_ends: Vec<usize>,
}

impl FillPlan {
    pub fn new(mask: &[bool], [height, width]: [usize; 2]) -> Self {
        assert_eq!(mask.len(), height * width, "mask size");
        let mut known = mask.to_vec();
        let mut steps = Vec::new();
        let mut ring_ends = Vec::new();
        loop {
            let ring_start = steps.len();
            for y in 0..height {
                for x in 0..width {
                    let i = y * width + x;
                    if known[i] {
                        continue;
                    }
                    let mut from = Vec::new();
                    for ny in y.saturating_sub(1)..=(y + 1).min(height - 1) {
                        for nx in x.saturating_sub(1)..=(x + 1).min(width - 1) {
                            if known[ny * width + nx] {
                                from.push(ny * width + nx);
                            }
                        }
                    }
                    if !from.is_empty() {
                        steps.push((i, from));
                    }
                }
            }
            if steps.len() == ring_start {
                break;
            }
            ring_ends.push(steps.len());
            for (i, _) in &steps[ring_start..] {
                known[*i] = true;
            }
        }
        FillPlan { len: mask.len(), steps, ring_ends }
    }

    /// The number of pixels of the planes it fills.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The rings in order, each as (pixel, neighbours averaged) steps: a ring reads only pixels
    /// known before it, so its steps may run together (the ONNX export gathers a ring at once).
    pub fn rings(&self) -> impl Iterator<Item = &[(usize, Vec<usize>)]> {
        let starts = std::iter::once(0).chain(self.ring_ends.iter().copied());
        starts.zip(&self.ring_ends).map(|(a, &b)| &self.steps[a..b])
    }

    pub fn apply(&self, values: &mut [f32]) {
        assert_eq!(values.len(), self.len, "plane size");
        for (i, from) in &self.steps {
            values[*i] = from.iter().map(|&j| values[j]).sum::<f32>() / from.len() as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covered_mask_keeps_pixels_wholly_inside() {
        // A 4x4 mask false in its first column, halved: the triangle filter (two source pixels
        // wide each way) reaches column 0 from the left output column only.
        let mask: Vec<bool> = (0..16).map(|i| i % 4 >= 1).collect();
        assert_eq!(covered_mask(&mask, 4, [2, 2]), vec![false, true, false, true]);
    }

    #[test]
    fn fill_plan_extends_the_known_values_ring_by_ring() {
        // Known: the centre of a 5x5 grid (4.0); garbage elsewhere.
        let mut v = vec![100.0f32; 25];
        v[12] = 4.0;
        let mask: Vec<bool> = (0..25).map(|i| i == 12).collect();
        FillPlan::new(&mask, [5, 5]).apply(&mut v);
        assert!(v.iter().all(|&x| x == 4.0), "{v:?}");
        // Two known values: a pixel between them takes their mean; known pixels are untouched.
        let mut v = vec![9.0, -1.0, 3.0];
        FillPlan::new(&[true, false, true], [1, 3]).apply(&mut v);
        assert_eq!(v, vec![9.0, 6.0, 3.0]);
        // The rings partition the steps, and each reads only pixels known before it.
        let mask: Vec<bool> = (0..49).map(|i| i == 24 || i == 10).collect();
        let plan = FillPlan::new(&mask, [7, 7]);
        let mut known = mask.clone();
        let mut steps = 0;
        for ring in plan.rings() {
            assert!(!ring.is_empty());
            assert!(ring.iter().all(|(_, from)| from.iter().all(|&j| known[j])), "a ring reads its own ring");
            ring.iter().for_each(|(i, _)| known[*i] = true);
            steps += ring.len();
        }
        assert_eq!(steps, 47);
        assert!(known.iter().all(|&k| k));
        // Nothing known: nothing changes.
        let mut v = vec![1.0, 2.0];
        FillPlan::new(&[false, false], [1, 2]).apply(&mut v);
        assert_eq!(v, vec![1.0, 2.0]);
    }

    #[test]
    fn keeps_large_values_constants_and_averages() {
        // A constant plane of 7 mm stays 7 mm both ways (no clamping to 1).
        let c = vec![7.0f32; 57 * 57];
        for v in resize_plane(&c, [57, 57], [8, 8]).into_iter().chain(resize_plane(&c, [57, 57], [200, 200])) {
            assert!((v - 7.0).abs() < 1e-4, "{v}");
        }
        // Shrinking by an integer factor of a ramp keeps the mean.
        let ramp: Vec<f32> = (0..64 * 64).map(|i| (i % 64) as f32 * 0.1).collect();
        let small = resize_plane(&ramp, [64, 64], [16, 16]);
        let (a, b) = (ramp.iter().sum::<f32>() / ramp.len() as f32, small.iter().sum::<f32>() / small.len() as f32);
        assert!((a - b).abs() < 0.05, "{a} vs {b}");
        // Growing a linear ramp interpolates it linearly inside.
        let big = resize_plane(&[0.0, 2.0, 4.0, 6.0], [1, 4], [1, 8]);
        assert!((big[3] - 2.5).abs() < 1e-5 && (big[4] - 3.5).abs() < 1e-5, "{big:?}");
    }
}
