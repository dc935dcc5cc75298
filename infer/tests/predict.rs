//! Prediction from a bundle: the contact gate, shapes and masks, bad frames, the CLI's files, and
//! the crate's dependencies.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{bundle, bundle_file, dataset_of, dataset_with, pressed};

use dataset::{Renderer, SensorUnit};
use infer::Predictor;
use model::bundle::{BundleFile, write_bundle};
use model::{DenseDepthConfig, DenseNetConfig};

/// `infer eval` of `bundle` on `data`'s `split` into `out`.
fn eval(bundle: &Path, data: &Path, split: &str, out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["eval", "--bundle", bundle.to_str().unwrap(), "--data", data.to_str().unwrap()])
        .args(["--split", split, "--out", out.to_str().unwrap()])
        .output()
        .unwrap()
}

#[test]
fn frames_without_contact_skip_the_network_and_others_run_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle(&dir);
    let device = model::backend::default_device();
    let p = Predictor::load(&dir, &device).unwrap();
    assert!(p.reference.is_some());

    // A noisy frame of the untouched sensor: no contact, zeros.
    let zeros = vec![0.0; renderer.grid().len()];
    let quiet = renderer.render(&zeros, Some(4));
    assert!(!p.has_contact(&quiet));
    let d = p.predict(&quiet).unwrap();
    assert!(d.depth_mm.iter().all(|&v| v == 0.0));

    let (_, frame) = pressed(&renderer);
    assert!(p.has_contact(&frame));
    let d = p.predict(&frame).unwrap();
    assert_eq!(d.size_px, 570);
    let max = p.file.sensor.max_depth_mm as f32;
    for (v, &m) in d.depth_mm.iter().zip(&p.mask) {
        assert!(v.is_finite() && (0.0..=max).contains(v));
        if !m {
            assert_eq!(*v, 0.0, "outside the useful disk depth is zero");
        }
    }
    // Batched prediction equals one frame at a time.
    let batch = p.predict_network(&[frame.clone(), quiet.clone()]).unwrap();
    assert_eq!(batch[0], p.predict_network(std::slice::from_ref(&frame)).unwrap()[0]);
    assert_eq!(batch[0], d);

    let small = image::RgbImage::new(100, 80);
    let e = p.predict(&small).unwrap_err().to_string();
    assert!(e.contains("100x80") && e.contains("570x570"), "{e}");
}

#[test]
fn the_tare_zeroes_the_reference_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    bundle(&dir);
    let mut p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    let reference = p.reference.clone().unwrap();
    assert!(p.is_tared(), "a bundle with a reference image loads tared");
    let tared = p.predict_network(std::slice::from_ref(&reference)).unwrap().remove(0);
    assert!(tared.depth_mm.iter().all(|&v| v == 0.0), "tared, the reference itself reads zero");

    // Taring on another frame moves the zero there; the two frames then read each other's
    // difference, which cannot be zero both ways unless the tare does nothing.
    let one = |p: &Predictor, f: &image::RgbImage| p.predict_network(std::slice::from_ref(f)).unwrap().remove(0);
    let other = image::RgbImage::from_pixel(reference.width(), reference.height(), image::Rgb([128, 128, 128]));
    let other_on_reference = one(&p, &other);
    p.set_tare(Some(&other)).unwrap();
    assert!(one(&p, &other).depth_mm.iter().all(|&v| v == 0.0));
    let reference_on_other = one(&p, &reference);
    assert!(other_on_reference.max_mm() > 0.0 || reference_on_other.max_mm() > 0.0, "the tare changed nothing");
    let small = image::RgbImage::new(10, 10);
    assert!(p.set_tare(Some(&small)).is_err(), "a tare frame of the wrong size is an error");
    assert!(p.is_tared(), "and leaves the tare as it was");
    assert!(one(&p, &other).depth_mm.iter().all(|&v| v == 0.0), "still tared on the other frame");
    p.set_tare(None).unwrap();
    assert!(!p.is_tared());
}

/// A dataset rendered under random looks: each frame is read against its own sample's
/// untouched frame, whose own reading is then zero (the tare), in the library and in `eval`.
#[test]
fn samples_under_their_own_looks_are_read_against_their_own_untouched_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle(&dir);
    let data = tmp.path().join("data");
    dataset_with(&renderer, &data, 4, |params| formats::dataset::GeneratorParams {
        test_fraction: 1.0,
        random_looks: true,
        ..params
    });
    let device = model::backend::default_device();
    let p = Predictor::load(&dir, &device).unwrap();
    let manifest = formats::dataset::Manifest::load(&data).unwrap();
    let mut expected = Vec::new();
    for s in &manifest.samples {
        let frame = sensor::frame::read(&data.join(s.image.as_ref().unwrap())).unwrap();
        let reference = sensor::frame::read(&data.join(s.reference.as_ref().unwrap())).unwrap();
        let mut own = p.clone();
        own.set_reference(reference.clone()).unwrap();
        assert_eq!(own.reference.as_ref(), Some(&reference));
        let on_itself = own.predict_network(std::slice::from_ref(&reference)).unwrap().remove(0);
        assert!(on_itself.depth_mm.iter().all(|&v| v == 0.0), "sample {}: its untouched frame reads zero", s.id);
        let (with_own, _) = own.predict_gated(&frame).unwrap();
        let (with_units, _) = p.predict_gated(&frame).unwrap();
        assert_ne!(with_own.depth_mm, with_units.depth_mm, "sample {}: the reference is not used", s.id);
        expected.push(with_own);
        // A reference of the wrong size is refused and changes nothing.
        let small = image::RgbImage::new(10, 10);
        assert!(own.set_reference(small).is_err());
        assert_eq!(own.reference.as_ref(), Some(&reference));
    }
    // eval reads each sample against its own reference: its errors are those of the
    // predictions above.
    let stats =
        infer::eval::evaluate_dataset(&p, &data, &[formats::dataset::Split::Test], &tmp.path().join("e")).unwrap();
    let mask = &p.mask;
    let truth: Vec<sensor::DepthMap> =
        manifest.samples.iter().map(|s| sensor::DepthMap::load_png_um(&data.join(&s.depth)).unwrap()).collect();
    let mean_l1: f64 = expected
        .iter()
        .zip(&truth)
        .map(|(e, t)| infer::eval::ImageErrors::of(0, formats::Split::Test, &e.depth_mm, &t.depth_mm, mask).l1_mm)
        .sum::<f64>()
        / expected.len() as f64;
    let got = stats[&formats::dataset::Split::Test].l1_mm.mean;
    assert!((got - mean_l1).abs() < 1e-9, "eval's L1 {got} against {mean_l1} read sample by sample");
}

/// A test bundle in `tmp/bundle` and a pressed frame of its unit in `tmp/frame.png`.
fn bundle_and_pressed_frame(tmp: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = tmp.join("bundle");
    let (_, frame) = pressed(&bundle(&dir));
    let image = tmp.join("frame.png");
    frame.save(&image).unwrap();
    (dir, image)
}

#[test]
fn the_command_writes_depth_colour_and_a_point_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, image) = bundle_and_pressed_frame(tmp.path());
    let out = |name: &str| tmp.path().join(name).to_str().unwrap().to_string();
    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap()])
        .args(["--depth-out", &out("d.png"), "--colour-out", &out("c.png"), "--ply", &out("p.ply"), "--always"])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let depth = sensor::DepthMap::load_png_um(Path::new(&out("d.png"))).unwrap();
    assert_eq!(depth.size_px, 570);
    assert_eq!(image::open(out("c.png")).unwrap().to_rgb8().dimensions(), (570, 570));
    let ply = std::fs::read(out("p.ply")).unwrap();
    assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));

    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["predict", "--bundle", tmp.path().join("nothing").to_str().unwrap(), "--image", image.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("bundle.json"));
}

/// `infer bench` times each stage and gives its median and quartiles to a hundredth of a
/// millisecond, the quartiles around the median.
#[test]
fn bench_reports_each_stage_with_its_quartiles() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, image) = bundle_and_pressed_frame(tmp.path());
    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["bench", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap(), "--repeats", "5"])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let out = String::from_utf8_lossy(&r.stdout);
    for stage in ["network only", "end to end", "as `predict`", "frame without contact"] {
        let line = out.lines().find(|l| l.trim_start().starts_with(stage)).unwrap_or_else(|| panic!("{stage}: {out}"));
        let numbers: Vec<f64> = line
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .filter(|w| w.contains('.'))
            .map(|w| w.parse().unwrap())
            .collect();
        let [median, q1, q3] = numbers[..] else { panic!("{stage}: median [q1, q3] expected: {line}") };
        assert!(q1 <= median && median <= q3 && q1 > 0.0, "{line}");
        assert!(
            line.split_whitespace()
                .all(|w| !w.contains('.')
                    || w.trim_matches(['[', ']', ',']).split('.').nth(1).is_some_and(|d| d.len() == 2)),
            "{line}"
        );
    }
}

/// The camera's full frame (PNG or JPEG) is cut around the bundle's optical centre and reads as
/// its crop does; greyscale and BGR frames are refused with the reason, through the CLI too.
#[test]
fn full_camera_frames_and_jpeg_are_read_and_wrong_colours_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle(&dir);
    let p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    let unit = renderer.unit().clone();
    // The same press rendered on the whole camera frame.
    let full = Renderer::new(&unit, dataset::PixelGrid::frame(&unit.sensor, 1));
    let (depth, crop) = pressed(&renderer);
    let (x0, y0) = unit.sensor.crop_origin_px();
    let (n, w) = (unit.sensor.crop_size_px as usize, unit.sensor.frame_width_px as usize);
    let mut frame_depth = vec![0f32; full.grid().len()];
    for (y, row) in depth.chunks_exact(n).enumerate() {
        let at = (y0 as usize + y) * w + x0 as usize;
        frame_depth[at..at + n].copy_from_slice(row);
    }
    let frame = full.render(&frame_depth, None);
    assert_eq!(frame.dimensions(), (800, 600));
    let png = tmp.path().join("full.png");
    frame.save(&png).unwrap();
    let from_full = p.read_frame(&png).unwrap();
    assert_eq!(from_full.dimensions(), (570, 570));
    // Noise aside, the full frame's crop is the crop.
    let noiseless = renderer.render(&depth, None);
    assert_eq!(from_full, noiseless);
    let jpeg = tmp.path().join("full.jpg");
    std::fs::write(&jpeg, sensor::frame::encode_jpeg_rgb(&frame, 92)).unwrap();
    let (a, b) =
        (p.predict_network(&[noiseless]).unwrap(), p.predict_network(&[p.read_frame(&jpeg).unwrap()]).unwrap());
    let mean_diff = a[0].depth_mm.iter().zip(&b[0].depth_mm).map(|(x, y)| (x - y).abs()).sum::<f32>() / (n * n) as f32;
    assert!(mean_diff < 0.05, "a JPEG frame reads like its PNG: {mean_diff} mm apart on average");

    let mut bgr = crop.clone();
    bgr.pixels_mut().for_each(|px| px.0.swap(0, 2));
    let swapped = tmp.path().join("bgr.png");
    bgr.save(&swapped).unwrap();
    let e = p.read_frame(&swapped).unwrap_err().to_string();
    assert!(e.contains("bgr.png") && e.contains("BGR"), "{e}");
    let grey = tmp.path().join("grey.png");
    image::DynamicImage::ImageRgb8(crop).to_luma8().save(&grey).unwrap();
    for (file, words) in [(&swapped, "BGR"), (&grey, "greyscale")] {
        let r = Command::new(env!("CARGO_BIN_EXE_infer"))
            .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", file.to_str().unwrap()])
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && e.contains(words), "{e}");
    }
    let small = tmp.path().join("small.png");
    image::RgbImage::from_pixel(640, 480, image::Rgb([10, 200, 30])).save(&small).unwrap();
    let e = p.read_frame(&small).unwrap_err().to_string();
    assert!(e.contains("640x480") && e.contains("800x600"), "{e}");
}

/// `cargo tree -e normal --prefix none --offline` with `args`, run in the workspace's root.
fn cargo_tree(args: &[&str]) -> String {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let r = Command::new(env!("CARGO"))
        .args(["tree", "-e", "normal", "--prefix", "none", "--offline"])
        .args(args)
        .current_dir(root)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    String::from_utf8_lossy(&r.stdout).into_owned()
}

/// Neither `-p infer` nor a plain `cargo build` in the workspace's root (its default members,
/// which leave `train` out because Cargo unifies the features of the packages one build
/// selects) compiles autodiff into the inference binary; `-p train` does, so the check can fail.
#[test]
fn infer_depends_on_neither_autodiff_nor_training() {
    for (what, args) in [("-p infer", &["-p", "infer"][..]), ("the default members", &[])] {
        let tree = cargo_tree(args);
        assert!(
            tree.contains("burn-flex") && tree.contains("infer v"),
            "{what}: the tree lists Burn and infer: {tree}"
        );
        for banned in ["burn-autodiff", "burn-train", "train v", "burn-optim"] {
            assert!(!tree.contains(banned), "{what}: infer must not be built with {banned}");
        }
    }
    assert!(cargo_tree(&["-p", "train"]).contains("burn-autodiff"), "the check sees autodiff where it is");
}

#[test]
fn eval_writes_statistics_per_split_errors_and_a_violin_plot() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle(&dir);
    let data = tmp.path().join("data");
    dataset_of(&renderer, &data, 10, 0.3);
    let out = tmp.path().join("eval");
    let r = eval(&dir, &data, "all", &out);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    let mut n = 0;
    for split in ["train", "test"] {
        for key in infer::eval::STAT_KEYS {
            assert!(stats[split][key]["mean"].is_number(), "{split}.{key}: {}", stats[split][key]);
        }
        n += stats[split]["l1_mm"]["n"].as_u64().unwrap();
    }
    assert_eq!(n, 10);
    // Read back as the quickstart reads it: keyed by split, typed.
    let typed: std::collections::BTreeMap<formats::dataset::Split, infer::eval::SplitStats> =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    assert_eq!(
        typed.keys().copied().collect::<Vec<_>>(),
        [formats::dataset::Split::Train, formats::dataset::Split::Test]
    );
    assert_eq!(typed.values().map(|s| s.l1_mm.n).sum::<usize>(), 10);
    let csv = std::fs::read_to_string(out.join("errors.csv")).unwrap();
    assert_eq!(csv.lines().count(), 11);
    assert!(std::fs::read_to_string(out.join("violin.svg")).unwrap().contains("<polygon"));
    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["eval", "--bundle", dir.to_str().unwrap(), "--data", data.to_str().unwrap()])
        .args(["--split", "val", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("--split"));
}

/// Outputs never overwrite an input, and a failure writes none of them; an evaluation of a split
/// with no samples is an error, not NaN statistics.
#[test]
fn outputs_spare_inputs_and_come_whole_or_not_at_all() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle(&dir);
    let (_, frame) = pressed(&renderer);
    let image = tmp.path().join("f.png");
    frame.save(&image).unwrap();
    let before = std::fs::read(&image).unwrap();
    let predict = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_infer"))
            .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap(), "--always"])
            .args(extra)
            .output()
            .unwrap()
    };
    let r = predict(&["--depth-out", image.to_str().unwrap()]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("is also an input"));
    assert_eq!(std::fs::read(&image).unwrap(), before);
    let d = tmp.path().join("d.png");
    let r = predict(&["--depth-out", d.to_str().unwrap(), "--colour-out", d.to_str().unwrap()]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("two outputs"));
    // The point cloud cannot be written (its folder is missing): the depth map is not left alone.
    let ply = tmp.path().join("missing/p.ply");
    let r = predict(&["--depth-out", d.to_str().unwrap(), "--ply", ply.to_str().unwrap()]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("p.ply"));
    assert!(!d.exists(), "a failed command leaves none of its outputs");
    // Never into the bundle's folder (over its own files or beside them), nor into a dataset's.
    let data = tmp.path().join("data");
    dataset_of(&renderer, &data, 4, 0.0);
    let reference = std::fs::read(dir.join("reference.png")).unwrap();
    for out in [dir.join("reference.png"), dir.join("depth.png"), data.join("depth/extra.png")] {
        let r = predict(&["--depth-out", out.to_str().unwrap()]);
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && (e.contains("input folder") || e.contains("only its own command")), "{e}");
    }
    assert_eq!(std::fs::read(dir.join("reference.png")).unwrap(), reference);
    assert!(Predictor::load(&dir, &model::backend::default_device()).is_ok(), "the bundle still loads");

    // A dataset without test samples: `--split test` is an error naming it.
    let out = tmp.path().join("eval");
    let r = eval(&dir, &data, "test", &out);
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && e.contains("no test samples"), "{e}");
    assert!(!out.exists(), "nothing is written");
}

#[test]
fn a_reference_difference_bundle_reads_its_reference_and_predicts_at_full_resolution() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("b");
    let unit = SensorUnit::from_seed(3, 25.0);
    let renderer = Renderer::for_crop(&unit);
    let device = model::backend::default_device();
    let config = DenseDepthConfig::new(DenseNetConfig::tiny())
        .with_input(model::InputChannels::RgbDifference)
        .with_full_resolution(true);
    let net = config.init(&device);
    let file = bundle_file(config, &unit);
    // Such a bundle is not written without the reference frame its input needs.
    let e = write_bundle(&dir, &net, &file, None, &[]).unwrap_err().to_string();
    assert!(e.contains("reference image") && !dir.exists(), "{e}");
    let reference_frame = renderer.reference_image(1);
    write_bundle(&dir, &net, &file, Some(&sensor::frame::encode_png_rgb(&reference_frame)), &[]).unwrap();

    let predictor = Predictor::load(&dir, &device).unwrap();
    let input = predictor.input(std::slice::from_ref(&reference_frame)).unwrap();
    assert_eq!(input.dims(), [1, 6, 64, 64]);
    let values = input.into_data().try_to_vec::<f32>().unwrap();
    assert!(values[3 * 64 * 64..].iter().all(|&v| v == 0.0), "the reference differs from itself by nothing");
    assert!(values[..3 * 64 * 64].iter().any(|&v| v > 0.1), "the RGB channels come first");
    let (_, frame) = pressed(&renderer);
    let out = predictor.forward(predictor.input(std::slice::from_ref(&frame)).unwrap());
    assert_eq!(out.dims(), [1, 1, 64, 64]);
    let depth = predictor.predict_network(std::slice::from_ref(&frame)).unwrap().remove(0);
    assert_eq!(depth.size_px, unit.sensor.crop_size_px);

    // The difference is read at the gain the bundle records (the unit's, fitted in training).
    let fitted = model::InputEncoding { channels: model::InputChannels::RgbDifference, difference_gain: 10.0 };
    let strong = tmp.path().join("strong");
    let file10 = model::bundle::BundleFile { input_encoding: fitted.text(), ..file.clone() };
    write_bundle(&strong, &net, &file10, Some(&sensor::frame::encode_png_rgb(&reference_frame)), &[]).unwrap();
    let difference = |p: &Predictor| -> Vec<f32> {
        let v = p.input(std::slice::from_ref(&frame)).unwrap().into_data().try_to_vec::<f32>().unwrap();
        v[3 * 64 * 64..].to_vec()
    };
    let (at4, at10) = (difference(&predictor), difference(&Predictor::load(&strong, &device).unwrap()));
    assert!(at4.iter().any(|&v| v.abs() > 0.01), "the pressed frame differs from the reference");
    for (a, b) in at4.iter().zip(&at10) {
        assert!((b - 2.5 * a).abs() < 1e-5, "{b} against 2.5 x {a}");
    }

    // A bundle whose file names no reference image is refused on loading, by name.
    let json = dir.join(model::bundle::BUNDLE_JSON);
    let text = std::fs::read_to_string(&json).unwrap();
    std::fs::write(&json, text.replace("\"reference_image\": \"reference.png\"", "\"reference_image\": null")).unwrap();
    let e = Predictor::load(&dir, &device).err().unwrap().to_string();
    assert!(e.contains("bundle.json") && e.contains("reference"), "{e}");
}

/// Bundles whose input is not a multiple of 32 (odd sides, not square) load and predict the
/// crop's depth; the output follows `output_hw`; a side under 32 is refused by name on loading.
#[test]
fn bundles_of_any_input_size_predict_and_too_small_ones_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let unit = SensorUnit::from_seed(3, 25.0);
    let renderer = Renderer::for_crop(&unit);
    let device = model::backend::default_device();
    let (_, frame) = pressed(&renderer);
    for (k, (full_resolution, [h, w])) in [(false, [75, 90]), (true, [57, 33])].into_iter().enumerate() {
        let dir = tmp.path().join(format!("b{k}"));
        let config = DenseDepthConfig::new(DenseNetConfig::tiny()).with_full_resolution(full_resolution);
        let net = config.init(&device);
        let file = BundleFile { input_height_px: h, input_width_px: w, ..bundle_file(config.clone(), &unit) };
        write_bundle(&dir, &net, &file, None, &[]).unwrap();
        let predictor = Predictor::load(&dir, &device).unwrap();
        let out = predictor.forward(predictor.input(std::slice::from_ref(&frame)).unwrap());
        let [oh, ow] = config.output_hw([h, w]);
        assert_eq!(out.dims(), [1, 1, oh, ow]);
        let depth = predictor.predict_network(std::slice::from_ref(&frame)).unwrap().remove(0);
        assert_eq!(depth.size_px, unit.sensor.crop_size_px);
        assert!(depth.depth_mm.iter().all(|d| d.is_finite()));
    }
    let dir = tmp.path().join("small");
    let config = DenseDepthConfig::new(DenseNetConfig::tiny());
    let net = config.init(&device);
    let file = BundleFile { input_height_px: 28, input_width_px: 64, ..bundle_file(config, &unit) };
    write_bundle(&dir, &net, &file, None, &[]).ok();
    let e = Predictor::load(&dir, &device).err().expect("a 28 px side is refused").to_string();
    assert!(e.contains("bundle.json") && e.contains("at least 29"), "{e}");
}
