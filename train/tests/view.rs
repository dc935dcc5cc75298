//! `train fit --view-save`: the recording, read back with Rerun's own decoder, holds the run's
//! step losses, its epochs' figures as metrics.csv has them, and the network's reading of the
//! held-out samples shown.

#![cfg(feature = "view")]

use std::path::Path;

use burn::data::dataloader::batcher::Batcher;
use train::{FitConfig, RunOptions, Start, fit_with};
use view::{entity, timeline};

use crate::common;
use common::tiny_dataset;

fn config(data: &Path) -> FitConfig {
    FitConfig { epochs: 2, batch: 2, lr: 3e-3, seed: 5, val_fraction: 0.0, ..FitConfig::new(data.into(), [64, 64]) }
}

#[test]
fn a_recorded_run_reads_back_as_its_metrics_and_its_network_say() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let device = model::backend::default_device();
    let (run, rrd) = (tmp.path().join("run"), tmp.path().join("run.rrd"));
    let config = config(&data);
    let start = Start { model_config: model::DenseDepthConfig::new(model::DenseNetConfig::tiny()), weights: None };
    let options = RunOptions { view: Some(view::Target::Save(rrd.clone())), ..RunOptions::on(&device) };
    let fitted = fit_with(&run, &config, start, &options).unwrap();
    assert!(!tmp.path().join("run.rrd.partial").exists());
    let rec = view::read_back(&rrd).unwrap();

    // Every step's loss, at its step; an epoch's mean is the epoch's training loss.
    let (train, val) = train::select(&config).unwrap();
    let steps_per_epoch = train.len().div_ceil(config.batch);
    let losses = rec.scalars(entity::TRAIN_LOSS, timeline::STEP);
    assert_eq!(
        losses.iter().map(|(s, _)| *s).collect::<Vec<_>>(),
        (1..=2 * steps_per_epoch as i64).collect::<Vec<_>>()
    );
    let history = &fitted.state.history;
    for (e, metrics) in history.iter().enumerate() {
        let epoch = &losses[e * steps_per_epoch..(e + 1) * steps_per_epoch];
        let mean = epoch.iter().map(|(_, l)| l).sum::<f64>() / steps_per_epoch as f64;
        assert!(
            (mean - metrics.train_loss).abs() <= 1e-12 * mean.abs(),
            "epoch {e}: {mean} against {}",
            metrics.train_loss
        );
    }
    // The epochs' figures as the run's metrics have them.
    let by_epoch = |name: &str| rec.scalars(name, timeline::EPOCH);
    let want = |f: fn(&train::EpochMetrics) -> f64| history.iter().map(|m| (m.epoch as i64, f(m))).collect::<Vec<_>>();
    assert_eq!(by_epoch(entity::VAL_L1_MM), want(|m| m.val_l1_mm));
    assert_eq!(by_epoch(entity::VAL_LOSS), want(|m| m.val_loss));
    assert_eq!(by_epoch(entity::EPOCH_LOSS), want(|m| m.train_loss));

    // The held-out samples: their images as their files, the truth as the dataset reads it, the
    // last epoch's prediction as the fitted network reads them, and the error between the two.
    let shown = val.len().min(3);
    assert!(shown > 0);
    // The layout came with the data: the series, then the held-out samples' panels.
    assert_eq!(rec.panels(), view::panels_by_name(&view::training_columns(shown)));
    let items: Vec<_> = (0..shown).map(|i| val.load(i, None).unwrap()).collect();
    let batch = train::data::DepthBatcher::for_data(&val).batch(items.clone(), &device);
    let [_, _, h, w] = batch.depths.dims();
    let pred =
        val.scale.tensor_to_mm(fitted.net.forward_heads(batch.images).depth).into_data().try_to_vec::<f32>().unwrap();
    for (k, item) in items.iter().enumerate() {
        let shown = |what: &str| rec.depth_images(&entity::held_out(k, what), timeline::EPOCH);
        let (truth, prediction, error) = (shown("truth"), shown("prediction"), shown("error"));
        assert_eq!(truth.len(), history.len());
        let ([sw, sh], last) = &prediction.last().unwrap().1;
        assert_eq!([*sw as usize, *sh as usize], [w, h]);
        let mask = &item.mask;
        for (px, &m) in mask.iter().enumerate() {
            let t = val.scale.to_mm(item.depth[px]) * m;
            let p = pred[k * h * w + px] * m;
            assert!((truth.last().unwrap().1.1[px] - t).abs() <= 1e-5, "sample {k} pixel {px}: truth");
            assert!((last[px] - p).abs() <= 1e-4, "sample {k} pixel {px}: prediction {} against {p}", last[px]);
            let e = error.last().unwrap().1.1[px];
            assert!(
                (e - (last[px] - truth.last().unwrap().1.1[px]).abs()).abs() <= 1e-5,
                "sample {k} pixel {px}: error"
            );
        }
        let input = rec.colour_images(&entity::held_out(k, "input"), timeline::EPOCH);
        let image = val.camera_image(k).unwrap();
        assert_eq!(input.len(), history.len());
        assert_eq!(input[0].1.1, image.into_raw());
    }
}
