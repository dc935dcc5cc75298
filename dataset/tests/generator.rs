//! The generator end to end: determinism, kill -9 and resume, bad arguments.

use std::path::Path;
use std::process::Command;

use crate::common;
use common::files;

/// The folders whose files make up a dataset here.
const DATASET_FILES: [&str; 4] = ["", "samples", "depth", "pressure"];

const BIN: &str = env!("CARGO_BIN_EXE_dataset");

fn generate(out: &Path, count: u32, extra: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .args(["generate", "--out", out.to_str().unwrap(), "--count", &count.to_string(), "--seed", "11"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn killed_and_resumed_run_equals_an_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let count = 400;

    // Kill -9 once some samples are done.
    let args = ["generate", "--out", a.to_str().unwrap(), "--count", &count.to_string(), "--seed", "11"];
    let mut child = common::spawn_until(BIN, &args, &a, 10);
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!a.join("manifest.json").exists(), "the run finished before it could be killed");
    // A half-written file as a kill could leave it.
    std::fs::write(a.join("depth/.000399.png.1234.tmp"), b"half").unwrap();

    let resumed = generate(&a, count, &[]);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let stdout = String::from_utf8_lossy(&resumed.stdout);
    assert!(stdout.contains("from an earlier run") && stdout.contains("contact"), "{stdout}");

    // As a power cut could leave them: a short PNG and a short record.
    let png = a.join("depth/000005.png");
    let bytes = std::fs::read(&png).unwrap();
    std::fs::write(&png, &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(a.join("samples/000007.json"), b"{\"id\": 7, \"spl").unwrap();
    let repaired = generate(&a, count, &[]);
    assert!(repaired.status.success(), "{}", String::from_utf8_lossy(&repaired.stderr));
    assert!(String::from_utf8_lossy(&repaired.stderr).contains("2 samples left incomplete"));
    assert!(String::from_utf8_lossy(&repaired.stdout).contains("(2 new"));

    let fresh = generate(&b, count, &[]);
    assert!(fresh.status.success());
    let (fa, fb) = (files(&a, &DATASET_FILES), files(&b, &DATASET_FILES));
    assert_eq!(fa.len(), fb.len());
    // generator.json, manifest.json, the output marker and its lock file, then a record, a
    // depth map and a pressure map a sample.
    assert_eq!(fa.len(), 4 + 3 * count as usize);
    for ((na, ca), (nb, cb)) in fa.iter().zip(&fb) {
        assert_eq!(na, nb);
        assert!(ca == cb, "{na} differs between the resumed and the uninterrupted run");
    }
    let manifest = formats::dataset::Manifest::load(&a).unwrap();
    assert_eq!(manifest.samples.len(), count as usize);
    assert!(manifest.summary.values().all(|s| s.samples > 0 && s.mean_contact_fraction > 0.0));
}

/// Kill anywhere, edit nothing, resume = uninterrupted: a generator run (random looks, so every
/// folder a dataset can have) killed -9 eight times at seeded moments across the run, each time
/// run again, writes exactly the uninterrupted run's files.
#[test]
fn a_generator_killed_anywhere_resumes_to_the_uninterrupted_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let args = |out: &Path| {
        let out = out.to_str().unwrap();
        common::kill::strings(&[
            "generate",
            "--out",
            out,
            "--count",
            "120",
            "--seed",
            "11",
            "--unit",
            "2",
            "--random-looks",
        ])
    };
    let span = common::kill::timed_run(BIN, &args(&a));
    let kills = common::kill::kill_anywhere(BIN, &args(&b), &args(&b), 8, span, 21);
    assert!(kills.mid_run >= 1, "no kill landed mid-run: {kills:?}");
    common::assert_same_files(&a, &b, &format!("after the kills {kills:?}"));
}

#[test]
fn bad_arguments_and_mismatched_folders_fail_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("d");
    let r = generate(&out, 3, &["--z-min-mm", "3", "--z-max-mm", "1"]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("--z-min-mm"));

    assert!(generate(&out, 3, &[]).status.success());
    let r = generate(&out, 3, &["--z-max-mm", "1.0"]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    // The refusal names the setting that differs, with both values.
    assert!(err.contains("generator.json") && err.contains("z_travel_mm: [0.0,2.5] before, [0.0,1.0] now"), "{err}");

    let r = generate(&tmp.path().join("e"), 3, &["--kit", "/nonexistent/kit"]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("/nonexistent/kit"));

    let bad_sensor = tmp.path().join("sensor.json");
    std::fs::write(&bad_sensor, "{\"radius_mm\": 25}").unwrap();
    let r = generate(&tmp.path().join("f"), 3, &["--sensor", bad_sensor.to_str().unwrap()]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("sensor.json"));
}

#[test]
fn a_units_images_follow_its_depth_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let r = generate(&a, 6, &["--unit", "5"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let manifest = formats::dataset::Manifest::load(&a).unwrap();
    let truth = sensor::Sensor::load_json(&a.join("unit/truth.json")).unwrap();
    assert_eq!(manifest.sensor, truth, "a unit's dataset is labelled in its true geometry");
    assert_eq!(manifest.generator.as_ref().unwrap().unit, Some(5));
    let reference = image::open(a.join("unit/reference.png")).unwrap().to_rgb8();
    let mask = truth.valid_mask();
    for s in &manifest.samples {
        let img = image::open(a.join(s.image.as_ref().unwrap())).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (570, 570));
        let depth = sensor::DepthMap::load_png_um(&a.join(&s.depth)).unwrap();
        // Far from contact (80 px beyond the box holding it) the membrane's sag has faded to a
        // few grey levels beside the noise (measured: 3.2 on average beside a 37,000-pixel
        // press); under contact the shading changes more than twice as much.
        let n = 570usize;
        let (mut x0, mut y0, mut x1, mut y1) = (n, n, 0, 0);
        for (i, &d) in depth.depth_mm.iter().enumerate() {
            if d > 0.0 {
                (x0, y0, x1, y1) = (x0.min(i % n), y0.min(i / n), x1.max(i % n), y1.max(i / n));
            }
        }
        let far = |i: usize| {
            let (x, y) = (i % n, i / n);
            x + 80 < x0 || x > x1 + 80 || y + 80 < y0 || y > y1 + 80
        };
        let (mut quiet, mut quiet_n, mut pressed, mut pressed_n) = (0.0, 0.0, 0.0, 0.0);
        for (i, (p, q)) in img.pixels().zip(reference.pixels()).enumerate() {
            let diff: f64 = (0..3).map(|c| (p.0[c] as f64 - q.0[c] as f64).abs()).sum::<f64>() / 3.0;
            if !mask[i] {
                continue;
            }
            if depth.depth_mm[i] > 0.3 {
                (pressed, pressed_n) = (pressed + diff, pressed_n + 1.0);
            } else if far(i) {
                (quiet, quiet_n) = (quiet + diff, quiet_n + 1.0);
            }
        }
        if quiet_n > 1000.0 {
            let quiet = quiet / quiet_n;
            assert!(quiet < 5.0, "sample {}: {quiet} grey levels off the reference far from contact", s.id);
            if pressed_n > 100.0 {
                assert!(pressed / pressed_n > 2.0 * quiet, "sample {}: contact barely shows", s.id);
            }
        }
    }
    // Same seed and unit, same images.
    assert!(generate(&b, 6, &["--unit", "5"]).status.success());
    for s in &manifest.samples {
        let name = s.image.as_ref().unwrap();
        assert_eq!(std::fs::read(a.join(name)).unwrap(), std::fs::read(b.join(name)).unwrap());
    }
    // Another unit cannot resume this folder.
    let r = generate(&a, 6, &["--unit", "6"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("other settings") && err.contains("params.unit: 5 before, 6 now"),
        "{err}"
    );
    let r = generate(&tmp.path().join("c"), 2, &["--unit", "5", "--sensor", "x.json"]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("--sensor"));
}

#[test]
fn sawtooth_and_calibrate_commands_round_trip() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let r = Command::new(BIN).args(["sawtooth", "--unit", "9", "--out", dir.to_str().unwrap()]).output().unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let out = dir.join("sensor.json");
    let r = Command::new(BIN)
        .args(["calibrate", "--image", dir.join("sawtooth.png").to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--truth", dir.join("truth.json").to_str().unwrap(), "--max-uncertainty-px", "1"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let last = stdout.lines().last().unwrap();
    let value = |key: &str| -> f64 {
        last.split_whitespace().find_map(|kv| kv.strip_prefix(key)).unwrap_or_else(|| panic!("{last}")).parse().unwrap()
    };
    assert!(value("rms_px=") <= 0.5 && value("rms_deg=") <= 0.1, "{last}");
    // The uncertainty it states holds.
    let stated: f64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("uncertainty of the map: +-"))
        .and_then(|l| l.split_whitespace().next())
        .unwrap_or_else(|| panic!("{stdout}"))
        .parse()
        .unwrap();
    assert!(value("rms_px=") <= stated, "{last}; stated +-{stated}");
    let calibrated = sensor::Sensor::load_json(&out).unwrap();
    assert!(matches!(calibrated.correspondence.radial, sensor::RadialMap::Tabulated { .. }));

    // A depth map is no calibration image: a named error, and no output written.
    let bad = dir.join("bad.png");
    std::fs::write(&bad, sensor::DepthMap::zeros(64).to_png_um()).unwrap();
    let out2 = dir.join("sensor2.json");
    let r = Command::new(BIN)
        .args(["calibrate", "--image", bad.to_str().unwrap(), "--out", out2.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("bad.png"));
    assert!(!out2.exists());
}

#[test]
fn random_looks_give_each_sample_its_own_untouched_frame_and_keep_the_scenes() {
    let tmp = tempfile::tempdir().unwrap();
    let (plain, looks, again) = (tmp.path().join("plain"), tmp.path().join("looks"), tmp.path().join("again"));
    let r = generate(&plain, 6, &["--unit", "5"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let r = generate(&looks, 6, &["--unit", "5", "--random-looks"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (p, l) = (formats::dataset::Manifest::load(&plain).unwrap(), formats::dataset::Manifest::load(&looks).unwrap());
    assert_eq!(p.sensor, l.sensor, "the unit's geometry is kept");
    assert!(p.samples.iter().all(|s| s.reference.is_none()));
    let unit_reference = image::open(looks.join("unit/reference.png")).unwrap().to_rgb8();
    let mask = l.sensor.valid_mask();
    // Mean grey-level difference over useful pixels that the sample does not press.
    let quiet_diff = |a: &image::RgbImage, b: &image::RgbImage, depth: &sensor::DepthMap| {
        let (mut sum, mut n) = (0.0, 0.0);
        for (i, (x, y)) in a.pixels().zip(b.pixels()).enumerate() {
            if mask[i] && depth.depth_mm[i] == 0.0 {
                sum += (0..3).map(|c| (x.0[c] as f64 - y.0[c] as f64).abs()).sum::<f64>() / 3.0;
                n += 1.0;
            }
        }
        sum / n
    };
    let mut references = Vec::new();
    let mut far_from_the_units = 0;
    for (a, b) in p.samples.iter().zip(&l.samples) {
        assert_eq!((a.trial, &a.scene), (b.trial, &b.scene), "the same scenes");
        assert_eq!(std::fs::read(plain.join(&a.depth)).unwrap(), std::fs::read(looks.join(&b.depth)).unwrap());
        let depth = sensor::DepthMap::load_png_um(&looks.join(&b.depth)).unwrap();
        let frame = sensor::frame::read(&looks.join(b.image.as_ref().unwrap())).unwrap();
        let own =
            sensor::frame::read(&looks.join(b.reference.as_ref().expect("each sample has its reference"))).unwrap();
        let against_own = quiet_diff(&frame, &own, &depth);
        assert!(against_own < 6.0, "sample {}: {against_own} grey levels off its own untouched frame", b.id);
        if quiet_diff(&frame, &unit_reference, &depth) > 3.0 * against_own {
            far_from_the_units += 1;
        }
        references.push(own);
    }
    assert!(far_from_the_units >= 4, "only {far_from_the_units} of 6 looks differ from the unit's own");
    for (i, a) in references.iter().enumerate() {
        for b in &references[i + 1..] {
            assert_ne!(a, b, "every sample has its own look");
        }
    }
    // Deterministic, and resumable like any dataset: a lost reference is made again, the same.
    let lost = looks.join(l.samples[2].reference.as_ref().unwrap());
    let bytes = std::fs::read(&lost).unwrap();
    std::fs::remove_file(&lost).unwrap();
    let r = generate(&looks, 6, &["--unit", "5", "--random-looks"]);
    assert!(r.status.success() && String::from_utf8_lossy(&r.stdout).contains("(1 new"), "{r:?}");
    assert_eq!(std::fs::read(&lost).unwrap(), bytes);
    assert!(generate(&again, 6, &["--unit", "5", "--random-looks"]).status.success());
    for s in &l.samples {
        for rel in [s.image.as_ref().unwrap(), s.reference.as_ref().unwrap()] {
            assert_eq!(std::fs::read(looks.join(rel)).unwrap(), std::fs::read(again.join(rel)).unwrap(), "{rel}");
        }
    }
    // A folder made with one look cannot be resumed with the other; looks need a unit.
    let r = generate(&plain, 6, &["--unit", "5", "--random-looks"]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("random_looks"), "{r:?}");
    let r = generate(&tmp.path().join("bare"), 2, &["--random-looks"]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("--unit"), "{r:?}");
}

#[test]
fn lifted_samples_have_no_contact_and_leave_the_others_unchanged() {
    let tmp = tempfile::tempdir().unwrap();
    let (plain, lifted) = (tmp.path().join("plain"), tmp.path().join("lifted"));
    // A raised z range is accepted as written (a negative number, not a flag).
    let args = ["--z-min-mm", "-0.5", "--z-max-mm", "2.0"];
    let r = generate(&plain, 40, &args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let r = generate(&lifted, 40, &[&args[..], &["--lifted-fraction", "0.3"]].concat());
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (a, b) =
        (formats::dataset::Manifest::load(&plain).unwrap(), formats::dataset::Manifest::load(&lifted).unwrap());
    let mut lifted_count = 0;
    for (p, l) in a.samples.iter().zip(&b.samples) {
        assert_eq!((p.trial, p.split, p.scene.pose.b_axis_deg), (l.trial, l.split, l.scene.pose.b_axis_deg));
        let depth = sensor::DepthMap::load_png_um(&lifted.join(&l.depth)).unwrap();
        if l.scene.pose.z_travel_mm == formats::dataset::LIFTED_Z_TRAVEL_MM {
            lifted_count += 1;
            assert_eq!(l.stats.contact_fraction, 0.0, "sample {}", l.id);
            assert!(depth.depth_mm.iter().all(|&d| d == 0.0), "sample {}: a lifted rig presses", l.id);
        } else {
            assert_eq!(p.scene.pose.z_travel_mm, l.scene.pose.z_travel_mm);
            assert!(l.stats.contact_fraction > 0.0, "sample {}", l.id);
        }
    }
    assert!((5..=20).contains(&lifted_count), "{lifted_count} of 40 lifted at a 0.3 chance");
    let r = generate(&tmp.path().join("bad"), 3, &["--lifted-fraction", "1.5"]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("--lifted-fraction"));
}

#[test]
fn force_labels_follow_the_depth_maps_and_can_be_left_out() {
    let tmp = tempfile::tempdir().unwrap();
    let (with, without) = (tmp.path().join("with"), tmp.path().join("without"));
    let r = generate(&with, 16, &["--lifted-fraction", "0.25"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let manifest = formats::dataset::Manifest::load(&with).unwrap();
    let (mut pressed, mut lifted) = (0, 0);
    for s in &manifest.samples {
        let depth = sensor::DepthMap::load_png_um(&with.join(&s.depth)).unwrap();
        let pressure = sensor::PressureMap::load_png(&with.join(s.pressure.as_ref().expect("a pressure map"))).unwrap();
        let wrench = s.wrench.expect("a wrench");
        assert_eq!(pressure.size_px, depth.size_px);
        // Pressure only where the scene overlaps the dome; the force pushes into the sensor
        // and, without friction, passes through the dome's centre.
        assert!(
            pressure.pressure_kpa.iter().zip(&depth.depth_mm).all(|(&p, &d)| p == 0.0 || d > 0.0),
            "sample {}",
            s.id
        );
        let force = wrench.force_n.iter().map(|f| f * f).sum::<f64>().sqrt();
        let torque = wrench.torque_nmm.iter().map(|t| t * t).sum::<f64>().sqrt();
        assert!(torque <= 1e-6 * force.max(1.0) * 25.0, "sample {}: {wrench:?}", s.id);
        if s.stats.contact_fraction > 0.0 {
            pressed += 1;
            assert!(force > 0.0 && wrench.force_n[2] < 0.0, "sample {}: {wrench:?}", s.id);
            assert!(pressure.pressure_kpa.iter().any(|&p| p > 0.0), "sample {}", s.id);
        } else {
            lifted += 1;
            assert_eq!(force, 0.0, "sample {}", s.id);
            assert!(pressure.pressure_kpa.iter().all(|&p| p == 0.0), "sample {}", s.id);
        }
    }
    assert!(pressed > 0 && lifted > 0, "{pressed} pressed, {lifted} lifted");

    // Left out on request: the same scenes and depth maps, no pressure maps.
    let r = generate(&without, 16, &["--lifted-fraction", "0.25", "--no-force-labels"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let bare = formats::dataset::Manifest::load(&without).unwrap();
    assert!(!without.join("pressure").exists());
    for (a, b) in manifest.samples.iter().zip(&bare.samples) {
        assert!(b.pressure.is_none() && b.wrench.is_none());
        assert_eq!(std::fs::read(with.join(&a.depth)).unwrap(), std::fs::read(without.join(&b.depth)).unwrap());
    }
    // A folder made one way is not resumed the other.
    let r = generate(&without, 16, &["--lifted-fraction", "0.25"]);
    assert!(!r.status.success(), "resumed a folder without force labels as one with them");
}

/// A finished run resumes for any unit: the settings read back from `generator.json` equal the
/// unit's own to the last bit (unit 21's lens distortion once differed by one ulp after a JSON
/// round trip, and the resume was refused). Units 0..40 are checked in memory, unit 21 on disk.
#[test]
fn every_units_settings_survive_their_json_round_trip() {
    for seed in 0..40 {
        let unit = dataset::SensorUnit::from_seed(seed, 25.0);
        let back: dataset::SensorUnit = serde_json::from_str(&serde_json::to_string(&unit).unwrap()).unwrap();
        assert_eq!(back, unit, "unit {seed}");
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("d");
    for _ in 0..2 {
        let r = generate(&out, 2, &["--unit", "21"]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
}

/// Two generators into one folder (a resume started while the first still runs) would remove
/// each other's temporary files and interleave their work: the second is refused, by name,
/// while the first runs, and may go on once it has ended (killed, here).
#[test]
fn a_second_run_into_a_folder_being_written_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    let mut child =
        common::spawn_until(BIN, &["generate", "--out", a.to_str().unwrap(), "--count", "400", "--seed", "11"], &a, 2);
    let second = generate(&a, 400, &[]);
    let running = child.try_wait().unwrap().is_none();
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(running, "the first run ended before the second started");
    assert!(!second.status.success());
    let e = String::from_utf8_lossy(&second.stderr);
    assert!(e.contains(a.to_str().unwrap()) && e.contains("another process is writing a dataset"), "{e}");
    let after = generate(&a, 4, &[]);
    assert!(!after.status.success(), "a different count is refused for its settings, not the lock");
    assert!(String::from_utf8_lossy(&after.stderr).contains("other settings"));
}
