//! What the contact model's grid cannot resolve: where the indenter's own detail stands deeper
//! than the solved surface between two nodes (a tooth's tip, a sharp rim), the membrane must
//! still lie on it, and beyond it the surface cannot step back to the coarse solution. That
//! excess is spread as the membrane would bridge it: every sample takes the largest of its
//! neighbours' excess, each attenuated by `exp(-distance / spacing)` with the solve's node
//! spacing as the length (the scale below which the solution says nothing), and its own. The
//! saw-tooth shot's drape is the same spread of the indenter's depth itself.

use std::borrow::Cow;

/// Below this (mm) an excess is invisible in the shading and is cut, so that the work stays
/// bounded: 5 um spread over a few pixels tilts the normal by well under a tenth of a degree,
/// less than a grey level.
pub(super) const EXCESS_FLOOR_MM: f32 = 5e-3;

/// The spread of an excess: every sample takes the largest of its neighbours' values, each
/// attenuated by `exp(-distance / decay)`, and its own. Distances are chamfer distances (steps of
/// 1 and sqrt 2 over the grid), so two raster passes compute it exactly for that metric.
#[derive(Clone, Copy, Debug)]
pub(super) struct Spread {
    /// Attenuation over one grid step and over one diagonal step.
    straight: f32,
    diagonal: f32,
    pub(super) decay_steps: f32,
}

impl Spread {
    /// `None` for a decay of zero (nothing spreads).
    pub(super) fn new(decay_mm: f64, mm_per_step: f64) -> Option<Self> {
        let decay_steps = (decay_mm / mm_per_step) as f32;
        (decay_steps.is_finite() && decay_steps > 1e-3).then(|| Spread {
            straight: (-1.0 / decay_steps).exp(),
            diagonal: (-std::f32::consts::SQRT_2 / decay_steps).exp(),
            decay_steps,
        })
    }

    /// `excess_mm` (zero but where the indenter stands deeper) spread over a `width`-wide grid.
    ///
    /// Each pass takes a row's neighbours in the row before (above, and the two diagonals) in
    /// one vectorised step, then runs along the row for the neighbour before it in the row: only
    /// that scan is serial.
    pub(super) fn apply<'a>(&self, depth_mm: &'a [f32], width: usize) -> Cow<'a, [f32]> {
        let height = depth_mm.len() / width;
        let Some(bbox) = BoundingBox::of_positive(depth_mm, width) else {
            return Cow::Borrowed(depth_mm);
        };
        let deepest = depth_mm.iter().fold(0f32, |m, &d| m.max(d));
        let reach = (self.decay_steps * (deepest / EXCESS_FLOOR_MM).ln().max(0.0)).ceil() as usize;
        let b = bbox.grown(reach, width, height);
        let (bw, bh) = (b.x1 - b.x0, b.y1 - b.y0);
        // The box alone, row by row, with a zero column on either side for the diagonals.
        let stride = bw + 2;
        let mut grid = vec![0f32; stride * bh];
        for y in 0..bh {
            let src = &depth_mm[(b.y0 + y) * width + b.x0..][..bw];
            grid[y * stride + 1..][..bw].copy_from_slice(src);
        }
        self.pass(&mut grid, stride, 0..bh, |y| y.checked_sub(1));
        // Backwards: rows from the bottom, each row scanned from the right (reversed in place).
        for row in grid.chunks_exact_mut(stride) {
            row.reverse();
        }
        self.pass(&mut grid, stride, (0..bh).rev(), |y| (y + 1 < bh).then_some(y + 1));
        for row in grid.chunks_exact_mut(stride) {
            row.reverse();
        }
        let mut out = depth_mm.to_vec();
        for y in 0..bh {
            let dst = &mut out[(b.y0 + y) * width + b.x0..][..bw];
            for (o, &g) in dst.iter_mut().zip(&grid[y * stride + 1..][..bw]) {
                // A sample keeps its own excess; elsewhere a spread under the floor is cut.
                *o = if *o > 0.0 || g >= EXCESS_FLOOR_MM { o.max(g) } else { 0.0 };
            }
        }
        Cow::Owned(out)
    }

    /// One raster pass over `grid` (rows of `stride` with a zero border column each side) in
    /// the row order `rows`; `previous(y)` is the row already done before row `y`.
    fn pass(
        &self,
        grid: &mut [f32],
        stride: usize,
        rows: impl Iterator<Item = usize>,
        previous: impl Fn(usize) -> Option<usize>,
    ) {
        let (a, d) = (self.straight, self.diagonal);
        let mut from = vec![0f32; stride];
        for y in rows {
            if let Some(p) = previous(y) {
                from.copy_from_slice(&grid[p * stride..][..stride]);
                let row = &mut grid[y * stride..][..stride];
                for x in 1..stride - 1 {
                    let v = (from[x] * a).max(from[x - 1] * d).max(from[x + 1] * d);
                    row[x] = row[x].max(v);
                }
            }
            let row = &mut grid[y * stride..][..stride];
            let mut carry = 0f32;
            for v in &mut row[1..stride - 1] {
                // Runs far from any contact stay zero without the serial multiply.
                if carry < EXCESS_FLOOR_MM && *v == 0.0 {
                    carry = 0.0;
                    continue;
                }
                carry = v.max(carry * a);
                *v = carry;
            }
        }
    }
}

/// A half-open rectangle of grid samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct BoundingBox {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl BoundingBox {
    /// The smallest box holding every sample of `depth` (rows of `width`) above zero; `None` if
    /// none is.
    fn of_positive(depth: &[f32], width: usize) -> Option<Self> {
        let mut b: Option<BoundingBox> = None;
        for (y, row) in depth.chunks_exact(width).enumerate() {
            let Some(first) = row.iter().position(|&d| d > 0.0) else {
                continue;
            };
            let last = row.iter().rposition(|&d| d > 0.0).unwrap_or(first);
            let bb = b.get_or_insert(BoundingBox { x0: first, y0: y, x1: last + 1, y1: y + 1 });
            bb.x0 = bb.x0.min(first);
            bb.x1 = bb.x1.max(last + 1);
            bb.y1 = y + 1;
        }
        b
    }

    fn grown(self, by: usize, width: usize, height: usize) -> Self {
        BoundingBox {
            x0: self.x0.saturating_sub(by),
            y0: self.y0.saturating_sub(by),
            x1: (self.x1 + by).min(width),
            y1: (self.y1 + by).min(height),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plateau's spread falls off as exp(-distance / decay) along a row and never touches the
    /// plateau itself; far away nothing changes.
    #[test]
    fn spread_decays_exponentially_beyond_an_edge() {
        let (w, h) = (80, 40);
        let mut depth = vec![0f32; w * h];
        for y in 10..30 {
            for x in 10..30 {
                depth[y * w + x] = 2.0;
            }
        }
        let spread = Spread::new(3.0, 1.0).unwrap();
        let out = spread.apply(&depth, w);
        for y in 10..30 {
            for x in 10..30 {
                assert_eq!(out[y * w + x], 2.0);
            }
        }
        for k in 1..10 {
            let got = out[20 * w + 29 + k];
            let want = 2.0 * (-(k as f32) / 3.0).exp();
            assert!((got - want).abs() < 1e-5 * want.max(1.0), "{k} steps out: {got} vs {want}");
        }
        // Beyond the floor's reach the depth is exactly zero again.
        assert_eq!(out[20 * w + 79], 0.0);
        assert!(out.iter().zip(&depth).all(|(o, d)| o >= d), "the spread never lifts the membrane off the indenter");
        // No contact: nothing to do, and the input is handed back as it was.
        assert!(matches!(spread.apply(&vec![0.0; w * h], w), Cow::Borrowed(_)));
        assert!(Spread::new(0.0, 0.1).is_none());
    }
}
