//! One-dimensional Gaussian-process regression: RBF kernel plus noise, hyper-parameters by
//! maximising the log marginal likelihood.
//!
//! Inputs and targets are normalised first (inputs to [0, 1], targets to unit spread about a
//! fitted line through the origin), so the same hyper-parameter search serves pixels and
//! millimetres. The line is the prior mean: beyond the last data point the prediction follows
//! it instead of falling back to zero. A growing jitter keeps the Cholesky factorisation alive
//! for duplicate inputs.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};

/// RBF + noise hyper-parameters, in normalised units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hyper {
    pub signal_sd: f64,
    pub length: f64,
    pub noise_sd: f64,
}

/// A fitted Gaussian process `y(x)`.
#[derive(Clone, Debug)]
pub struct Gp {
    x_scale: f64,
    slope: f64,
    y_scale: f64,
    xs: Vec<f64>,
    alpha: DVector<f64>,
    chol: Cholesky<f64, Dyn>,
    pub hyper: Hyper,
    /// Log marginal likelihood of the normalised data at `hyper`.
    pub log_likelihood: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GpError {
    #[error("a Gaussian process needs at least 3 points, got {0}")]
    TooFew(usize),
    #[error("input {0} is not a finite number")]
    NotFinite(usize),
    #[error("all inputs are equal")]
    Degenerate,
    #[error("the kernel matrix stays singular even with jitter")]
    Singular,
}

fn kernel(h: &Hyper, a: f64, b: f64) -> f64 {
    let d = (a - b) / h.length;
    h.signal_sd * h.signal_sd * (-0.5 * d * d).exp()
}

/// Cholesky factor of `K + noise^2 I + diag(extra)`, adding jitter (relative to the diagonal)
/// until it works.
fn factor(xs: &[f64], extra: &[f64], h: &Hyper) -> Option<Cholesky<f64, Dyn>> {
    let n = xs.len();
    let base = DMatrix::from_fn(n, n, |i, j| kernel(h, xs[i], xs[j]));
    let diag = h.signal_sd * h.signal_sd + h.noise_sd * h.noise_sd;
    let mut jitter = 0.0;
    for _ in 0..8 {
        let mut k = base.clone();
        for i in 0..n {
            k[(i, i)] += h.noise_sd * h.noise_sd + extra[i] + jitter;
        }
        if let Some(c) = Cholesky::new(k) {
            return Some(c);
        }
        jitter = if jitter == 0.0 { diag * 1e-10 } else { jitter * 100.0 };
    }
    None
}

/// Log marginal likelihood of `ys` under `h`, with the factor and `alpha = K^-1 y`.
fn evidence(
    xs: &[f64],
    extra: &[f64],
    ys: &DVector<f64>,
    h: &Hyper,
) -> Option<(f64, Cholesky<f64, Dyn>, DVector<f64>)> {
    let chol = factor(xs, extra, h)?;
    let alpha = chol.solve(ys);
    let log_det: f64 = chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>() * 2.0;
    let n = xs.len() as f64;
    let ll = -0.5 * ys.dot(&alpha) - 0.5 * log_det - 0.5 * n * (2.0 * std::f64::consts::PI).ln();
    ll.is_finite().then_some((ll, chol, alpha))
}

impl Gp {
    /// Fits a GP to `(x, y)` pairs, choosing hyper-parameters by maximum marginal likelihood
    /// (a coarse grid, then coordinate refinement in log space). `min_noise` bounds the noise
    /// from below, in the targets' units.
    pub fn fit(x: &[f64], y: &[f64], min_noise: f64) -> Result<Gp, GpError> {
        Gp::fit_with_noise(x, y, &vec![0.0; x.len()], min_noise)
    }

    /// [`Gp::fit`] with a known noise standard deviation of each point on top of the fitted
    /// common one (in the targets' units): a point measured less precisely pulls less.
    pub fn fit_with_noise(x: &[f64], y: &[f64], point_sd: &[f64], min_noise: f64) -> Result<Gp, GpError> {
        if x.len() < 3 || x.len() != y.len() || point_sd.len() != x.len() {
            return Err(GpError::TooFew(x.len().min(y.len())));
        }
        if let Some(i) = x.iter().zip(y).position(|(a, b)| !a.is_finite() || !b.is_finite()) {
            return Err(GpError::NotFinite(i));
        }
        let x_scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if !(x_scale > 0.0) || x.iter().all(|&v| v == x[0]) {
            return Err(GpError::Degenerate);
        }
        let xs: Vec<f64> = x.iter().map(|v| v / x_scale).collect();
        // Prior mean: the least-squares line through the origin.
        let slope = xs.iter().zip(y).map(|(a, b)| a * b).sum::<f64>() / xs.iter().map(|a| a * a).sum::<f64>();
        let resid: Vec<f64> = xs.iter().zip(y).map(|(a, b)| b - slope * a).collect();
        let spread = (resid.iter().map(|r| r * r).sum::<f64>() / resid.len() as f64).sqrt();
        let y_scale = if spread > 1e-12 * slope.abs().max(1e-300) { spread } else { 1.0 };
        let ys = DVector::from_iterator(resid.len(), resid.iter().map(|r| r / y_scale));
        let noise_floor = (min_noise / y_scale).max(1e-6);
        let extra: Vec<f64> = point_sd.iter().map(|sd| (sd / y_scale).powi(2)).collect();

        let score = |h: &Hyper| evidence(&xs, &extra, &ys, h).map_or(f64::NEG_INFINITY, |e| e.0);
        let mut best = Hyper { signal_sd: 1.0, length: 0.3, noise_sd: noise_floor.max(0.1) };
        let mut best_ll = score(&best);
        for &s in &[0.3, 1.0, 3.0, 10.0] {
            for &l in &[0.05, 0.1, 0.2, 0.4, 0.8, 1.6] {
                for &n in &[1e-3f64, 1e-2, 0.05, 0.2, 0.5] {
                    let h = Hyper { signal_sd: s, length: l, noise_sd: n.max(noise_floor) };
                    let ll = score(&h);
                    if ll > best_ll {
                        (best, best_ll) = (h, ll);
                    }
                }
            }
        }
        let mut step = 0.5f64;
        while step > 1e-3 {
            let mut improved = false;
            for dim in 0..3 {
                for dir in [-1.0, 1.0] {
                    let mut h = best;
                    let f = (step * dir).exp();
                    match dim {
                        0 => h.signal_sd *= f,
                        1 => h.length = (h.length * f).clamp(0.01, 10.0),
                        _ => h.noise_sd = (h.noise_sd * f).max(noise_floor),
                    }
                    let ll = score(&h);
                    if ll > best_ll + 1e-9 {
                        (best, best_ll, improved) = (h, ll, true);
                    }
                }
            }
            if !improved {
                step /= 2.0;
            }
        }
        let (log_likelihood, chol, alpha) = evidence(&xs, &extra, &ys, &best).ok_or(GpError::Singular)?;
        Ok(Gp { x_scale, slope, y_scale, xs, alpha, chol, hyper: best, log_likelihood })
    }

    /// Posterior mean and standard deviation (of the function, without noise) at `x`.
    pub fn predict(&self, x: f64) -> (f64, f64) {
        let xn = x / self.x_scale;
        let k = DVector::from_iterator(self.xs.len(), self.xs.iter().map(|&xi| kernel(&self.hyper, xn, xi)));
        let mean = self.slope * xn + self.y_scale * k.dot(&self.alpha);
        let v = self.chol.l_dirty().solve_lower_triangular(&k).unwrap_or_else(|| k.clone());
        let var = (self.hyper.signal_sd.powi(2) - v.dot(&v)).max(0.0);
        (mean, self.y_scale * var.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_smooth_curve() {
        let f = |x: f64| 0.0055 * x + 2e-8 * x * x * x;
        let xs: Vec<f64> = (0..30).map(|i| i as f64 * 10.0).collect();
        let ys: Vec<f64> = xs.iter().map(|&x| f(x)).collect();
        let gp = Gp::fit(&xs, &ys, 1e-6).unwrap();
        for i in 0..290 {
            let x = i as f64 + 0.5;
            let (m, sd) = gp.predict(x);
            assert!((m - f(x)).abs() < 1e-4, "x {x}: {m} vs {}", f(x));
            assert!(sd.is_finite());
        }
    }

    #[test]
    fn duplicates_bad_scaling_and_extrapolation_stay_finite() {
        // Every input twice, with different targets, in badly scaled units.
        let xs: Vec<f64> = (0..20).flat_map(|i| [i as f64 * 1e6, i as f64 * 1e6]).collect();
        let ys: Vec<f64> =
            xs.iter().enumerate().map(|(i, &x)| x * 1e-9 + if i % 2 == 0 { 1e-6 } else { -1e-6 }).collect();
        let gp = Gp::fit(&xs, &ys, 0.0).unwrap();
        for x in [0.0, 5.5e6, 19e6, 40e6, 1e9] {
            let (m, sd) = gp.predict(x);
            assert!(m.is_finite() && sd.is_finite(), "x {x}: {m} +- {sd}");
        }
        // Far beyond the data the prediction follows the prior line, not zero.
        let (far, sd_far) = gp.predict(40e6);
        assert!((far - 40e6 * 1e-9).abs() < 2e-3, "{far}");
        let (_, sd_in) = gp.predict(10e6);
        assert!(sd_far > sd_in, "uncertainty grows beyond the data: {sd_far} vs {sd_in}");
        // Exactly duplicated points (same target) need the jitter.
        let gp = Gp::fit(&[1.0, 1.0, 1.0, 2.0, 2.0, 3.0], &[1.0, 1.0, 1.0, 2.0, 2.0, 3.0], 0.0).unwrap();
        assert!((gp.predict(2.5).0 - 2.5).abs() < 1e-3);
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert_eq!(Gp::fit(&[1.0, 2.0], &[1.0, 2.0], 0.0).unwrap_err(), GpError::TooFew(2));
        assert_eq!(Gp::fit(&[1.0, f64::NAN, 3.0], &[1.0, 2.0, 3.0], 0.0).unwrap_err(), GpError::NotFinite(1));
        assert_eq!(Gp::fit(&[2.0, 2.0, 2.0], &[1.0, 2.0, 3.0], 0.0).unwrap_err(), GpError::Degenerate);
    }
}
