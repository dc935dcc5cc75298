//! Training end to end on a tiny simulated dataset: learning, export, kill -9 and resume,
//! non-finite steps and bad samples.

use std::path::{Path, PathBuf};
use std::process::Command;

use burn::tensor::{Distribution, Tensor};
use train::{FitConfig, OnBadData, RunOptions, Start, fit, fit_with};

use crate::common;
use crate::kill;
use common::{tiny_dataset, unit_dataset};

const BIN: &str = env!("CARGO_BIN_EXE_train");

fn config(data: &Path, epochs: usize) -> FitConfig {
    FitConfig {
        epochs,
        batch: 2,
        lr: 3e-3,
        seed: 5,
        checkpoint_every: 3,
        max_bad_steps: 3,
        val_fraction: 0.0,
        ..FitConfig::new(data.into(), [64, 64])
    }
}

fn tiny_start() -> Start {
    Start { model_config: model::DenseDepthConfig::new(model::DenseNetConfig::tiny()), weights: None }
}

fn fit_args(data: &Path, out: &Path) -> Vec<String> {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    ["fit", "--data", &s(data), "--out", &s(out), "--recipe", "paper", "--preset", "tiny", "--input", "64x64"]
        .iter()
        .chain(&["--epochs", "3"])
        .map(|a| a.to_string())
        .chain(["--batch", "2", "--lr", "3e-3", "--seed", "5", "--checkpoint-every", "2"].map(String::from))
        .collect()
}

fn export(run: &Path, out: &Path) {
    let r = Command::new(BIN)
        .args(["export", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

fn predictions(bundle: &Path) -> Vec<f32> {
    let device = model::backend::default_device();
    let (net, _) = model::bundle::load_bundle(bundle, &device).unwrap();
    // The same input for every call: a fixed pattern rather than random numbers.
    let values: Vec<f32> = (0..2 * 3 * 64 * 64).map(|i| ((i * 7919) % 1000) as f32 / 1000.0).collect();
    let x = Tensor::<4>::from_data(burn::tensor::TensorData::new(values, [2, 3, 64, 64]), &device);
    net.forward(x).into_data().try_to_vec::<f32>().unwrap()
}

/// `train fit --dry-run`'s settings and network for the data folder `data`, as JSON.
fn dry_run(data: &Path, extra: &[&str]) -> serde_json::Value {
    let r = Command::new(BIN)
        .current_dir(data.parent().unwrap())
        .args(["fit", "--data", data.file_name().unwrap().to_str().unwrap(), "--out", "r", "--dry-run"])
        .args(extra)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    serde_json::from_slice(&r.stdout).unwrap()
}

#[test]
fn the_cli_trains_the_quickstarts_recipe_unless_told_otherwise() {
    fn json(v: &impl serde::Serialize) -> serde_json::Value {
        serde_json::to_value(v).unwrap()
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("d");
    std::fs::create_dir(&d).unwrap();
    // The data folder given relative to the working directory is recorded absolute.
    let absolute = std::fs::canonicalize(&d).unwrap();
    for (flags, recipe) in [(&[][..], train::Recipe::Quickstart), (&["--recipe", "paper"][..], train::Recipe::Paper)] {
        let printed = dry_run(&d, flags);
        assert_eq!(printed["fit"], json(&recipe.fit_config(absolute.clone())), "{recipe:?}");
        assert_eq!(printed["model"], json(&recipe.model_config().unwrap()), "{recipe:?}");
    }
    // A flag given wins over the recipe's value; the rest stay the recipe's.
    let printed = dry_run(&d, &["--epochs", "3", "--half-resolution", "--channels", "rgb"]);
    let quickstart = train::Recipe::Quickstart.fit_config(absolute.clone());
    assert_eq!(printed["fit"]["epochs"], 3);
    assert_eq!(printed["fit"]["lr"], quickstart.lr);
    assert_eq!(printed["model"]["full_resolution"], false);
    assert_eq!(printed["model"]["input"], json(&model::InputChannels::Rgb));
    // The same folder twice, or a flood of loader threads, is refused before any work.
    for (flags, words) in [
        (&["--more-data", "../d"][..], "already among the data"),
        (&["--loader-workers", "100000"][..], "--loader-workers"),
    ] {
        let r = Command::new(BIN)
            .current_dir(&d)
            .args(["fit", "--data", ".", "--out", "r", "--dry-run"])
            .args(flags)
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && e.contains(words) && !e.contains("panicked"), "{flags:?}: {e}");
    }
}

#[test]
fn a_tiny_dataset_trains_and_its_bundle_predicts_the_same() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    // Targets keep depths above 1 mm (a float image resize would clamp them there).
    let set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
    let deepest =
        (0..set.len()).max_by(|&a, &b| set.record(a).stats.max_depth_mm.total_cmp(&set.record(b).stats.max_depth_mm));
    let deepest = deepest.unwrap();
    assert!(set.record(deepest).stats.max_depth_mm > 2.0);
    let item = set.load(deepest, None).unwrap();
    let max_mm = item.depth.iter().map(|&v| set.scale.to_mm(v)).fold(0.0f32, f32::max);
    assert!(max_mm > 1.5, "targets are cut at {max_mm} mm");
    let device = model::backend::default_device();
    let run = tmp.path().join("run");
    let fitted = fit(&run, &config(&data, 2), tiny_start(), &device, false).unwrap();
    let h = &fitted.state.history;
    assert_eq!(h.len(), 2);
    assert!(h.iter().all(|m| m.train_loss.is_finite() && m.val_l1_mm.is_finite()));
    assert!(h[1].val_loss < h[0].val_loss, "validation loss must drop: {h:?}");
    assert!(run.join("metrics.csv").is_file() && run.join("metrics.json").is_file());

    let bundle = tmp.path().join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[]).unwrap();
    assert!(bundle.join("reference.png").is_file(), "the unit's reference image travels with the bundle");
    let (loaded, file) = model::bundle::load_bundle(&bundle, &device).unwrap();
    assert_eq!([file.input_height_px, file.input_width_px], [64, 64]);
    let x = Tensor::<4>::random([1, 3, 64, 64], Distribution::Uniform(0.0, 1.0), &device);
    let a = fitted.net.forward(x.clone()).into_data().try_to_vec::<f32>().unwrap();
    let b = loaded.forward(x).into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(a, b, "the exported bundle predicts exactly what the trained network does");
}

/// The tiny network reading RGB and its difference to the reference, output at full resolution.
fn difference_full_resolution() -> model::DenseDepthConfig {
    model::DenseDepthConfig::new(model::DenseNetConfig::tiny())
        .with_input(model::InputChannels::RgbDifference)
        .with_full_resolution(true)
}

#[test]
fn a_reference_difference_full_resolution_network_trains_and_exports() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let model_config = difference_full_resolution();
    // Items carry six channels and full-size targets; the reference frame's differences are 0.
    let mut set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
    set.set_model(&model_config).unwrap();
    let item = set.load(0, None).unwrap();
    assert_eq!((item.image.len(), item.depth.len(), set.mask().len()), (6 * 64 * 64, 64 * 64, 64 * 64));
    let device = model::backend::default_device();
    let run = tmp.path().join("run");
    let config = FitConfig { contact_weight: 2.0, ..config(&data, 2) };
    let fitted =
        fit(&run, &config, Start { model_config: model_config.clone(), weights: None }, &device, false).unwrap();
    let h = &fitted.state.history;
    assert!(h[1].val_loss < h[0].val_loss, "validation loss must drop: {h:?}");
    let bundle = tmp.path().join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[]).unwrap();
    let (loaded, file) = model::bundle::load_bundle(&bundle, &device).unwrap();
    assert_eq!(file.model, model_config);
    // The bundle reads crops as training did: the gain fitted to the unit's contact frames.
    assert_eq!(file.encoding().unwrap(), set.encoding());
    assert_eq!(set.encoding().channels, model::InputChannels::RgbDifference);
    let x = Tensor::<4>::random([1, 6, 64, 64], Distribution::Uniform(0.0, 1.0), &device);
    let out = loaded.forward(x);
    assert_eq!(out.dims(), [1, 1, 64, 64]);

    // Without the unit's reference frame there is no such run, and the message says why.
    std::fs::remove_file(data.join("unit/reference.png")).unwrap();
    let e =
        fit(&tmp.path().join("run2"), &config, Start { model_config, weights: None }, &device, false).err().unwrap();
    assert!(format!("{e:#}").contains("reference.png"), "{e:#}");
}

/// Samples kept decoded between epochs give the items decoding them again gives, jitter and
/// all, and the kept bytes never pass the budget.
#[test]
fn decoded_samples_kept_between_epochs_give_the_same_items() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let model_config = difference_full_resolution();
    let open = |budget: Option<usize>| {
        let mut set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
        set.set_model(&model_config).unwrap();
        if let Some(b) = budget {
            set.keep_decoded(b);
        }
        set
    };
    let fresh = open(None);
    let all = open(Some(1 << 30));
    // One sample's bytes: a 64x64 RGB crop and a 64x64 depth map.
    let one = 64 * 64 * 3 + 64 * 64 * 4;
    let some = open(Some(2 * one + one / 2));
    for epoch in 0..3u64 {
        for i in 0..fresh.len() {
            let jitter = (epoch > 0).then(|| train::data::Jitter::draw(5, epoch, i as u64));
            let want = fresh.load(i, jitter).unwrap();
            for (name, set) in [("all", &all), ("some", &some)] {
                let got = set.load(i, jitter).unwrap();
                assert_eq!((&got.image, &got.depth), (&want.image, &want.depth), "{name}: epoch {epoch}, sample {i}");
            }
        }
    }
    assert_eq!(fresh.decoded_bytes(), 0);
    assert_eq!(all.decoded_bytes(), fresh.len() * one);
    assert_eq!(some.decoded_bytes(), 2 * one);
    // Other samples, other indices: what was kept goes.
    let mut fewer = all.clone();
    fewer.keep(&[3, 1]);
    assert_eq!(fewer.decoded_bytes(), 0);
    assert_eq!(fewer.load(0, None).unwrap().depth, fresh.load(3, None).unwrap().depth);
}

#[test]
fn a_run_killed_at_any_moment_resumes_to_the_same_weights() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    // Kill anywhere, edit nothing, resume = uninterrupted: four kills -9 at seeded moments
    // (before the first checkpoint too, where --resume starts afresh), each run resumed.
    let span = kill::timed_run(BIN, &fit_args(&data, &a));
    let resume = |run: &Path| [fit_args(&data, run), vec!["--resume".to_string()]].concat();
    let kills = kill::kill_anywhere(BIN, &fit_args(&data, &b), &resume(&b), 4, span, 3);
    assert!(kills.mid_run >= 1, "no kill landed mid-run: {kills:?}");
    let r = Command::new(BIN).args(fit_args(&data, &b)).output().unwrap();
    assert!(!r.status.success(), "a second run into the same folder without --resume is refused");
    assert!(String::from_utf8_lossy(&r.stderr).contains("--resume"));
    let (ba, bb) = (tmp.path().join("bundle-a"), tmp.path().join("bundle-b"));
    export(&a, &ba);
    export(&b, &bb);
    assert_eq!(predictions(&ba), predictions(&bb), "resumed and uninterrupted runs end with the same weights");
    let metrics = |run: &PathBuf| std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let strip = |s: String| s.lines().map(|l| l.rsplit_once(',').unwrap().0.to_string()).collect::<Vec<_>>();
    assert_eq!(strip(metrics(&a)), strip(metrics(&b)), "same losses, epoch by epoch");
}

#[test]
fn unknown_unbuilt_or_repeated_devices_and_unbuilt_views_are_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let refusal = |extra: &[&str]| {
        let r = Command::new(BIN).args(fit_args(&tmp.path().join("no-data"), &out)).args(extra).output().unwrap();
        assert!(!r.status.success(), "{extra:?} must be refused");
        String::from_utf8_lossy(&r.stderr).into_owned()
    };
    assert!(refusal(&["--devices", "flex,cpu"]).contains("twice"));
    assert!(refusal(&["--device", "tpu"]).contains("\"tpu\""));
    // Without the cuda feature the message says how to build it; with it and no GPU, which
    // device cannot start.
    let cuda = refusal(&["--devices", "cuda:0,cuda:1"]);
    assert!(cuda.contains("--features model/cuda") || cuda.contains("cannot start"), "{cuda}");
    // A live view in a build without one says how to build it.
    #[cfg(not(feature = "view"))]
    assert!(refusal(&["--view-save", "run.rrd"]).contains("--features view"));
    assert!(!out.exists(), "nothing is written for a refused device");
}

#[test]
fn non_finite_steps_are_skipped_and_bad_samples_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let device = model::backend::default_device();

    let nan = RunOptions { inject_nan_step: Some(4), ..RunOptions::on(&device) };
    let fitted = fit_with(&tmp.path().join("nan"), &config(&data, 1), tiny_start(), &nan).unwrap();
    assert_eq!(fitted.state.skipped_steps, 1);
    assert!(fitted.state.history[0].train_loss.is_finite());

    let stop = FitConfig { max_bad_steps: 1, ..config(&data, 1) };
    let run = tmp.path().join("stop");
    let nan = RunOptions { inject_nan_step: Some(2), ..RunOptions::on(&device) };
    let e = fit_with(&run, &stop, tiny_start(), &nan).err().unwrap().to_string();
    assert!(e.contains("non-finite") && e.contains("checkpoint"), "{e}");

    // A corrupt image: named, and the run stops or skips it as asked.
    let manifest = formats::dataset::Manifest::load(&data).unwrap();
    let victim = manifest.samples.iter().find(|s| s.split == dataset::Split::Train).unwrap();
    let image = data.join(victim.image.as_ref().unwrap());
    std::fs::write(&image, b"\x89PNG\r\n\x1a\n garbage").unwrap();
    let e = fit(&tmp.path().join("bad"), &config(&data, 1), tiny_start(), &device, false).err().unwrap();
    let e = format!("{e:#}");
    assert!(e.contains(image.file_name().unwrap().to_str().unwrap()) && e.contains("skip"), "{e}");
    let skip = FitConfig { on_bad_data: OnBadData::Skip, ..config(&data, 1) };
    let fitted = fit(&tmp.path().join("skip"), &skip, tiny_start(), &device, false).unwrap();
    assert_eq!(fitted.state.bad_samples.len(), 1);
    assert!(fitted.state.bad_samples[0].contains(image.file_name().unwrap().to_str().unwrap()));

    // An image of the wrong size.
    image::RgbImage::from_fn(100, 100, |x, y| image::Rgb([x as u8, y as u8, 90])).save(&image).unwrap();
    let e = fit(&tmp.path().join("size"), &config(&data, 1), tiny_start(), &device, false).err().unwrap();
    assert!(format!("{e:#}").contains("image is 100x100"), "{e:#}");
    // A depth map beyond the sensor's range (with a good image back in place).
    let other = manifest.samples.iter().find(|s| s.id != victim.id).unwrap();
    std::fs::copy(data.join(other.image.as_ref().unwrap()), &image).unwrap();
    let mut deep = sensor::DepthMap::zeros(570);
    deep.depth_mm[1000] = 20.0;
    let depth_path = data.join(&victim.depth);
    std::fs::write(&depth_path, deep.to_png_um()).unwrap();
    let e = fit(&tmp.path().join("deep"), &config(&data, 1), tiny_start(), &device, false).err().unwrap();
    let e = format!("{e:#}");
    assert!(e.contains("outside") && e.contains(depth_path.file_name().unwrap().to_str().unwrap()), "{e}");
}

#[test]
fn finetuning_with_a_frozen_encoder_changes_only_the_decoder() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let device = model::backend::default_device();
    let fitted = fit(&tmp.path().join("base"), &config(&data, 1), tiny_start(), &device, false).unwrap();
    let base = tmp.path().join("base-bundle");
    train::export::export_net(&fitted.net, &fitted.state, &base, &[]).unwrap();

    let (run, tuned) = (tmp.path().join("tune"), tmp.path().join("tuned-bundle"));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let tune_args = |run: &Path, tuned: &Path| {
        let (base, data, run, tuned) = (s(&base), s(&data), s(run), s(tuned));
        let args = ["finetune", "--from", &base, "--data", &data, "--out", &run, "--bundle", &tuned, "--epochs", "1"];
        kill::strings(&[&args[..], &["--batch", "2", "--lr", "1e-2", "--freeze-encoder"]].concat())
    };
    let span = kill::timed_run(BIN, &tune_args(&run, &tuned));
    let (a, _) = model::bundle::load_bundle(&base, &device).unwrap();
    let (b, _) = model::bundle::load_bundle(&tuned, &device).unwrap();
    let v = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(v(a.encoder.conv0.weight.val()), v(b.encoder.conv0.weight.val()), "a frozen encoder keeps its weights");
    // ... and its batch norms' running statistics: at the stem, in every dense layer, at the end.
    let v1 = |t: burn::tensor::Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
    let norms = |net: &model::DenseDepth| -> Vec<Vec<f32>> {
        let e = &net.encoder;
        let mut all: Vec<&burn::nn::BatchNorm> = vec![e.norm0.as_ref().unwrap(), &e.norm5];
        for block in [&e.denseblock1, &e.denseblock2, &e.denseblock3, &e.denseblock4] {
            all.extend(block.layers.iter().map(|l| &l.norm1));
        }
        all.iter().flat_map(|n| [v1(n.running_mean.value()), v1(n.running_var.value())]).collect()
    };
    assert_eq!(norms(&a), norms(&b), "a frozen encoder keeps its batch norms' running statistics");
    assert_ne!(v(a.decoder.conv3.weight.val()), v(b.decoder.conv3.weight.val()), "the decoder learns");

    // Kill anywhere, edit nothing, resume = uninterrupted, for a fine-tuning too (its bundle is
    // written after the run): three kills -9, each run resumed.
    let (run2, tuned2) = (tmp.path().join("tune2"), tmp.path().join("tuned2"));
    let resume = [tune_args(&run2, &tuned2), vec!["--resume".to_string()]].concat();
    let kills = kill::kill_anywhere(BIN, &tune_args(&run2, &tuned2), &resume, 3, span, 5);
    assert!(kills.mid_run >= 1, "no kill landed mid-run: {kills:?}");
    assert_eq!(
        predictions(&tuned),
        predictions(&tuned2),
        "a fine-tuning killed {kills:?} ends as an uninterrupted one"
    );
}

#[test]
#[ignore = "needs ../shared"]
fn a_pytorch_state_dict_becomes_a_bundle() {
    let fixtures = sensor::shared::shared_dir("DENSETACT_FIXTURES", "fixtures");
    let tmp = tempfile::tempdir().unwrap();
    let sensor_json = tmp.path().join("sensor.json");
    formats::write_json(&sensor_json, &sensor::Sensor::default()).unwrap();
    let out = tmp.path().join("bundle");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let r = Command::new(BIN)
        .args(["import", "--pth", &s(&fixtures.join("densedepth_tiny.pth")), "--sensor", &s(&sensor_json)])
        .args(["--input", "64x96", "--out", &s(&out)])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let device = model::backend::default_device();
    let (net, file) = model::bundle::load_bundle(&out, &device).unwrap();
    assert_eq!((file.input_height_px, file.input_width_px), (64, 96));
    let direct = model::import::load_pytorch(&fixtures.join("densedepth_tiny.pth"), &device).unwrap().model;
    let x = Tensor::<4>::random([1, 3, 64, 96], Distribution::Uniform(0.0, 1.0), &device);
    let v = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(v(net.forward(x.clone())), v(direct.forward(x)));

    let r = Command::new(BIN)
        .args(["import", "--pth", &s(&tmp.path().join("missing.pth")), "--sensor", &s(&sensor_json), "--out", &s(&out)])
        .output()
        .unwrap();
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("missing.pth"));
}

/// Training reads datasets through `formats`, without the generator's dependencies.
#[test]
fn train_does_not_link_the_generator() {
    let r = Command::new(env!("CARGO"))
        .args(["tree", "-p", "train", "-e", "normal", "--prefix", "none", "--offline"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let tree = String::from_utf8_lossy(&r.stdout);
    assert!(tree.contains("formats v"), "the tree lists formats: {tree}");
    for banned in ["obvhs ", "tobj ", "imageproc ", "dataset "] {
        assert!(!tree.lines().any(|l| l.starts_with(banned)), "train must not depend on {banned}");
    }
}

/// Several units at once: each sample is read with its own unit's reference frame and mask
/// (units differ in both), exactly as that unit's folder alone reads it; a base model trains on
/// them and its bundle describes the first; a folder of another sensor radius is refused.
#[test]
fn several_units_train_together_each_read_with_its_own_unit() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    unit_dataset(&a, 3, 8);
    unit_dataset(&b, 9, 8);
    let model_config = difference_full_resolution();
    let open = |dirs: &[PathBuf]| {
        let mut set = train::data::DepthDataset::open_all(dirs, None, [64, 64]).unwrap();
        set.set_model(&model_config).unwrap();
        set
    };
    let both = open(&[a.clone(), b.clone()]);
    let (only_a, only_b) = (open(std::slice::from_ref(&a)), open(std::slice::from_ref(&b)));
    assert_eq!(both.len(), only_a.len() + only_b.len());
    let (from_a, from_b) = (both.load(0, None).unwrap(), both.load(only_a.len(), None).unwrap());
    let (alone_a, alone_b) = (only_a.load(0, None).unwrap(), only_b.load(0, None).unwrap());
    assert_eq!((&from_a.image, &from_a.depth, &from_a.mask), (&alone_a.image, &alone_a.depth, &alone_a.mask));
    assert_eq!((&from_b.image, &from_b.depth, &from_b.mask), (&alone_b.image, &alone_b.depth, &alone_b.mask));
    assert_ne!(from_a.mask, from_b.mask, "two units' useful disks differ");
    // A batch of both carries each item's own mask.
    let batcher = train::data::DepthBatcher::for_data(&both);
    let device = model::backend::default_device();
    let batch =
        burn::data::dataloader::batcher::Batcher::batch(&batcher, vec![from_a.clone(), from_b.clone()], &device);
    let masks = batch.masks.into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(masks, [from_a.mask.as_slice(), from_b.mask.as_slice()].concat());

    let config = FitConfig { more_data: vec![b.clone()], val_fraction: 0.25, ..config(&a, 1) };
    let run = tmp.path().join("run");
    let fitted =
        fit(&run, &config, Start { model_config: model_config.clone(), weights: None }, &device, false).unwrap();
    assert!(fitted.state.history[0].train_loss.is_finite());
    let bundle = tmp.path().join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[]).unwrap();
    let file = model::bundle::BundleFile::read(&bundle).unwrap();
    assert_eq!(file.sensor, only_a.sensor, "the bundle describes --data's unit");

    let c = tmp.path().join("c");
    common::generated(&c, 4, 4, 30.0, 0.25);
    let e = train::data::DepthDataset::open_all(&[a.clone(), c.clone()], None, [64, 64]).err().unwrap().to_string();
    assert!(e.contains("manifest.json") && e.contains("radius"), "{e}");
}

/// A varied look (a base model's variation between units) changes the frame and the unit's
/// reference alike, so the difference channels see another unit's rendering of the same dent;
/// a dataset that does not vary looks ignores it; the draws stay within their documented spread.
#[test]
fn a_varied_look_changes_frame_and_reference_alike() {
    use train::data::{Jitter, Look};
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    unit_dataset(&a, 3, 4);
    let mut set = train::data::DepthDataset::open(&a, None, [64, 64]).unwrap();
    set.set_model(
        &model::DenseDepthConfig::new(model::DenseNetConfig::tiny()).with_input(model::InputChannels::RgbDifference),
    )
    .unwrap();
    let look = Look { gain_rgb: [1.2, 0.9, 1.05], exponent: 1.3 };
    let jitter = Jitter { gain: 1.0, offset: 0.0, noise_sd: 0.0, seed: 1, look };
    let plain = set.load(1, None).unwrap().image;
    assert_eq!(set.load(1, Some(jitter)).unwrap().image, plain, "the look is ignored unless the dataset varies it");

    set.vary_look = true;
    let looked = set.load(1, Some(jitter)).unwrap().image;
    let per = 64 * 64;
    let (rgb, difference) = plain.split_at(3 * per);
    let mut want_rgb = rgb.to_vec();
    look.apply(&mut want_rgb);
    let gain = set.encoding().difference_gain;
    let mut reference: Vec<f32> = rgb.iter().zip(difference).map(|(v, d)| v - d / gain).collect();
    look.apply(&mut reference);
    for (k, &got) in looked.iter().enumerate() {
        let want = if k < 3 * per { want_rgb[k] } else { gain * (want_rgb[k - 3 * per] - reference[k - 3 * per]) };
        assert!((got - want).abs() < 1e-4, "value {k}: {got} against {want}");
    }
    assert!(looked.iter().zip(&plain).filter(|(a, b)| a != b).count() > per, "the look changed the frame");

    let draws: Vec<Look> = (0..500).map(|i| Jitter::draw(7, 0, i).look).collect();
    let gains: Vec<f32> = draws.iter().flat_map(|l| l.gain_rgb).collect();
    let exponents: Vec<f32> = draws.iter().map(|l| l.exponent).collect();
    let within = |v: &[f32], ratio: f64| {
        let (lo, hi) = (v.iter().cloned().fold(f32::MAX, f32::min), v.iter().cloned().fold(f32::MIN, f32::max));
        let r = ratio as f32;
        assert!(lo >= 1.0 / r - 1e-6 && hi <= r + 1e-6, "{lo}..{hi} outside 1/{r}..{r}");
        assert!(lo < 1.0 / r.powf(0.8) && hi > r.powf(0.8), "{lo}..{hi} does not fill 1/{r}..{r}");
    };
    within(&gains, Look::GAIN_RATIO);
    within(&exponents, Look::EXPONENT_RATIO);
}

/// A dataset rendered under random looks: each item's difference channels are taken against
/// its own sample's untouched frame (noise where nothing presses), not the unit's; the contact
/// gate is fitted against the same frames when the bundle is made.
#[test]
fn samples_under_random_looks_are_read_against_their_own_untouched_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("looks");
    let kit = dataset::Kit::procedural(25.0);
    let params = formats::dataset::GeneratorParams {
        test_fraction: 0.25,
        lifted_fraction: 0.5,
        random_looks: true,
        ..formats::dataset::GeneratorParams::new(2, 12, &kit.source)
    };
    dataset::generate::generate_with_unit(&data, &kit, 3, 25.0, params).unwrap();
    let model_config = difference_full_resolution();
    let mut set = train::data::DepthDataset::open(&data, None, [64, 64]).unwrap();
    set.set_model(&model_config).unwrap();
    let unit_reference = sensor::frame::read(&data.join("unit/reference.png")).unwrap();
    let against_unit = model::InputEncoder::new(set.encoding(), [64, 64], Some(&unit_reference)).unwrap();
    let per = 64 * 64;
    let mean_abs = |v: &[f32]| v.iter().map(|x| x.abs() as f64).sum::<f64>() / v.len() as f64;
    let mut lifted = 0;
    for i in 0..set.len() {
        let record = set.record(i).clone();
        if record.stats.contact_fraction > 0.0 {
            continue;
        }
        lifted += 1;
        let item = set.load(i, None).unwrap();
        let own = mean_abs(&item.image[3 * per..]);
        let frame = sensor::frame::read(&data.join(record.image.as_ref().unwrap())).unwrap();
        let unit = mean_abs(&against_unit.encode(&frame)[3 * per..]);
        assert!(own < 0.05 && unit > 3.0 * own, "sample {}: {own} against its own frame, {unit} the unit's", record.id);
    }
    assert!(lifted >= 3, "{lifted} lifted samples");
    // Trains, exports, and the gate is fitted against each sample's own untouched frame: it
    // misses no contact frame of the train split, and sees its untouched frames as such.
    let device = model::backend::default_device();
    let config = FitConfig { val_fraction: 0.25, ..config(&data, 1) };
    let fitted = fit(&tmp.path().join("run"), &config, Start { model_config, weights: None }, &device, false).unwrap();
    let bundle = tmp.path().join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[]).unwrap();
    let gate = model::bundle::BundleFile::read(&bundle).unwrap().contact_gate.expect("a fitted gate");
    assert!(gate.train.contact > 0 && gate.train.untouched > 0 && gate.train.misses == 0, "{gate:?}");
}

/// A finished one-epoch run in `dir` on 8 samples of unit 3: the data folder, the run folder
/// and its settings.
fn finished_run(dir: &Path) -> (PathBuf, PathBuf, FitConfig) {
    let data = dir.join("data");
    unit_dataset(&data, 3, 8);
    let (run, cfg) = (dir.join("run"), FitConfig { val_fraction: 0.25, ..config(&data, 1) });
    fit(&run, &cfg, tiny_start(), &model::backend::default_device(), false).unwrap();
    (data, run, cfg)
}

/// A resumed run checks its data: a dataset whose manifest changed since the run began (a
/// sample relabelled, removed or added) is refused, naming the file.
#[test]
fn a_resume_on_changed_data_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run, cfg) = finished_run(tmp.path());
    let device = model::backend::default_device();
    // Unchanged data resumes (here: a finished run, returned as it is).
    fit(&run, &cfg, tiny_start(), &device, true).unwrap();
    let mut manifest = formats::dataset::Manifest::load(&data).unwrap();
    manifest.samples.pop();
    formats::write_json(&data.join("manifest.json"), &manifest).unwrap();
    let e = fit(&run, &cfg, tiny_start(), &device, true).err().expect("a resume on changed data");
    let e = format!("{e:#}");
    assert!(e.contains("manifest.json") && e.contains("changed since this run began"), "{e}");
}

/// `train export` of a run that a `fit` still holds (its lock) is refused, not exported at
/// whatever step the run last saved; once the run is free, it exports.
#[test]
fn a_run_still_training_is_not_exported() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, run, _) = finished_run(tmp.path());
    let device = model::backend::default_device();
    let held = formats::output::claim_dir(&run, formats::output::OutputKind::Run, &[]).unwrap();
    let out = tmp.path().join("bundle");
    let e = train::export::export_run(&run, &out, &device, model::bundle::SafetensorsKeys::Burn).unwrap_err();
    let e = format!("{e:#}");
    assert!(e.contains("another process") && !out.exists(), "{e}");
    drop(held);
    train::export::export_run(&run, &out, &device, model::bundle::SafetensorsKeys::Burn).unwrap();
}

/// Two gels that differ only in how strongly contact shades them: each frame's change from the
/// reference `q` in one and `2 q` in the other (both built from one generated unit, on a
/// reference compressed to 96..159 so that neither clips). The stronger one's difference gain
/// comes out half as large, and the network reads both units' contact at the same scale.
#[test]
fn a_gel_that_changes_more_under_contact_gets_a_smaller_gain_and_reads_the_same() {
    let tmp = tempfile::tempdir().unwrap();
    let source = tmp.path().join("source");
    unit_dataset(&source, 3, 16);
    let reference = sensor::frame::read(&source.join("unit/reference.png")).unwrap();
    let compressed = |r: u8| 96 + r as i32 / 4;
    let gel = |dir: &Path, strength: i32| {
        copy_dir(&source, dir);
        let base = image::RgbImage::from_fn(reference.width(), reference.height(), |x, y| {
            image::Rgb(reference.get_pixel(x, y).0.map(|r| compressed(r) as u8))
        });
        base.save(dir.join("unit/reference.png")).unwrap();
        let mut manifest = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
        for record in formats::dataset::Manifest::load(&source).unwrap().samples {
            let rel = record.image.unwrap();
            let frame = sensor::frame::read(&source.join(&rel)).unwrap();
            let shaded = image::RgbImage::from_fn(frame.width(), frame.height(), |x, y| {
                let (f, r) = (frame.get_pixel(x, y).0, reference.get_pixel(x, y).0);
                image::Rgb(std::array::from_fn(|c| {
                    let q = (f[c] as i32 - r[c] as i32) / 2;
                    (compressed(r[c]) + strength * q).clamp(0, 255) as u8
                }))
            });
            // Lossless, whatever the unit streams.
            let png = Path::new(&rel).with_extension("png").to_string_lossy().into_owned();
            shaded.save(dir.join(&png)).unwrap();
            manifest = manifest.replace(&format!("\"{rel}\""), &format!("\"{png}\""));
        }
        std::fs::write(dir.join("manifest.json"), manifest).unwrap();
        let mut set = train::data::DepthDataset::open(dir, None, [64, 64]).unwrap();
        set.set_model(&difference_full_resolution()).unwrap();
        set
    };
    let (weak, strong) = (gel(&tmp.path().join("weak"), 1), gel(&tmp.path().join("strong"), 2));
    let (gw, gs) = (weak.encoding().difference_gain, strong.encoding().difference_gain);
    assert!((gw / gs - 2.0).abs() < 0.1, "gains {gw} and {gs}: the stronger gel's should be half");
    // The difference channels where contact is labelled: the same size in both (elsewhere the
    // resized frames' rounding, times each unit's gain, is all there is).
    let per = 64 * 64;
    let size = |set: &train::data::DepthDataset| -> f64 {
        let touched = set.scale.to_net(sensor::CONTACT_THRESHOLD_MM);
        let mut sum = 0.0;
        for i in 0..set.len() {
            let item = set.load(i, None).unwrap();
            for k in (0..per).filter(|&k| item.depth[k] > touched) {
                sum += (0..3).map(|c| item.image[(3 + c) * per + k].abs() as f64).sum::<f64>();
            }
        }
        sum
    };
    let (dw, ds) = (size(&weak), size(&strong));
    assert!((ds / dw - 1.0).abs() < 0.05, "difference channels {dw} against {ds}");
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}
