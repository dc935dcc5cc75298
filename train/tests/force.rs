//! Training the pressure output beside depth (`--force-weight`): it learns, its bundle says it
//! has it, a depth-only network gains it, and data without pressure maps is refused. The bundle
//! records the elastomer fitted to the labels.

use std::path::Path;

use train::{FitConfig, Start, fit};

use crate::common;
use common::tiny_dataset;

fn config(data: &Path, epochs: usize, force_weight: f64) -> FitConfig {
    FitConfig {
        epochs,
        batch: 2,
        lr: 3e-3,
        seed: 5,
        val_fraction: 0.0,
        net_range: model::UNIT_NET_RANGE,
        force_weight,
        ..FitConfig::new(data.into(), [64, 64])
    }
}

fn tiny() -> model::DenseDepthConfig {
    model::DenseDepthConfig::new(model::DenseNetConfig::tiny())
}

#[test]
fn the_pressure_output_trains_beside_depth_and_travels_in_the_bundle() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let device = model::backend::default_device();

    // Items carry the pressure maps at the output's size, in network units.
    let mut set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
    set.set_model(&tiny().with_pressure(true)).unwrap();
    let busiest = (0..set.len()).max_by(|&a, &b| {
        let force = |i: usize| set.record(i).wrench.unwrap().force_magnitude_n();
        force(a).total_cmp(&force(b))
    });
    let item = set.load(busiest.unwrap(), None).unwrap();
    let pressure = item.pressure.expect("the item's pressure map");
    assert_eq!(pressure.len(), 32 * 32);
    let peak_kpa = pressure.iter().fold(0f32, |m, &p| m.max(p)) * model::PRESSURE_KPA_PER_UNIT;
    assert!(peak_kpa > 1.0, "peak {peak_kpa} kPa");

    // The untrained network's validation figures against the trained one's.
    let (train_set, val) = train::select(&config(&data, 1, 1.0)).unwrap();
    let mut val = val;
    val.set_model(&tiny().with_pressure(true)).unwrap();
    let batcher = train::data::DepthBatcher::for_data(&val);
    device.seed(5);
    let untrained = tiny().with_pressure(true).init(&device);
    let on = |net: &model::DenseDepth| {
        train::validate(net, &val, &batcher, 2, &device, train::OnBadData::Stop, "test").unwrap()
    };
    let before = on(&untrained).pressure_l1_kpa.expect("pressure figures");
    drop(train_set);
    // The zero predictor's: the mean pressure over the useful pixels, image by image.
    let zeros = (0..val.len())
        .map(|i| {
            let item = val.load(i, None).unwrap();
            let p = item.pressure.unwrap();
            let useful = item.mask.iter().sum::<f32>();
            (p.iter().zip(item.mask.iter()).map(|(v, m)| v * m).sum::<f32>() / useful * model::PRESSURE_KPA_PER_UNIT)
                as f64
        })
        .sum::<f64>()
        / val.len() as f64;

    let run = tmp.path().join("run");
    let fitted = fit(&run, &config(&data, 3, 1.0), Start { model_config: tiny(), weights: None }, &device, false);
    let fitted = fitted.unwrap();
    assert!(fitted.net.has_pressure() && fitted.state.model.pressure, "a force weight gives the pressure output");
    assert!(fitted.net.has_force_head(), "and the force head");
    assert_eq!(fitted.state.model.force_head, Some(model::ForceHead::DEFAULT_HIDDEN));
    assert_eq!(fitted.force_refit, None, "validated on the test split: no refit chosen on it");
    let h = &fitted.state.history;
    let evaluation = on(&fitted.net);
    let after = evaluation.pressure_l1_kpa.unwrap();
    // The head's figures: over the images with a force label, against their mean |F|;
    // ||F'| - |F|| never exceeds |F' - F|.
    let head = evaluation.head_force.expect("the force head's figures");
    let labelled: Vec<f64> =
        (0..val.len()).filter_map(|i| val.record(i).force_label().map(|w| w.force_magnitude_n())).collect();
    assert_eq!(head.images, labelled.len());
    let mean = labelled.iter().sum::<f64>() / labelled.len() as f64;
    assert!((head.mean_n - mean).abs() <= 1e-4 * mean, "{head:?} against a mean of {mean} N");
    assert!(head.total_n.is_finite() && head.total_n <= head.vector_n + 1e-9, "{head:?}");
    assert!(on(&untrained).head_force.is_none(), "no head, no head figures");
    assert_eq!(h.last().unwrap().val_pressure_l1_kpa, Some(after));
    eprintln!("pressure L1: untrained {before} kPa, trained {after} kPa, zeros {zeros} kPa");
    // Three epochs of the tiny network lower the training loss, whose force terms dominate at
    // the start; its validation figures are no measure yet at this budget (eval-mode batch
    // norms of a few steps; answering zeros does better: the quickstart measures the trained
    // figures).
    assert!(h.last().unwrap().train_loss < h[0].train_loss, "{h:?}");
    assert!(before.is_finite() && after.is_finite() && zeros > 0.0);
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    assert!(csv.lines().next().unwrap().ends_with("val_pressure_l1_kpa,seconds"), "{csv}");

    let bundle = tmp.path().join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[]).unwrap();
    let (loaded, file) = model::bundle::load_bundle(&bundle, &device).unwrap();
    assert!(file.model.pressure && loaded.has_pressure() && loaded.has_force_head());
    // The bundle also records the unit's elastomer, fitted to the labels: the generator's own
    // material (unit 3), whose E* the labels were solved with.
    let e = file.elastomer.expect("an elastomer fitted to the force labels");
    let truth = dataset::SensorUnit::from_seed(3, 25.0).elastomer.material().effective_modulus_mpa();
    assert!((e.effective_modulus_mpa / truth - 1.0).abs() <= 0.01, "{e:?} against E* {truth} MPa");
    assert!(e.quartiles_mpa[0] <= e.effective_modulus_mpa && e.effective_modulus_mpa <= e.quartiles_mpa[1]);
    assert!(e.samples > 0 && e.measured == 0, "{e:?}");

    // A depth-only network given as the start gains a fresh pressure output and trains it.
    let depth_only = tiny().init(&device);
    let start = Start { model_config: tiny(), weights: Some(depth_only.clone()) };
    let tuned = fit(&tmp.path().join("tune"), &config(&data, 1, 1.0), start, &device, false).unwrap();
    assert!(tuned.net.has_pressure() && tuned.state.model.pressure && tuned.net.has_force_head());
    assert!(tuned.state.history[0].val_pressure_l1_kpa.is_some());
}

/// With a validation hold-out the head's linear map is refitted in closed form when training
/// ends: both figures it reports are the networks' own on that hold-out read as `infer` reads
/// it (the best epoch's as trained, the returned one's), and the refitted map is kept only
/// where it does better there.
#[test]
fn the_force_heads_map_is_refitted_on_the_hold_out_and_reports_the_networks_figures() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let device = model::backend::default_device();
    let config = FitConfig { val_fraction: 0.25, ..config(&data, 2, 1.0) };
    let run = tmp.path().join("run");
    let fitted = fit(&run, &config, Start { model_config: tiny(), weights: None }, &device, false).unwrap();
    let refit = fitted.force_refit.clone().expect("a refit judged on the hold-out");

    let (train_set, mut val) = train::select(&config).unwrap();
    val.set_model(&fitted.state.model).unwrap();
    // Judged on the hold-out read as `infer` reads it.
    let val = val.read_as_infer().unwrap();
    let labelled =
        |set: &train::data::DepthDataset| (0..set.len()).filter(|&i| set.record(i).force_label().is_some()).count();
    assert_eq!((refit.train_images, refit.val_images), (labelled(&train_set), labelled(&val)));
    let batcher = train::data::DepthBatcher::for_data(&val);
    let percent = |net: &model::DenseDepth| {
        let e = train::validate(net, &val, &batcher, 2, &device, train::OnBadData::Stop, "validation").unwrap();
        e.head_force.expect("the head's figures").total_percent()
    };
    let best = train::checkpoint::best(&run).expect("the best epoch");
    let trained = train::checkpoint::restore_model(&best, &fitted.state.model, &device).unwrap();
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * b.max(1.0);
    assert!(close(percent(&trained), refit.trained_percent), "{refit:?}");
    let returned = percent(&fitted.net);
    assert!(close(returned, if refit.kept { refit.refit_percent } else { refit.trained_percent }), "{refit:?}");
    assert_eq!(refit.kept, refit.refit_percent < refit.trained_percent, "{refit:?}");
    let map = |net: &model::DenseDepth| net.decoder.force.as_ref().unwrap().map();
    assert_eq!(map(&trained) != map(&fitted.net), refit.kept, "the map changes exactly when the refit is kept");
    assert!(refit.line().contains("force head") && (1e-6..=0.1).contains(&refit.alpha), "{}", refit.line());
    // `train export` of the run writes the network `fit` returned, refitted alike.
    let bundle = tmp.path().join("bundle");
    train::export::export_run(&run, &bundle, &device, model::bundle::SafetensorsKeys::Burn).unwrap();
    let (exported, _) = model::bundle::load_bundle(&bundle, &device).unwrap();
    assert_eq!(map(&exported), map(&fitted.net));
}

/// The refit reads frames as `infer` does (`DepthDataset::read_as_infer`): a frame whose camera
/// drifted (a gain per channel) reads, balanced, as the undrifted frame does; as stored it
/// does not.
#[test]
fn a_drifted_frame_read_balanced_reads_as_the_undrifted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let open = |as_infer: bool| {
        let set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
        if as_infer { set.read_as_infer().unwrap() } else { set }
    };
    let i = 1;
    let (stored, balanced) = (open(false).load(i, None).unwrap().image, open(true).load(i, None).unwrap().image);
    let frame = open(false).camera_image(i).unwrap();
    let path = data.join(open(false).record(i).image.as_ref().unwrap());
    let gain = [1.08f32, 0.93, 1.05];
    let mut drifted = frame.clone();
    for p in drifted.pixels_mut() {
        for (v, g) in p.0.iter_mut().zip(gain) {
            *v = (*v as f32 * g).round().clamp(0.0, 255.0) as u8;
        }
    }
    drifted.save(&path).unwrap();
    let worst = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
    let mean = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(p, q)| (p - q).abs()).sum::<f32>() / a.len() as f32;
    let as_stored = open(false).load(i, None).unwrap().image;
    let read_balanced = open(true).load(i, None).unwrap().image;
    assert!(mean(&as_stored, &stored) > 0.02, "the drift shows as stored: {}", mean(&as_stored, &stored));
    // Undone to the balance's bins and the levels' rounding (about a level in 255), bar the
    // levels the gain clipped at 255.
    let (m, w) = (mean(&read_balanced, &balanced), worst(&read_balanced, &balanced));
    assert!(m < 0.004 && w < 0.06, "balanced: mean {m}, worst {w}");
}

#[test]
fn a_force_weight_on_data_without_pressure_maps_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let kit = dataset::Kit::procedural(25.0);
    let params = formats::dataset::GeneratorParams {
        test_fraction: 0.25,
        force_labels: false,
        ..formats::dataset::GeneratorParams::new(2, 8, &kit.source)
    };
    dataset::generate::generate_with_unit(&data, &kit, 3, 25.0, params).unwrap();
    let device = model::backend::default_device();
    let config = |epochs, weight| FitConfig { val_fraction: 0.25, ..config(&data, epochs, weight) };
    let e =
        fit(&tmp.path().join("run"), &config(1, 1.0), Start { model_config: tiny(), weights: None }, &device, false)
            .err()
            .expect("refused");
    let e = format!("{e:#}");
    assert!(e.contains("manifest.json") && e.contains("pressure map") && e.contains("--force-weight"), "{e}");
    // Nor is an elastomer fitted: there is nothing to fit it to.
    assert_eq!(train::elastomer::fit_elastomer(&data, false).unwrap(), None);
    // Without the force weight the same data trains depth alone.
    let fitted =
        fit(&tmp.path().join("run2"), &config(1, 0.0), Start { model_config: tiny(), weights: None }, &device, false);
    assert!(!fitted.unwrap().net.has_pressure());
}
