//! The project's one quantile rule, for every figure it reports (evaluation violins, stream
//! latencies, benchmark medians): linear interpolation between the closest ranks, numpy's
//! default (R's type 7), so that a figure here is the one a Python user computes from the same
//! values.

/// The `q` quantile (0..=1) of values sorted ascending; NaN for none.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < sorted.len() { sorted[i] * (1.0 - f) + sorted[i + 1] * f } else { sorted[i] }
}

/// The values sorted ascending (NaN last), for several quantiles of one set.
pub fn sorted(values: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = values.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v
}

/// The median of `values` (the mean of the middle two for an even count); NaN for none.
pub fn median(values: impl IntoIterator<Item = f64>) -> f64 {
    quantile_sorted(&sorted(values), 0.5)
}

/// Summary statistics of a set of values (NaNs left out).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub n: usize,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub mean: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub sd: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub median: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub q1: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub q3: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub min: f64,
    #[serde(deserialize_with = "crate::training::nan_if_null")]
    pub max: f64,
}

impl Summary {
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let v = sorted(values.into_iter().filter(|x| x.is_finite()));
        let n = v.len();
        if n == 0 {
            return Summary {
                n,
                mean: f64::NAN,
                sd: f64::NAN,
                median: f64::NAN,
                q1: f64::NAN,
                q3: f64::NAN,
                min: f64::NAN,
                max: f64::NAN,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        // Sample standard deviation (n - 1), zero for one value.
        let sd = if n > 1 { (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt() } else { 0.0 };
        Summary {
            n,
            mean,
            sd,
            median: quantile_sorted(&v, 0.5),
            q1: quantile_sorted(&v, 0.25),
            q3: quantile_sorted(&v, 0.75),
            min: v[0],
            max: v[n - 1],
        }
    }

    /// A timing as the benchmarks print it: the median and the interquartile range, to 0.01
    /// (`1.23 [1.20, 1.31]`), so that small networks' times and their run-to-run spread show.
    pub fn median_and_quartiles(&self) -> String {
        format!("{:.2} [{:.2}, {:.2}]", self.median, self.q1, self.q3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_as_numpy_does() {
        // numpy.quantile([1, 2, 3, 4], [0, 0.25, 0.5, 0.9, 1]) = 1, 1.75, 2.5, 3.7, 4
        let v = [1.0, 2.0, 3.0, 4.0];
        for (q, want) in [(0.0, 1.0), (0.25, 1.75), (0.5, 2.5), (0.9, 3.7), (1.0, 4.0)] {
            assert!((quantile_sorted(&v, q) - want).abs() < 1e-12, "q {q}");
        }
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median([7.5]), 7.5);
        assert!(median([]).is_nan());
    }

    #[test]
    fn a_timing_prints_its_median_and_quartiles_to_a_hundredth() {
        let t = Summary::of([1.0, 1.234, 1.3, 2.0, 9.0]);
        assert_eq!(t.median_and_quartiles(), "1.30 [1.23, 2.00]");
    }
}
