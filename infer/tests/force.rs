//! A bundle with the pressure output: the force read back through the dome's areas, its files,
//! the tare and the gate, and the evaluation's force figures.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{PRESSURE_KPA, bundle_with, constant, dataset_of, pressed, pressure_config};
use infer::Predictor;

/// A uniform pressure on the whole visible cap pushes along the axis with p times the cap's
/// projected area, pi (R sin theta_max)^2: read through the bundle, its files and its tare.
#[test]
fn a_uniform_pressure_output_gives_the_caps_projected_force() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle_with(&dir, pressure_config(), constant);
    let device = model::backend::default_device();
    let mut p = Predictor::load(&dir, &device).unwrap();
    assert!(p.has_force());
    let (_, frame) = pressed(&renderer);

    // Tared on the reference frame, a constant network reads no contact and no force.
    let tared = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0);
    let force = tared.force.expect("a force bundle reports force");
    assert!(tared.depth.depth_mm.iter().all(|&d| d.abs() < 1e-4));
    assert!(force.pressure.pressure_kpa.iter().all(|&v| v == 0.0), "no contact, no pressure");
    assert_eq!(force.wrench, sensor::Wrench::default());

    p.set_tare(None).unwrap();
    let out = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0);
    let force = out.force.unwrap();
    let sensor = &p.file.sensor;
    let r_base = sensor.radius_mm * sensor.max_theta_rad.sin();
    let want_n = PRESSURE_KPA as f64 * std::f64::consts::PI * r_base * r_base * 1e-3;
    let [fx, fy, fz] = force.wrench.force_n;
    assert!((fz + want_n).abs() <= 0.01 * want_n, "fz {fz} N against -{want_n} N");
    assert!(fx.abs() <= 0.01 * want_n && fy.abs() <= 0.01 * want_n, "{:?}", force.wrench.force_n);
    // Pressure on the useful disk only, at the network's value.
    for ((&v, &m), &d) in force.pressure.pressure_kpa.iter().zip(&p.mask).zip(&out.depth.depth_mm) {
        assert!(if m { (v - PRESSURE_KPA).abs() < 0.01 && d > 0.9 } else { v == 0.0 }, "{v} kPa, mask {m}, {d} mm");
    }
    assert_eq!(force.wrench, sensor::DomeAreas::new(sensor).wrench(&force.pressure.pressure_kpa));

    // The command writes the same map (0.1 kPa steps) and prints the force.
    let image = tmp.path().join("frame.png");
    std::fs::write(&image, sensor::frame::encode_png_rgb(&frame)).unwrap();
    let pressure_png = tmp.path().join("pressure.png");
    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap(), "--always"])
        .args(["--no-tare", "--pressure-out", pressure_png.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(stdout.contains(&format!("force {:.3} N", force.wrench.force_magnitude_n())), "{stdout}");
    let back = sensor::PressureMap::load_png(&pressure_png).unwrap();
    assert!(back.pressure_kpa.iter().zip(&force.pressure.pressure_kpa).all(|(a, b)| (a - b).abs() <= 0.05));
}

/// A bundle with the force head reports the head's force, with the pressure map scaled to it
/// (the map's shape, the head's size; the torque with the map); tared, less the head's reading of
/// the reference frame; the gate's answer pushes nothing; with `head_force` off, the map's own
/// resultant again.
#[test]
fn the_force_head_gives_the_force_and_the_pressure_scales_to_it() {
    use burn::module::Param;
    use burn::tensor::Tensor;
    const HEAD_N: [f64; 3] = [3.0, -4.0, -12.0];
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let config = pressure_config().with_force_head(Some(8));
    // A head that answers HEAD_N whatever the frame: its linear map's weights zero, its bias set.
    let renderer = bundle_with(&dir, config, |net, scale| {
        let mut net = constant(net, scale);
        let head = net.decoder.force.as_mut().expect("the force head");
        let w = head.linear.weight.val();
        head.linear.weight = Param::from_tensor(w.zeros_like());
        let device = w.device();
        let bias = HEAD_N.map(|v| v as f32 / model::FORCE_N_PER_LOSS_UNIT);
        head.linear.bias = Some(Param::from_tensor(Tensor::<1>::from_floats(bias, &device)));
        net
    });
    let mut p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    assert!(p.has_force() && p.head_force);
    let (_, frame) = pressed(&renderer);
    let areas = sensor::DomeAreas::new(&p.file.sensor);

    // Untared: the constant network reads contact everywhere; the head's force is reported,
    // and the uniform pressure is scaled to its size.
    p.set_tare(None).unwrap();
    let out = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0);
    let force = out.force.expect("a force bundle reports force");
    for (got, want) in force.wrench.force_n.iter().zip(HEAD_N) {
        assert!((got - want).abs() < 1e-5, "{:?} N against {HEAD_N:?}", force.wrench.force_n);
    }
    p.head_force = false;
    let map = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0).force.unwrap();
    let scale = 13.0 / map.wrench.force_magnitude_n();
    for ((&v, &m), &own) in force.pressure.pressure_kpa.iter().zip(&p.mask).zip(&map.pressure.pressure_kpa) {
        assert!((v as f64 - own as f64 * scale).abs() <= 1e-4 * v.abs().max(1.0) as f64, "{v} against {own} x {scale}");
        assert!(!m || v > 0.0);
    }
    let resultant = areas.wrench(&force.pressure.pressure_kpa).force_magnitude_n();
    assert!((resultant - 13.0).abs() < 1e-3 * 13.0, "the scaled map's resultant is {resultant} N");
    for (t, own) in force.wrench.torque_nmm.iter().zip(map.wrench.torque_nmm) {
        assert!((t - own * scale).abs() <= 1e-9 * (1.0 + own.abs() * scale), "torque {t} against {own} x {scale}");
    }

    // Tared on the reference frame: the constant network reads no contact, so no force.
    p.head_force = true;
    let reference = p.reference.clone().unwrap();
    p.set_tare(Some(&reference)).unwrap();
    let tared = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0);
    assert_eq!(tared.force.unwrap().wrench, sensor::Wrench::default());
    let untouched = p.predict_all(&reference).unwrap();
    assert!(!untouched.network_ran);
    assert_eq!(untouched.force.unwrap().wrench, sensor::Wrench::default());
}

/// A depth-only bundle has no pressure to write, and says so; its predictions carry no force,
/// unless the command names an elastomer to solve them with.
#[test]
fn a_depth_only_bundle_refuses_a_pressure_output() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = common::bundle(&dir);
    let p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    let (_, frame) = pressed(&renderer);
    assert!(!p.has_force() && p.predict_all(&frame).unwrap().force.is_none());
    let image = tmp.path().join("frame.png");
    std::fs::write(&image, sensor::frame::encode_png_rgb(&frame)).unwrap();
    let out = tmp.path().join("p.png");
    let r = Command::new(env!("CARGO_BIN_EXE_infer"))
        .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap()])
        .args(["--pressure-out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && err.contains("no force output"), "{err}");
    assert!(!out.exists());

    // Given an elastomer on the command line, the same bundle solves the predicted contact
    // with it: the map and the force the library gives with that elastomer.
    let predict_with = |modulus: &str| {
        Command::new(env!("CARGO_BIN_EXE_infer"))
            .args(["predict", "--bundle", dir.to_str().unwrap(), "--image", image.to_str().unwrap()])
            .args(["--pressure-out", out.to_str().unwrap(), "--effective-modulus-mpa", modulus])
            .output()
            .unwrap()
    };
    let r = predict_with("0.4");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let mut p = p;
    p.set_elastomer(Some(model::bundle::ElastomerRecord::given(0.4))).unwrap();
    let force = p.predict_all(&frame).unwrap().force.expect("solved force");
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(stdout.contains(&format!("force {:.3} N", force.wrench.force_magnitude_n())), "{stdout}");
    let back = sensor::PressureMap::load_png(&out).unwrap();
    assert!(back.pressure_kpa.iter().zip(&force.pressure.pressure_kpa).all(|(a, b)| (a - b).abs() <= 0.05));
    std::fs::remove_file(&out).unwrap();
    for bad in ["-1", "0", "nan"] {
        let r = predict_with(bad);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && err.contains("--effective-modulus-mpa") && err.contains("positive"), "{err}");
        assert!(!out.exists());
    }
}

/// `eval` of a force bundle on samples with force labels adds the force figures: per image in
/// errors.csv (against the labels' wrench and pressure map), per split in stats.json, and the
/// force violin.
#[test]
fn eval_of_a_force_bundle_scores_force_against_the_labels() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle_with(&dir, pressure_config(), constant);
    let data = tmp.path().join("data");
    dataset_of(&renderer, &data, 6, 0.34);
    let out = tmp.path().join("eval");
    let mut p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    p.set_tare(None).unwrap();
    p.gate = None;
    let stats = infer::eval::evaluate_dataset(&p, &data, &[formats::Split::Train, formats::Split::Test], &out).unwrap();
    let manifest = formats::dataset::Manifest::load(&data).unwrap();
    // The constant network's force is the same on every frame: each image's error is its
    // distance to that image's label.
    let frame = p.read_frame(&data.join(manifest.samples[0].image.as_ref().unwrap())).unwrap();
    let predicted = p.predict_all(&frame).unwrap().force.unwrap().wrench;
    let csv = std::fs::read_to_string(out.join("errors.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    for line in csv.lines().skip(1) {
        let cells: Vec<&str> = line.split(',').collect();
        let id: u32 = cells[col("id")].parse().unwrap();
        let sample = manifest.samples.iter().find(|s| s.id == id).unwrap();
        let truth = sample.wrench.expect("force labels");
        let got: f64 = cells[col("force_error_n")].parse().unwrap();
        assert!((got - predicted.force_distance_n(&truth)).abs() < 1e-9, "{line}");
        let magnitude: f64 = cells[col("force_n")].parse().unwrap();
        assert!((magnitude - truth.force_magnitude_n()).abs() < 1e-9);
        assert!(cells[col("pressure_l1_kpa")].parse::<f64>().unwrap() > 0.0);
    }
    for s in stats.values() {
        let f = s.force.as_ref().expect("force figures");
        assert_eq!(f.force_n.n, s.l1_mm.n);
        let pct = 100.0 * f.force_magnitude_error_n.mean / f.force_n.mean;
        assert!((f.force_magnitude_error_pct - pct).abs() < 1e-9);
    }
    let violin = std::fs::read_to_string(out.join("force_violin.svg")).unwrap();
    assert!(violin.contains("<polygon") && violin.contains("DenseTact 2.0"));
    assert!(Path::new(&out.join("violin.svg")).is_file());
}

/// A stream of a force bundle writes each contact frame's pressure map beside its depth and
/// each frame's force in frames.csv.
#[test]
fn a_stream_of_a_force_bundle_writes_pressure_and_force() {
    use infer::stream::{FolderSink, GlobSource, Sink, StreamLimits};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle_with(&dir, pressure_config(), constant);
    let mut p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    p.set_tare(None).unwrap();
    let (_, frame) = pressed(&renderer);
    let frames = tmp.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    std::fs::write(frames.join("a.png"), sensor::frame::encode_png_rgb(&frame)).unwrap();
    let out = tmp.path().join("out");
    let mut sink = FolderSink::new(&out).unwrap();
    let source = Box::new(GlobSource::new(frames.join("*.png").to_str().unwrap(), None).unwrap());
    let mut sinks: Vec<&mut dyn Sink> = vec![&mut sink];
    let stop = std::sync::atomic::AtomicBool::new(false);
    let report = infer::stream::run(&p, source, &mut sinks, &StreamLimits::default(), &stop).unwrap();
    sink.finish(&report).unwrap();
    let want = p.predict_all(&frame).unwrap().force.unwrap();
    let map = sensor::PressureMap::load_png(&out.join("pressure/a.png")).unwrap();
    assert!(map.pressure_kpa.iter().zip(&want.pressure.pressure_kpa).all(|(a, b)| (a - b).abs() <= 0.05));
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let row: Vec<&str> = csv.lines().nth(1).unwrap().split(',').collect();
    let fz: f64 = row[header.iter().position(|h| *h == "fz_n").unwrap()].parse().unwrap();
    assert_eq!(fz, want.wrench.force_n[2]);
}

/// A depth-only bundle that records its unit's elastomer reports the contact solved on the
/// predicted depth: the contact model's own solve of that map (pixels under the contact
/// threshold left out), scaling with E*, zero on a frame the gate answers; turned off, no force.
#[test]
fn a_fitted_elastomer_solves_the_force_on_the_predicted_depth() {
    use mechanics::{Dome, GridConfig, Material, force_label};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = common::bundle(&dir);
    let mut p = Predictor::load(&dir, &model::backend::default_device()).unwrap();
    assert!(!p.has_force() && p.solved_force(&sensor::DepthMap::zeros(p.file.sensor.crop_size_px)).is_none());
    let record = model::bundle::ElastomerRecord::given;
    let e_star = 0.4;
    p.set_elastomer(Some(record(e_star))).unwrap();
    assert!(p.has_force() && p.solve_force);

    // A 1 mm dent as a network might predict it, and a speck below the contact threshold.
    let (depth, frame) = pressed(&renderer);
    let n = renderer.grid().width as usize;
    let clean = sensor::DepthMap { size_px: n as u32, depth_mm: depth };
    let mut specked = clean.clone();
    specked.depth_mm[250 * n + 250] = 0.5 * sensor::CONTACT_THRESHOLD_MM;
    let force = p.solved_force(&specked).unwrap();
    let dome = Dome::new(&p.file.sensor);
    let want = force_label(&dome, &clean, &Material::with_effective_modulus(e_star), &GridConfig::default()).unwrap();
    assert_eq!(force.wrench, want.wrench);
    assert_eq!(force.pressure.pressure_kpa, want.pressure_kpa);
    let f = force.wrench.force_magnitude_n();
    assert!(f > 0.1 && force.wrench.force_n[2] < -0.9 * f, "{:?}", force.wrench);
    p.set_elastomer(Some(record(2.0 * e_star))).unwrap();
    let twice = p.solved_force(&specked).unwrap().wrench.force_magnitude_n();
    assert!((twice / f - 2.0).abs() < 1e-9, "{twice} N against 2 x {f} N");
    // A modulus no silicone has is refused, and the predictor keeps the one it had.
    for bad in [0.0, -0.4, f64::NAN, f64::INFINITY] {
        let err = p.set_elastomer(Some(record(bad))).unwrap_err().to_string();
        assert!(err.contains("effective modulus"), "{err}");
        assert_eq!(p.file.elastomer.as_ref().unwrap().effective_modulus_mpa, 2.0 * e_star);
        assert_eq!(p.solved_force(&specked).unwrap().wrench.force_magnitude_n(), twice);
    }
    // The same number in a bundle's file stops its load, naming the file.
    let text = std::fs::read_to_string(dir.join(model::bundle::BUNDLE_JSON)).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["elastomer"] = serde_json::to_value(record(-1.0)).unwrap();
    std::fs::write(dir.join(model::bundle::BUNDLE_JSON), json.to_string()).unwrap();
    let err = Predictor::load(&dir, &model::backend::default_device()).err().expect("refused").to_string();
    assert!(err.contains("bundle.json") && err.contains("effective modulus"), "{err}");
    std::fs::write(dir.join(model::bundle::BUNDLE_JSON), text).unwrap();

    // Predictions solve the network's own depth, frame by frame; the gate's answer has none.
    let pred = p.predict_network_all(std::slice::from_ref(&frame)).unwrap().remove(0);
    assert_eq!(pred.force.unwrap().wrench, p.solved_force(&pred.depth).unwrap().wrench);
    let reference = p.reference.clone().unwrap();
    let untouched = p.predict_all(&reference).unwrap();
    assert!(!untouched.network_ran);
    assert_eq!(untouched.force.unwrap().wrench, sensor::Wrench::default());
    p.solve_force = false;
    assert!(!p.has_force() && p.predict_all(&frame).unwrap().force.is_none());
}
