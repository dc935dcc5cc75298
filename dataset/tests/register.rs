//! Registration from the frames (`dataset label --register`): a simulated session pressed in z
//! sweeps, its frames obeying a rig's errors its log does not know, gives back those errors
//! from its frames alone, and labels that meet the true depth where the log's miss it.

use std::path::Path;

use dataset::label::LabelFile;
use dataset::register::Registration;
use dataset::rig::{Labels, RigOffsets, label_errors_mm};

use crate::common::{dataset, ok, refused};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn label(session: &Path, kit: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    let truth = session.join(".simulation/truth.json");
    let mut args = vec![
        "label",
        "--session",
        s(session),
        "--kit",
        kit,
        "--sensor",
        s(&truth),
        "--out",
        s(out),
        "--no-force-labels",
    ];
    args.extend(extra);
    dataset(&args)
}

/// A sweep session of `sweeps` sweeps (36 frames, 0.05 mm apart, from 1 mm above the logged
/// touch) with rig errors 9, labelled as logged and registered: the report without
/// `--register`, the registration, the truth, and the labels' depth error as logged and
/// registered (mm).
struct Registered {
    plain_report: String,
    registration: Registration,
    truth: RigOffsets,
    logged_error_mm: f64,
    registered_error_mm: f64,
}

impl Registered {
    /// The offsets matter to the labels, and the registered ones miss the truth by at most
    /// `factor` of what the log's miss it by.
    fn labels_beat_the_log(&self, factor: f64) {
        assert!(self.logged_error_mm > 0.05, "the offsets matter to the labels: {} mm", self.logged_error_mm);
        let (after, before) = (self.registered_error_mm, self.logged_error_mm);
        assert!(after <= factor * before, "registered {after} mm against {before} mm as logged");
    }
}

fn register_session(dir: &Path, kit: &str, sweeps: u32) -> Registered {
    let session = dir.join("s");
    let count = (36 * sweeps).to_string();
    let mut args = vec![
        "generate",
        "--session",
        s(&session),
        "--unit",
        "2",
        "--seed",
        "4",
        "--rig-errors",
        "9",
        "--count",
        &count,
        "--sweep-frames",
        "36",
        "--sweep-step-mm",
        "0.05",
    ];
    if kit != "procedural" {
        args.extend(["--kit", kit]);
    }
    ok(dataset(&args));
    let truth: RigOffsets = formats::read_json(&session.join(".simulation/rig.json")).unwrap();
    let kit_name = kit;
    let kit = dataset::Kit::open(kit, 1.0, 25.0, "kit").unwrap();
    let (logged, registered) = (dir.join("logged"), dir.join("registered"));
    let plain_report = ok(label(&session, kit_name, &logged, &[]));
    let file: LabelFile = formats::read_json(&logged.join("label.json")).unwrap();
    assert!(file.registration.is_none(), "nothing applied, nothing recorded");
    let report = ok(label(&session, kit_name, &registered, &["--register"]));
    assert!(report.contains("applied to the labels (--register)"), "{report}");
    let file: LabelFile = formats::read_json(&registered.join("label.json")).unwrap();
    let registration = file.registration.expect("label.json records the offsets applied");
    // The labels an offset set gives, cast rather than read: the truth's are the truth, and the
    // registration's are its labels (to the labels' 1 um steps).
    let labels = [
        Labels::Written(&logged),
        Labels::Written(&registered),
        Labels::Cast(&truth),
        Labels::Cast(&registration.offsets),
    ];
    let errors: [(f64, usize); 4] =
        label_errors_mm(&session, &registered, &kit, &truth, &labels).unwrap().try_into().unwrap();
    let [logged_error_mm, registered_error_mm, truth_error_mm, cast_error_mm] = errors.map(|(mm, _)| mm);
    assert_eq!(truth_error_mm, 0.0);
    assert!(
        (cast_error_mm - registered_error_mm).abs() < 1e-3,
        "cast {cast_error_mm} mm, labelled {registered_error_mm} mm"
    );
    eprintln!(
        "recovered {:?}\nsd {:?}\nleft out {:?}\nlabel depth error against the truth: {registered_error_mm:.4} mm \
         registered, {logged_error_mm:.4} mm as logged",
        registration.offsets, registration.sd, registration.left_out
    );
    Registered { plain_report, registration, truth, logged_error_mm, registered_error_mm }
}

/// The embedded kit: the report warns about what the frames show, and the registered labels
/// are closer to the truth than the log's; a wrong line in the log is left out without harm.
#[test]
fn registered_labels_of_the_embedded_kit_beat_the_logs() {
    let tmp = tempfile::tempdir().unwrap();
    let r = register_session(tmp.path(), "procedural", 14);
    assert!(r.plain_report.contains("z sweeps, NOT applied"), "{}", r.plain_report);
    assert!(r.plain_report.contains("warning: the frames say the log's poses are off"), "{}", r.plain_report);
    r.labels_beat_the_log(0.5);

    // A wrong line in the log: the first sweep's tilt written as 85 degrees (the cast touches
    // elsewhere) or -89 (it never touches). The sweep is named and left out, and it does not
    // drag the others' estimate away (85 did: x 1.08 mm against 0.49, before sweeps were judged
    // against the others' fit).
    let session = tmp.path().join("s");
    let log = session.join("captures.csv");
    let text = std::fs::read_to_string(&log).unwrap();
    for (tilt_deg, why) in [("85", "disagrees with the other sweeps"), ("-89", "the ray cast finds no first touch")] {
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let a = lines[0].split(',').position(|c| c == "a_deg").expect("the log has a tilt column");
        for line in &mut lines[1..=36] {
            let mut cells: Vec<&str> = line.split(',').collect();
            cells[a] = tilt_deg;
            *line = cells.join(",");
        }
        std::fs::write(&log, lines.join("\n") + "\n").unwrap();
        let wrong = tmp.path().join(format!("wrong{tilt_deg}"));
        ok(label(&session, "procedural", &wrong, &["--register"]));
        let file: LabelFile = formats::read_json(&wrong.join("label.json")).unwrap();
        let registration = file.registration.expect("the other sweeps register");
        let named = |w: &String| w.starts_with("line 2 (") && w.contains(why);
        assert!(registration.left_out.iter().any(named), "{tilt_deg}: {:?}", registration.left_out);
        let (o, truth) = (&registration.offsets, &r.truth);
        assert!((o.x_mm - truth.x_mm).abs() <= 0.1, "{tilt_deg}: x {} against {}", o.x_mm, truth.x_mm);
        assert!((o.y_mm - truth.y_mm).abs() <= 0.1, "{tilt_deg}: y {} against {}", o.y_mm, truth.y_mm);
    }
}

/// The authors' kit: every offset within three of its stated standard deviations, or twice the
/// issue's goal where the sweeps pin it closer, and labels well closer to the truth than the
/// log's.
#[test]
#[ignore = "needs ../shared"]
fn sweeps_of_the_authors_kit_give_back_the_rigs_offsets() {
    let tmp = tempfile::tempdir().unwrap();
    let kit = sensor::shared::shared_dir("DENSETACT_KIT", "densetact-kit");
    let r = register_session(tmp.path(), kit.to_str().unwrap(), 24);
    let (o, sd, truth) = (&r.registration.offsets, &r.registration.sd, &r.truth);
    let near = |what: &str, got: f32, truth: f32, sd: f32, goal: f32| {
        assert!((got - truth).abs() <= (3.0 * sd).max(2.0 * goal), "{what}: {got} +- {sd} against {truth}");
    };
    near("x", o.x_mm, truth.x_mm, sd.x_mm, 0.1);
    near("y", o.y_mm, truth.y_mm, sd.y_mm, 0.1);
    near("tilt about x", o.tilt_x_deg, truth.tilt_x_deg, sd.tilt_x_deg, 0.2);
    near("tilt about y", o.tilt_y_deg, truth.tilt_y_deg, sd.tilt_y_deg, 0.2);
    near("B zero", o.b_zero_deg, truth.b_zero_deg, sd.b_zero_deg, 0.2);
    assert!(r.registration.sweeps >= 18, "most sweeps used: {:?}", r.registration.left_out);
    for (t, z) in &o.z_zero_by_trial_mm {
        near(t, *z, truth.z_zero_by_trial_mm[t], sd.z_zero_by_trial_mm[t], 0.03);
    }
    // The trials of sweeps left out keep the log's zero, so the whole is not yet the goal's 0.02 mm.
    r.labels_beat_the_log(0.4);
}

#[test]
fn register_without_sweeps_or_with_another_z_is_refused_naming_the_log() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("s");
    ok(dataset(&["generate", "--session", s(&session), "--unit", "2", "--count", "6"]));
    let out = tmp.path().join("l");
    let report = ok(label(&session, "procedural", &out, &[]));
    assert!(report.contains("rig offsets not checked: the log has no z sweeps"), "{report}");
    let err = refused(label(&session, "procedural", &tmp.path().join("r"), &["--register"]));
    assert!(err.contains("captures.csv") && err.contains("--register needs z sweeps"), "{err}");
    // A log whose z counts from elsewhere is not registered: its convention is not a rig's zero.
    let first_touch = ["--register", "--z-from", "first-touch"];
    let err = refused(label(&session, "procedural", &tmp.path().join("f"), &first_touch));
    assert!(err.contains("captures.csv") && err.contains("--register reads the log's z as travel"), "{err}");
}
