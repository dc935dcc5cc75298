//! The generator end to end: determinism, kill -9 and resume, bad arguments.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_dataset");

fn generate(out: &Path, count: u32, extra: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .args(["generate", "--out", out.to_str().unwrap(), "--count", &count.to_string(), "--seed", "11"])
        .args(extra)
        .output()
        .unwrap()
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in ["", "samples", "depth"] {
        let mut names: Vec<_> =
            std::fs::read_dir(dir.join(sub)).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_file()).collect();
        names.sort();
        out.extend(
            names.into_iter().map(|p| (p.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&p).unwrap())),
        );
    }
    out
}

#[test]
fn killed_and_resumed_run_equals_an_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let count = 400;

    // Kill -9 once some samples are done.
    let mut child = Command::new(BIN)
        .args(["generate", "--out", a.to_str().unwrap(), "--count", &count.to_string(), "--seed", "11"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        let done = std::fs::read_dir(a.join("samples")).map(|d| d.count()).unwrap_or(0);
        if done >= 10 {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!a.join("manifest.json").exists(), "the run finished before it could be killed");
    // A half-written file as a kill could leave it.
    std::fs::write(a.join("depth/.000399.png.1234.tmp"), b"half").unwrap();

    let resumed = generate(&a, count, &[]);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let stdout = String::from_utf8_lossy(&resumed.stdout);
    assert!(stdout.contains("from an earlier run") && stdout.contains("contact"), "{stdout}");

    let fresh = generate(&b, count, &[]);
    assert!(fresh.status.success());
    let (fa, fb) = (files(&a), files(&b));
    assert_eq!(fa.len(), fb.len());
    assert_eq!(fa.len(), 2 + 2 * count as usize);
    for ((na, ca), (nb, cb)) in fa.iter().zip(&fb) {
        assert_eq!(na, nb);
        assert!(ca == cb, "{na} differs between the resumed and the uninterrupted run");
    }
    let manifest = dataset::format::Manifest::load(&a).unwrap();
    assert_eq!(manifest.samples.len(), count as usize);
    assert!(manifest.summary.values().all(|s| s.samples > 0 && s.mean_contact_fraction > 0.0));
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
    assert!(err.contains("generator.json") && err.contains("other parameters"), "{err}");

    let r = generate(&tmp.path().join("e"), 3, &["--kit", "/nonexistent/kit"]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("/nonexistent/kit"));

    let bad_sensor = tmp.path().join("sensor.json");
    std::fs::write(&bad_sensor, "{\"radius_mm\": 25}").unwrap();
    let r = generate(&tmp.path().join("f"), 3, &["--sensor", bad_sensor.to_str().unwrap()]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("sensor.json"));
}
