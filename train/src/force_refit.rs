//! The force head's linear map refitted in closed form when training ends: ridge regression of
//! the labelled force on the head's pooled features as the trained network computes them in
//! eval mode on frames read as `infer` reads them, its strength chosen on the validation
//! hold-out, kept only where it beats the trained map there. Adam leaves the map on its last
//! steps' noise and fitted to train-mode batch statistics (BENCHMARKS.md, "The force head").

use anyhow::{Context, Result};
use burn::data::dataloader::batcher::Batcher;
use burn::tensor::Device;
use model::DenseDepth;
use nalgebra::{DMatrix, DVector};

use crate::config::{FitConfig, OnBadData};
use crate::data::{DepthBatcher, DepthDataset, Jitter};

/// The jitters' stream, apart from the epochs' (`Jitter::draw(seed, epoch, index)`).
const REFIT_STREAM: u64 = 0x4e6f_7263_6552_6566;

/// Ridge strengths tried, relative to the features' mean variance: half decades, 1e-6 to 0.1.
/// The quickstart's three seeds chose 1e-3 to 1e-2, inside the range.
const ALPHAS: [f64; 11] = [1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1];

/// What the refit did.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceRefit {
    /// Training images with a force label the map was fitted on (each read as stored and in
    /// two jitters).
    pub train_images: usize,
    /// Validation images with a force label it was judged on (read as `infer` reads them, once).
    pub val_images: usize,
    /// The ridge strength chosen (relative to the features' mean variance).
    pub alpha: f64,
    /// Validation total force error (mean ||F'| - |F||, % of the mean |F|) of the trained map.
    pub trained_percent: f64,
    /// The same of the refitted map.
    pub refit_percent: f64,
    /// Whether the refitted map replaced the trained one (it did better on validation).
    pub kept: bool,
    /// Wall time of the refit: the features' passes and the solves.
    pub seconds: f64,
}

impl ForceRefit {
    /// One line for the run's log.
    pub fn line(&self) -> String {
        format!(
            "force head: linear map refitted on {} training images' features, each as stored and jittered (ridge \
             {:.0e}, {:.1} s); validation force error {:.2} % of the mean as trained, {:.2} % refitted: {}",
            self.train_images,
            self.alpha,
            self.seconds,
            self.trained_percent,
            self.refit_percent,
            if self.kept { "refitted map kept" } else { "trained map kept" }
        )
    }
}

/// Each training image is read as it is and in this many photometric jitters of training's
/// kind ([`Jitter`]: gain, offset, noise, after `infer`'s drift balance), labelled alike: a
/// map that leans on what a camera's drift moves fits them worse. The frames themselves are
/// read with that balance: a map fitted on frames as stored erred by 3.6 % of the mean force
/// through it on the quickstart's test frames, against 2.6 % without it.
const JITTERED_COPIES: u64 = 2;

/// A split's labelled images: the head's pooled features (a row for each reading of each) and
/// force (N).
struct Labelled {
    features: DMatrix<f64>,
    force_n: DMatrix<f64>,
}

/// `net` with its force head's linear map refitted on `train` (each frame read as `infer` reads
/// it and jittered from `config`'s seed) and judged on `val` (a hold-out, never the test split;
/// read as `infer` reads it), and what was done; `net` as it was, and `None`, where it has no force head or a split has no force label.
/// Bad samples stop it or are left out, as `config` says; its batch size is `config`'s. Says
/// what it did on standard error.
pub fn refit_force_head(
    net: DenseDepth,
    train: &DepthDataset,
    val: &DepthDataset,
    batcher: &DepthBatcher,
    device: &Device,
    config: &FitConfig,
) -> Result<(DenseDepth, Option<ForceRefit>)> {
    let started = std::time::Instant::now();
    let Some(head) = net.decoder.force.as_ref() else { return Ok((net, None)) };
    let hidden = head.hidden();
    let (weight, bias) = head.map();
    let unit = model::FORCE_N_PER_LOSS_UNIT as f64;
    let trained = (
        DMatrix::from_fn(hidden, 3, |j, k| weight[j * 3 + k] as f64 * unit),
        DVector::from_fn(3, |k, _| bias[k] as f64 * unit),
    );
    let fit_on = gather(&net, &train.read_as_infer()?, JITTERED_COPIES, batcher, device, config)?;
    let judge_on = gather(&net, &val.read_as_infer()?, 0, batcher, device, config)?;
    if fit_on.features.nrows() < 2 || judge_on.features.nrows() == 0 {
        return Ok((net, None));
    }
    let trained_percent = total_error_percent(&judge_on, &trained);
    let Some((alpha, refit, refit_percent)) = ALPHAS
        .iter()
        .filter_map(|&alpha| ridge(&fit_on, alpha).map(|map| (alpha, total_error_percent(&judge_on, &map), map)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(alpha, percent, map)| (alpha, map, percent))
    else {
        return Ok((net, None));
    };
    let kept = refit_percent < trained_percent;
    let outcome = ForceRefit {
        train_images: fit_on.features.nrows() / (JITTERED_COPIES as usize + 1),
        val_images: judge_on.features.nrows(),
        alpha,
        trained_percent,
        refit_percent,
        kept,
        seconds: started.elapsed().as_secs_f64(),
    };
    eprintln!("{}", outcome.line());
    if !kept {
        return Ok((net, Some(outcome)));
    }
    let (w, b) = refit;
    let weight: Vec<f32> =
        (0..hidden).flat_map(|j| (0..3).map(move |k| (j, k))).map(|(j, k)| (w[(j, k)] / unit) as f32).collect();
    let bias = std::array::from_fn(|k| (b[k] / unit) as f32);
    let mut net = net;
    net.decoder.force = net.decoder.force.map(|h| h.with_map(&weight, bias));
    Ok((net, Some(outcome)))
}

/// The head's pooled features and the force label of each of `data`'s images that has one,
/// read as stored and in `jittered` jitters.
fn gather(
    net: &DenseDepth,
    data: &DepthDataset,
    jittered: u64,
    batcher: &DepthBatcher,
    device: &Device,
    config: &FitConfig,
) -> Result<Labelled> {
    let (mut rows, mut forces, mut hidden) = (Vec::new(), Vec::new(), 0);
    let readings: Vec<(usize, u64)> = (0..=jittered).flat_map(|copy| (0..data.len()).map(move |i| (i, copy))).collect();
    for chunk in readings.chunks(config.batch.max(1)) {
        let mut items = Vec::with_capacity(chunk.len());
        for &(i, copy) in chunk {
            let jitter = (copy > 0).then(|| Jitter::draw(config.seed ^ REFIT_STREAM, copy, i as u64));
            match data.load(i, jitter) {
                Ok(item) if item.force.is_some() => items.push(item),
                Ok(_) => {}
                // Listed by the epochs' validation and steps already.
                Err(_) if config.on_bad_data == OnBadData::Skip => {}
                Err(e) => return Err(e).context("bad sample while refitting the force head"),
            }
        }
        if items.is_empty() {
            continue;
        }
        forces.extend(items.iter().filter_map(|i| i.force.as_ref().map(|(f, _)| f.map(f64::from))));
        let b = batcher.batch(items, device);
        let features = net.force_features(b.images).context("the network has no force head")?;
        hidden = features.dims()[1];
        rows.extend(features.into_data().convert::<f32>().try_into_vec::<f32>()?.into_iter().map(f64::from));
    }
    Ok(Labelled {
        features: DMatrix::from_row_slice(forces.len(), hidden, &rows),
        force_n: DMatrix::from_fn(forces.len(), 3, |n, k| forces[n][k]),
    })
}

/// The ridge map (weight `[hidden, 3]`, bias; N) of `data`'s force on its features, the bias
/// unpenalised (both centred first), the penalty `alpha` times the features' mean variance;
/// `None` where the features do not vary or the system will not factor.
fn ridge(data: &Labelled, alpha: f64) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let (x, y) = (&data.features, &data.force_n);
    let n = x.nrows() as f64;
    let mean_x = x.row_mean().transpose();
    let mean_y = y.row_mean().transpose();
    let xc = DMatrix::from_fn(x.nrows(), x.ncols(), |i, j| x[(i, j)] - mean_x[j]);
    let yc = DMatrix::from_fn(y.nrows(), 3, |i, k| y[(i, k)] - mean_y[k]);
    let gram = xc.transpose() * &xc;
    let variance = gram.trace() / (n * x.ncols() as f64);
    if !(variance.is_finite() && variance > 0.0) {
        return None;
    }
    let penalised = gram + DMatrix::identity(x.ncols(), x.ncols()) * (alpha * variance * n);
    let w = penalised.cholesky()?.solve(&(xc.transpose() * yc));
    let b = mean_y - w.transpose() * mean_x;
    w.iter().chain(b.iter()).all(|v| v.is_finite()).then_some((w, b))
}

/// Mean ||F'| - |F|| over `data`'s images as a percentage of their mean |F|, F' = x · w + b.
fn total_error_percent(data: &Labelled, (w, b): &(DMatrix<f64>, DVector<f64>)) -> f64 {
    let predicted = &data.features * w;
    let (mut error, mut mean) = (0.0, 0.0);
    for i in 0..predicted.nrows() {
        let p = (0..3).map(|k| (predicted[(i, k)] + b[k]).powi(2)).sum::<f64>().sqrt();
        let t = (0..3).map(|k| data.force_n[(i, k)].powi(2)).sum::<f64>().sqrt();
        error += (p - t).abs();
        mean += t;
    }
    if mean > 0.0 { 100.0 * error / mean } else { f64::INFINITY }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Force labels exactly `features · w + b`.
    fn labelled(features: DMatrix<f64>, w: &DMatrix<f64>, b: [f64; 3]) -> Labelled {
        let mut force_n = &features * w;
        for mut row in force_n.row_iter_mut() {
            for k in 0..3 {
                row[k] += b[k];
            }
        }
        Labelled { features, force_n }
    }

    /// Exact data: a weak ridge returns the map that made it, bias and all, whatever the
    /// features' scale (the penalty follows their variance).
    #[test]
    fn a_weak_ridge_recovers_an_exact_map() {
        let w = DMatrix::from_row_slice(4, 3, &[1.0, -2.0, 0.5, 0.0, 3.0, 1.0, -1.5, 0.25, 2.0, 0.75, 0.0, -1.0]);
        let x = DMatrix::from_fn(40, 4, |i, j| (((i * 7 + j * 13) % 17) as f64 - 8.0) / 3.0 + (i * j) as f64 * 0.01);
        for scale in [1e-3, 1.0, 1e3] {
            let data = labelled(&x * scale, &(&w / scale), [4.0, -1.0, 20.0]);
            let (fw, fb) = ridge(&data, 1e-9).unwrap();
            assert!((fw - &w / scale).abs().max() * scale < 1e-5, "scale {scale}");
            assert!((fb - DVector::from_row_slice(&[4.0, -1.0, 20.0])).abs().max() < 1e-5, "scale {scale}");
        }
    }

    /// One feature: the ridge slope is the closed form cov(x, y) / (var(x) (1 + alpha)), and a
    /// constant feature (no variance) gives no map.
    #[test]
    fn one_feature_gives_the_shrunk_slope_and_a_constant_one_none() {
        let x = DMatrix::from_column_slice(4, 1, &[0.0, 1.0, 2.0, 3.0]);
        let data = labelled(x, &DMatrix::from_row_slice(1, 3, &[2.0, 0.0, -1.0]), [1.0, 1.0, 1.0]);
        let (w, b) = ridge(&data, 0.5).unwrap();
        // var(x) = 1.25, cov(x, y) = 2.5 for the first column: slope 2.5 / (1.25 * 1.5).
        assert!((w[(0, 0)] - 2.5 / 1.875).abs() < 1e-12);
        assert!((b[0] - (4.0 - w[(0, 0)] * 1.5)).abs() < 1e-12, "the mean passes through the means");
        let flat = Labelled { features: DMatrix::from_element(4, 1, 2.0), force_n: data.force_n.clone() };
        assert!(ridge(&flat, 0.5).is_none());
    }

    /// The error of a map: | |F'| - |F| | against the labels' mean |F|, per image.
    #[test]
    fn the_total_error_is_the_magnitudes_difference() {
        let data = Labelled {
            features: DMatrix::from_column_slice(2, 1, &[1.0, 2.0]),
            force_n: DMatrix::from_row_slice(2, 3, &[0.0, 0.0, -10.0, 3.0, 4.0, 0.0]),
        };
        // F' = (0, 0, -12) and (0, 0, -11): errors 2 and 6, mean |F| 7.5.
        let map = (DMatrix::from_row_slice(1, 3, &[0.0, 0.0, 1.0]), DVector::from_row_slice(&[0.0, 0.0, -13.0]));
        assert!((total_error_percent(&data, &map) - 100.0 * 4.0 / 7.5).abs() < 1e-12);
    }
}
