//! Capture sessions end to end: a simulated session labelled with the unit's true sensor gives
//! the generator's depth maps bit for bit, and with a calibrated sensor agrees within the
//! calibration's error; every bad row is named with its line; a killed labelling resumes to the
//! same dataset.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use formats::dataset::Manifest;
use sensor::DepthMap;

use crate::common;
use common::{dataset, files, ok};

const BIN: &str = env!("CARGO_BIN_EXE_dataset");

/// The folders whose files make up a dataset here.
const DATASET_FILES: [&str; 6] = ["", "samples", "depth", "images", "unit", "pressure"];

fn strings(args: &[&str]) -> Vec<String> {
    common::kill::strings(args)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The same draws as a session and as a dataset: unit 5, tilts on the A and C axes.
const DRAWS: [&str; 10] = ["--count", "16", "--seed", "3", "--unit", "5", "--a-deg", "0,30", "--c-deg", "-20..20"];

fn simulated_session(dir: &Path, extra: &[&str]) {
    let mut args = vec!["generate", "--session", s(dir)];
    args.extend(DRAWS);
    args.extend(extra);
    ok(dataset(&args));
}

fn truth(session: &Path) -> PathBuf {
    session.join(".simulation/truth.json")
}

fn label(session: &Path, sensor: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["label", "--session", s(session), "--sensor", s(sensor), "--out", s(out)];
    args.extend(extra);
    dataset(&args)
}

#[test]
fn a_session_labelled_with_the_true_sensor_is_the_generators_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let (session, generated, labelled) = (tmp.path().join("s"), tmp.path().join("g"), tmp.path().join("l"));
    simulated_session(&session, &[]);
    for f in ["captures.csv", "reference.png", "sawtooth.png", "frames/000000.png", "frames/000015.png"] {
        assert!(session.join(f).is_file(), "the session has {f}");
    }
    let frame = image::open(session.join("frames/000003.png")).unwrap();
    assert_eq!((frame.width(), frame.height()), (800, 600), "frames are the camera's full frame");
    let mut args = vec!["generate", "--out", s(&generated)];
    args.extend(DRAWS);
    ok(dataset(&args));
    // The force labels with the unit's own silicone, which a lab would have measured.
    let unit: dataset::SensorUnit =
        serde_json::from_slice(&std::fs::read(generated.join("unit/unit.json")).unwrap()).unwrap();
    let (modulus, poisson) = (unit.elastomer.youngs_modulus_mpa.to_string(), unit.elastomer.poisson_ratio.to_string());
    let material = ["--youngs-modulus-mpa", modulus.as_str(), "--poisson-ratio", poisson.as_str()];
    let report = ok(label(&session, &truth(&session), &labelled, &material));
    assert!(report.contains("samples/s"), "{report}");

    let (g, l) = (Manifest::load(&generated).unwrap(), Manifest::load(&labelled).unwrap());
    assert_eq!(g.samples.len(), l.samples.len());
    let mut tilted = 0;
    for (a, b) in g.samples.iter().zip(&l.samples) {
        assert_eq!((a.id, a.split, a.trial), (b.id, b.split, b.trial));
        assert_eq!(a.scene, b.scene, "sample {}: the logged pose round-trips", a.id);
        let bytes = |dir: &Path, rel: &str| std::fs::read(dir.join(rel)).unwrap();
        assert!(bytes(&generated, &a.depth) == bytes(&labelled, &b.depth), "sample {}: depth differs", a.id);
        let pressure = |r: &formats::dataset::SampleRecord| r.pressure.clone().expect("force labels by default");
        assert!(bytes(&generated, &pressure(a)) == bytes(&labelled, &pressure(b)), "sample {}: pressure differs", a.id);
        assert_eq!(a.wrench, b.wrench, "sample {}", a.id);
        assert_eq!(b.capture.as_ref().unwrap().line, b.id as usize + 2);
        tilted += (a.scene.pose.a_axis_deg != 0.0 || a.scene.pose.c_axis_deg != 0.0) as usize;
    }
    assert!(tilted > 8, "the draws exercise the A and C axes ({tilted} tilted)");
    assert!(l.generator.is_none() && l.labelled.is_some());
    assert!(labelled.join("unit/reference.png").is_file());
}

#[test]
fn a_calibrated_sensor_labels_within_the_calibrations_error() {
    let tmp = tempfile::tempdir().unwrap();
    let (session, exact, calibrated) = (tmp.path().join("s"), tmp.path().join("t"), tmp.path().join("c"));
    simulated_session(&session, &["--jpeg-quality", "90"]);
    assert!(session.join("frames/000000.jpg").is_file());
    let sensor = tmp.path().join("sensor.json");
    let out = ok(dataset(&[
        "calibrate",
        "--image",
        s(&session.join("sawtooth.png")),
        "--out",
        s(&sensor),
        "--truth",
        s(&truth(&session)),
    ]));
    ok(label(&session, &truth(&session), &exact, &[]));
    ok(label(&session, &sensor, &calibrated, &[]));
    let rms_px: f64 =
        out.lines().last().unwrap().split_whitespace().next().unwrap()["rms_px=".len()..].parse().unwrap();
    // Over the useful pixels of both, the mean depth difference, frame by frame.
    let (t, c) = (Manifest::load(&exact).unwrap(), Manifest::load(&calibrated).unwrap());
    let mask = t.sensor.valid_mask();
    // The two crops may start a pixel apart in the frame: compare frame pixel with frame pixel.
    let ((tx, ty), (cx, cy)) = (t.sensor.crop_origin_px(), c.sensor.crop_origin_px());
    let n = t.sensor.crop_size_px as i64;
    let mut worst = 0f64;
    for (a, b) in t.samples.iter().zip(&c.samples) {
        let (da, db) = (
            DepthMap::load_png_um(&exact.join(&a.depth)).unwrap(),
            DepthMap::load_png_um(&calibrated.join(&b.depth)).unwrap(),
        );
        let (mut sum, mut count) = (0f64, 0usize);
        for y in 0..n {
            for x in 0..n {
                let (xc, yc) = (x + tx - cx, y + ty - cy);
                if !mask[(y * n + x) as usize] || !(0..n).contains(&xc) || !(0..n).contains(&yc) {
                    continue;
                }
                sum += (da.depth_mm[(y * n + x) as usize] - db.depth_mm[(yc * n + xc) as usize]).abs() as f64;
                count += 1;
            }
        }
        worst = worst.max(sum / count as f64);
    }
    eprintln!("calibration rms {rms_px:.3} px; worst frame's mean depth difference {worst:.4} mm");
    // Measured (unit 5, JPEG session): calibration 0.088 px rms, the worst frame's labels
    // 0.0007 mm apart on average. The bound leaves room for units that calibrate less well
    // (the goal is 0.5 px), not for a shifted crop or a wrong correspondence (tenths of a mm).
    assert!(rms_px < 0.5, "calibration {rms_px} px");
    assert!(worst < 0.005, "labels with the calibrated sensor differ by {worst} mm on average in one frame");
}

/// Rewrites line `n` (1-based) of the session's log through `edit`.
fn edit_line(session: &Path, n: usize, edit: impl Fn(&str) -> String) {
    let path = session.join("captures.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<String> =
        text.lines().enumerate().map(|(k, l)| if k + 1 == n { edit(l) } else { l.to_string() }).collect();
    std::fs::write(&path, lines.join("\n") + "\n").unwrap();
}

fn field(line: &str, k: usize, value: &str) -> String {
    let mut f: Vec<String> = line.split(',').map(String::from).collect();
    f[k] = value.to_string();
    f.join(",")
}

#[test]
fn every_bad_row_is_named_with_its_line_and_skip_leaves_it_out() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    simulated_session(&session, &[]);
    let frame = |id: u32| session.join(format!("frames/{id:06}.png"));
    // Line k + 2 holds frame k.
    std::fs::remove_file(frame(0)).unwrap(); // line 2: missing
    std::fs::write(frame(1), b"\x89PNG\r\n\x1a\ngarbage").unwrap(); // line 3: unreadable
    let full = image::open(frame(2)).unwrap().to_rgb8();
    image::imageops::crop_imm(&full, 80, 60, 640, 480).to_image().save(frame(2)).unwrap(); // line 4: wrong size
    edit_line(&session, 5, |l| field(l, 2, "999")); // trial not in the index
    edit_line(&session, 6, |l| field(l, 6, "30")); // z beyond the depth range
    edit_line(&session, 7, |l| field(l, 3, "135")); // tilt beyond the rig's
    edit_line(&session, 8, |l| field(l, 0, "frames/000003.png")); // frame 3 twice
    let grey = image::open(frame(7)).unwrap().to_luma8();
    grey.save(frame(7)).unwrap(); // line 9: greyscale
    let mut bgr = image::open(frame(8)).unwrap().to_rgb8();
    bgr.pixels_mut().for_each(|p| p.0.swap(0, 2));
    bgr.save(frame(8)).unwrap(); // line 10: BGR
    let cases = [
        (2, "000000.png"),
        (3, "not a readable"),
        (4, "640x480"),
        (5, "trial 999"),
        (6, "z_mm"),
        (7, "a_deg"),
        (8, "already listed on line 5"),
        (9, "greyscale"),
        (10, "BGR"),
    ];
    let sensor = truth(&session);
    // Stop (the default): the run ends on a bad row, naming it; fixing rows one by one, every
    // case is met in turn would take long, so each message is checked in the skip report.
    let stopped = label(&session, &sensor, &tmp.path().join("stop"), &[]);
    assert!(!stopped.status.success());
    let e = String::from_utf8_lossy(&stopped.stderr);
    assert!(e.contains("captures.csv: line") && e.contains("--on-bad-row skip"), "{e}");
    let out = tmp.path().join("skip");
    let report = ok(label(&session, &sensor, &out, &["--on-bad-row", "skip"]));
    assert!(report.contains("9 rows skipped"), "{report}");
    for (line, words) in cases {
        let row = report
            .lines()
            .find(|l| l.contains(&format!("line {line}:")))
            .unwrap_or_else(|| panic!("line {line}: {report}"));
        assert!(row.contains(words), "line {line} should say {words:?}: {row}");
    }
    let manifest = Manifest::load(&out).unwrap();
    assert_eq!(manifest.samples.len(), 16 - 9);
}

#[test]
fn a_labelling_killed_at_any_moment_resumes_to_the_same_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    let mut args = vec!["generate", "--session", s(&session), "--count", "120", "--seed", "4", "--unit", "2"];
    args.extend(["--lifted-fraction", "0.1"]);
    ok(dataset(&args));
    let sensor = truth(&session);
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    // Kill anywhere, edit nothing, resume = uninterrupted: six kills -9 at seeded moments.
    let args = |out: &Path| strings(&["label", "--session", s(&session), "--sensor", s(&sensor), "--out", s(out)]);
    let span = common::kill::timed_run(BIN, &args(&a));
    let kills = common::kill::kill_anywhere(BIN, &args(&b), &args(&b), 6, span, 8);
    assert!(kills.mid_run >= 1, "no kill landed mid-run: {kills:?}");
    common::assert_same_files(&a, &b, &format!("a labelling after the kills {kills:?}"));
    std::fs::remove_file(b.join("manifest.json")).unwrap(); // as a kill before the end leaves it
    let report = ok(label(&session, &sensor, &b, &[]));
    assert!(report.contains("(0 new, 120 from an earlier run)"), "{report}");
    // Lifted frames: no contact in the ground truth, and none in the image either.
    assert!(report.contains("have no contact"), "{report}");
    assert!(!report.contains("logging slip"), "{report}");
    // Another sensor into the same folder is refused, naming the setting.
    let other = tmp.path().join("other.json");
    let mut moved: sensor::Sensor = formats::read_json(&sensor).unwrap();
    moved.correspondence.centre_u_px += 1.0;
    formats::write_json(&other, &moved).unwrap();
    let r = label(&session, &other, &b, &[]);
    assert!(!r.status.success());
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(e.contains("label.json") && e.contains("centre_u_px"), "{e}");
}

/// Kill anywhere, edit nothing, resume = uninterrupted, for a simulated session; and a frame
/// edited since the earlier run is made again.
#[test]
fn a_simulated_session_killed_anywhere_resumes_to_the_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let args = |out: &Path| strings(&["generate", "--session", s(out), "--count", "60", "--seed", "5", "--unit", "3"]);
    let span = common::kill::timed_run(BIN, &args(&a));
    let kills = common::kill::kill_anywhere(BIN, &args(&b), &args(&b), 6, span, 12);
    assert!(kills.mid_run >= 1, "no kill landed mid-run: {kills:?}");
    common::assert_same_files(&a, &b, &format!("a session after the kills {kills:?}"));
    // A frame replaced by another, and the log gone as a kill before the end leaves it.
    std::fs::copy(b.join("frames/000009.png"), b.join("frames/000004.png")).unwrap();
    std::fs::remove_file(b.join(formats::session::CAPTURES_CSV)).unwrap();
    let r = dataset(&args(&b).iter().map(String::as_str).collect::<Vec<_>>());
    let e = String::from_utf8_lossy(&r.stderr).into_owned();
    ok(r);
    assert!(e.contains("1 frames changed"), "{e}");
    common::assert_same_files(&a, &b, "a session whose frame was replaced, resumed");
}

/// A rig's errors (`--rig-errors`) move the frames, not the log: the log is the error-free
/// session's, the frames are filmed at the true poses in the offset mount, and labels made from
/// the log miss the true depth by what registration has to remove.
#[test]
fn a_rigs_errors_move_the_frames_not_the_log() {
    let tmp = tempfile::tempdir().unwrap();
    let (clean, off) = (tmp.path().join("clean"), tmp.path().join("off"));
    fn args(dir: &Path) -> Vec<&str> {
        vec!["generate", "--session", s(dir), "--count", "12", "--seed", "6", "--unit", "2"]
    }
    ok(dataset(&args(&clean)));
    ok(dataset(&[args(&off), vec!["--rig-errors", "7"]].concat()));
    let log = |dir: &Path| std::fs::read(dir.join(formats::session::CAPTURES_CSV)).unwrap();
    assert_eq!(log(&clean), log(&off), "the log says the same");
    let rig: dataset::rig::RigOffsets = formats::read_json(&off.join(".simulation/rig.json")).unwrap();
    let kit = dataset::Kit::procedural(25.0);
    assert_eq!(rig, dataset::rig::RigOffsets::draw(7, &kit));
    let none: dataset::rig::RigOffsets = formats::read_json(&clean.join(".simulation/rig.json")).unwrap();
    assert!(none.is_zero());
    let rows = formats::session::CaptureLog::read(&off).unwrap().rows;
    let differ = rows
        .iter()
        .filter(|r| std::fs::read(clean.join(&r.frame)).unwrap() != std::fs::read(off.join(&r.frame)).unwrap());
    assert!(differ.count() >= rows.len() / 2, "the frames obey the offsets");

    // Labels come from the log: those of the two sessions are the same depth maps, and miss the
    // true depth of the offset session's frames.
    let sensor = truth(&off);
    let (a, b) = (tmp.path().join("la"), tmp.path().join("lb"));
    ok(label(&clean, &truth(&clean), &a, &[]));
    ok(label(&off, &sensor, &b, &[]));
    assert!(files(&a, &["depth"]) == files(&b, &["depth"]));
    let (error_mm, pixels) = dataset::rig::label_error_mm(&off, &b, &kit, &rig).unwrap();
    eprintln!("unregistered labels against the truth: {error_mm:.4} mm over {pixels} contact pixels");
    assert!(error_mm > 0.05, "the offsets must matter to the labels: {error_mm} mm");
}

/// A log's z read as it was written: the same session logged from first touch, or in machine
/// coordinates (one zero for all, or a zero per row), labels to the seated log's depth maps, and
/// the report says which reading it assumed.
#[test]
fn logs_counting_z_from_first_touch_or_a_machine_zero_label_alike() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    ok(dataset(&["generate", "--session", s(&session), "--count", "8", "--seed", "8", "--unit", "2"]));
    let sensor = truth(&session);
    let seated_dir = tmp.path().join("seated");
    let report = ok(label(&session, &sensor, &seated_dir, &[]));
    assert!(report.contains("seated pose"), "{report}");
    let depths = |dir: &Path| -> Vec<Vec<f32>> {
        let m = Manifest::load(dir).unwrap();
        m.samples
            .iter()
            .map(|x| {
                DepthMap::decode_png_um(&dir.join(&x.depth), &std::fs::read(dir.join(&x.depth)).unwrap())
                    .unwrap()
                    .depth_mm
            })
            .collect()
    };
    let seated = depths(&seated_dir);
    let original = formats::session::CaptureLog::read(&session).unwrap().rows;
    // Each row's new z, and its machine zero if the row gives one.
    type Rewrite<'a> = &'a dyn Fn(usize, &formats::session::Capture) -> (f32, Option<f32>);
    let rewrite = |z: Rewrite| {
        let rows: Vec<_> = original
            .iter()
            .enumerate()
            .map(|(k, r)| {
                let (z_mm, zero) = z(k, r);
                let mut row =
                    formats::session::Capture { pose: dataset::RigPose { z_travel_mm: z_mm, ..r.pose }, ..r.clone() };
                if let Some(zero) = zero {
                    row.extra.insert("z_zero_mm".into(), zero.to_string());
                }
                row
            })
            .collect();
        std::fs::write(session.join(formats::session::CAPTURES_CSV), formats::session::CaptureLog::to_csv(&rows))
            .unwrap();
    };
    let alike = |dir: &Path, tolerance_mm: f32| {
        for (k, (a, b)) in seated.iter().zip(depths(dir)).enumerate() {
            let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
            assert!(worst <= tolerance_mm, "{}: sample {k} differs by {worst} mm", dir.display());
        }
    };
    // A machine coordinate: one zero for all, then a zero per row.
    rewrite(&|_, r| (r.pose.z_travel_mm + 8.0, None));
    let machine = tmp.path().join("machine");
    let report = ok(label(&session, &sensor, &machine, &["--z-from", "machine", "--z-zero-mm", "8"]));
    assert!(report.contains("machine coordinate") && report.contains("z - 8 mm"), "{report}");
    alike(&machine, 0.0011);
    rewrite(&|k, r| {
        let zero = if k % 2 == 0 { 5.0 } else { 8.0 };
        (r.pose.z_travel_mm + zero, Some(zero))
    });
    let per_row = tmp.path().join("per-row");
    ok(label(&session, &sensor, &per_row, &["--z-from", "machine"]));
    alike(&per_row, 0.0011);
    // From first touch, as the geometry puts it for each row.
    let kit = dataset::Kit::procedural(25.0);
    let unit: sensor::Sensor = formats::read_json(&sensor).unwrap();
    let rays = dataset::RayBundle::new(&unit);
    let touch: Vec<f32> = original
        .iter()
        .map(|r| {
            let trial = kit.trial(r.split, r.trial).unwrap();
            dataset::touch::first_touch_mm(&kit, trial, r.pose, &unit, &rays).unwrap()
        })
        .collect();
    rewrite(&|k, r| (r.pose.z_travel_mm - touch[k], None));
    let first_touch = tmp.path().join("first-touch");
    let report = ok(label(&session, &sensor, &first_touch, &["--z-from", "first-touch"]));
    assert!(report.contains("from first touch"), "{report}");
    alike(&first_touch, 0.0011);
    // A machine coordinate without its zero is refused before any work, saying what it needs.
    rewrite(&|_, r| (r.pose.z_travel_mm, None));
    let r = label(&session, &sensor, &tmp.path().join("no-zero"), &["--z-from", "machine"]);
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && e.contains("captures.csv") && e.contains("--z-zero-mm"), "{e}");
}

#[test]
fn a_logging_slip_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    ok(dataset(&[
        "generate",
        "--session",
        s(&session),
        "--count",
        "12",
        "--seed",
        "9",
        "--unit",
        "1",
        "--lifted-fraction",
        "0.5",
    ]));
    let log = formats::session::CaptureLog::read(&session).unwrap();
    let lifted: Vec<_> = log.rows.iter().filter(|r| r.pose.z_travel_mm < -10.0).collect();
    let pressed = log.rows.iter().find(|r| r.pose.z_travel_mm > 1.0).unwrap();
    let slip = lifted.first().expect("some frames are lifted");
    // The log says lifted, but the frame shows a press.
    std::fs::copy(session.join(&pressed.frame), session.join(&slip.frame)).unwrap();
    let report = ok(label(&session, &truth(&session), &tmp.path().join("l"), &[]));
    assert!(report.contains(&format!("line {}", slip.line)) && report.contains("logging slip"), "{report}");
}

/// A failing write (here an injected full disk) is an I/O error that stops the labelling, with
/// the path and the OS's reason, even with `--on-bad-row skip`: never a bad row to leave out.
#[test]
fn a_full_disk_stops_the_labelling_whatever_on_bad_row_says() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    simulated_session(&session, &[]);
    let out = tmp.path().join("out");
    for extra in [&[][..], &["--on-bad-row", "skip"][..]] {
        let r = Command::new(BIN)
            .args(["label", "--session", s(&session), "--sensor", s(&truth(&session)), "--out", s(&out)])
            .args(extra)
            .env(formats::fs::FAIL_WRITES_ENV, "depth/000003")
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{extra:?}: exit 0 on a full disk: {e}");
        assert!(e.contains("000003.png") && e.contains("No space left"), "{extra:?}: {e}");
        assert!(!e.contains("--on-bad-row") && !e.contains("skipped"), "{extra:?}: reported as a bad row: {e}");
        assert!(!out.join("manifest.json").exists(), "{extra:?}: a dataset written as complete");
    }
    // With the disk back, the same command finishes what was started.
    ok(label(&session, &truth(&session), &out, &[]));
    assert_eq!(Manifest::load(&out).unwrap().samples.len(), 16);
}

/// A resumed labelling checks what it resumes: a row edited or a frame replaced since the
/// earlier run is labelled again, so the result is what a fresh labelling of the session as it
/// now stands gives.
#[test]
fn a_resumed_labelling_relabels_rows_and_frames_that_changed() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    simulated_session(&session, &[]);
    let sensor = truth(&session);
    let (resumed, fresh) = (tmp.path().join("resumed"), tmp.path().join("fresh"));
    ok(label(&session, &sensor, &resumed, &[]));
    let before = Manifest::load(&resumed).unwrap().samples[2].scene.pose.z_travel_mm;
    // Line 4's z raised by 0.5 mm; frame 6 (line 8) replaced by frame 9's picture.
    edit_line(&session, 4, |l| {
        let z: f64 = l.split(',').nth(6).unwrap().parse().unwrap();
        field(l, 6, &format!("{}", z + 0.5))
    });
    std::fs::copy(session.join("frames/000009.png"), session.join("frames/000006.png")).unwrap();
    std::fs::remove_file(resumed.join("manifest.json")).unwrap(); // as a kill before the end leaves it
    let report = ok(label(&session, &sensor, &resumed, &[]));
    assert!(report.contains("2 rows changed") && report.contains("lines 4, 8"), "{report}");
    ok(label(&session, &sensor, &fresh, &[]));
    assert!(
        files(&resumed, &DATASET_FILES) == files(&fresh, &DATASET_FILES),
        "the resumed labelling is the fresh one of the edited session"
    );
    let after = Manifest::load(&resumed).unwrap().samples[2].scene.pose.z_travel_mm;
    assert!((after - before - 0.5).abs() < 1e-4, "line 4's z: {before} then {after}");

    // Rows removed (line 10, whose row goes to the end, and the last line): the rows below
    // move up, and the log is a row shorter. The resumed folder is again the fresh labelling of
    // the log as it stands, with nothing left of the sample the log no longer has.
    let text = std::fs::read_to_string(session.join(formats::session::CAPTURES_CSV)).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    let moved = lines.remove(9);
    lines.pop();
    lines.push(moved);
    std::fs::write(session.join(formats::session::CAPTURES_CSV), lines.join("\n") + "\n").unwrap();
    std::fs::remove_file(resumed.join("manifest.json")).unwrap();
    let report = ok(label(&session, &sensor, &resumed, &[]));
    assert!(report.contains("15 samples") && report.contains("rows changed"), "{report}");
    let fresh = tmp.path().join("fresh2");
    ok(label(&session, &sensor, &fresh, &[]));
    common::assert_same_files(&resumed, &fresh, "a log with a row removed and one changed, resumed");
}

/// A log with a force-torque sensor's columns: `label` keeps each row's measured wrench in its
/// sample's record, and that is the wrench the sample's force is trained and scored against;
/// rows whose cells are empty keep the labelled one.
#[test]
fn measured_wrenches_in_the_log_travel_to_the_samples() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    simulated_session(&session, &[]);
    let (plain, measured) = (tmp.path().join("plain"), tmp.path().join("measured"));
    ok(label(&session, &truth(&session), &plain, &[]));
    let labelled = Manifest::load(&plain).unwrap();
    // A "sensor" reading 10 % above the model's force on every other row.
    let mut log = formats::session::CaptureLog::read(&session).unwrap();
    for row in &mut log.rows {
        let sample = labelled.samples.iter().find(|s| s.capture.as_ref().unwrap().line == row.line).unwrap();
        let w = sample.wrench.unwrap();
        row.measured = (row.line % 2 == 0)
            .then(|| formats::dataset::Wrench { force_n: w.force_n.map(|f| f * 1.1), torque_nmm: [0.5, -0.5, 0.0] });
    }
    let csv = formats::session::CaptureLog::to_csv(&log.rows);
    assert!(csv.lines().next().unwrap().contains("fx_n,fy_n,fz_n,tx_nmm,ty_nmm,tz_nmm"));
    std::fs::write(session.join(formats::session::CAPTURES_CSV), csv).unwrap();
    ok(label(&session, &truth(&session), &measured, &[]));
    let (a, b) = (labelled.samples, Manifest::load(&measured).unwrap().samples);
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(&b) {
        let line = b.capture.as_ref().unwrap().line;
        assert_eq!(a.wrench, b.wrench, "the labelled wrench stays");
        match b.measured_wrench() {
            Some(m) => {
                assert!(line % 2 == 0);
                for (m, l) in m.force_n.iter().zip(a.wrench.unwrap().force_n) {
                    assert!((m - 1.1 * l).abs() <= 1e-6 * l.abs().max(1.0), "line {line}: {m} against {l}");
                }
                assert_eq!(b.force_label(), Some(m));
            }
            None => {
                assert!(line % 2 == 1, "line {line} lost its measurement");
                assert_eq!(b.force_label(), b.wrench.as_ref());
            }
        }
    }
}
