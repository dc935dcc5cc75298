//! Bad kits, bad travel and outputs onto inputs are refused with the file and the fix.

use std::path::Path;
use std::process::Output;

use dataset::Mesh;
use dataset::procedural::ProceduralKit;
use glam::Vec3;

use crate::common;
use common::{dataset, refused};

/// A kit folder in the authors' layout holding one procedural indicator and indenter, written
/// with `to_file` turning each sensor-frame point into the file's coordinates.
fn kit(dir: &Path, to_file: impl Fn(Vec3) -> Vec3) {
    let parts = ProceduralKit::new(25.0);
    std::fs::create_dir_all(dir.join("stl/indicators")).unwrap();
    std::fs::create_dir_all(dir.join("stl/indenters")).unwrap();
    let write = |mesh: &Mesh, path: &str| {
        let mut m = mesh.clone();
        m.vertices.iter_mut().for_each(|v| *v = to_file(*v));
        std::fs::write(dir.join(path), m.to_binary_stl()).unwrap();
    };
    write(&parts.indicators[0].mesh, "stl/indicators/3Dindicator_ver41.STL");
    write(&parts.indenters[0].mesh, "stl/indenters/indent_ver37.STL");
    let index = "Trial,Indicator,first,angle,second,angle\n1,41,37,0,,\n";
    std::fs::write(dir.join("Index_training.csv"), index).unwrap();
    std::fs::write(dir.join("Index_test.csv"), index).unwrap();
}

/// The sensor frame's point in a Y-up file: the inverse of `UpAxis::Y`'s `(x, -z, y)`.
fn y_up(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.z, -v.y)
}

fn generate_from(kit_dir: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["generate", "--kit", kit_dir.to_str().unwrap(), "--out", out.to_str().unwrap(), "--count", "2"];
    args.extend(extra);
    dataset(&args)
}

#[test]
fn a_kit_in_inches_or_turned_z_up_is_refused_with_the_fix() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good");
    kit(&good, y_up);
    let r = generate_from(&good, &tmp.path().join("a"), &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));

    let inches = tmp.path().join("inches");
    kit(&inches, |v| y_up(v) / 25.4);
    let e = refused(generate_from(&inches, &tmp.path().join("b"), &[]));
    assert!(e.contains("3Dindicator_ver41.STL") && e.contains("inches") && e.contains("--kit-scale 25.4"), "{e}");
    // The scale it suggests works.
    let r = generate_from(&inches, &tmp.path().join("c"), &["--kit-scale", "25.4"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));

    let z_up = tmp.path().join("z-up");
    kit(&z_up, |v| v);
    let e = refused(generate_from(&z_up, &tmp.path().join("d"), &[]));
    assert!(e.contains("3Dindicator_ver41.STL") && e.contains("+Z axis, not +Y") && e.contains("Y-up"), "{e}");
}

#[test]
fn travel_that_clips_most_contact_is_refused_with_the_figure() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("d");
    let e = refused(dataset(&["generate", "--out", out.to_str().unwrap(), "--count", "2", "--z-max-mm", "50"]));
    assert!(e.contains("with --z-max-mm 50") && e.contains("% of the contact pixels") && e.contains("9.4 mm"), "{e}");
    assert!(!out.exists(), "nothing is written");
}

#[test]
fn outputs_onto_inputs_or_foreign_folders_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let cal = tmp.path().join("cal");
    let r = dataset(&["sawtooth", "--unit", "3", "--out", cal.to_str().unwrap()]);
    assert!(r.status.success());
    let image = cal.join("sawtooth.png");
    let before = std::fs::read(&image).unwrap();
    let e = refused(dataset(&["calibrate", "--image", image.to_str().unwrap(), "--out", image.to_str().unwrap()]));
    assert!(e.contains("is also an input"), "{e}");
    assert_eq!(std::fs::read(&image).unwrap(), before);

    // A folder of the user's files is not turned into a dataset.
    let mine = tmp.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("thesis.tex"), b"years").unwrap();
    let e = refused(dataset(&["generate", "--out", mine.to_str().unwrap(), "--count", "2"]));
    assert!(e.contains("thesis.tex") && e.contains("did not write"), "{e}");
    assert_eq!(std::fs::read_dir(&mine).unwrap().count(), 1);
    // A session is not labelled into itself.
    let session = tmp.path().join("s");
    let r = dataset(&["generate", "--session", session.to_str().unwrap(), "--count", "2", "--unit", "3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let truth = session.join(".simulation/truth.json");
    let args = ["label", "--session", session.to_str().unwrap(), "--sensor", truth.to_str().unwrap()];
    let e = refused(dataset(&[&args[..], &["--out", session.to_str().unwrap()]].concat()));
    assert!(e.contains("is also an input"), "{e}");
}
