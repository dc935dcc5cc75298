//! What the dataset's end-to-end tests share.

use std::path::Path;
use std::process::{Command, Output};

/// The `dataset` command run with `args`.
#[allow(dead_code)]
pub fn dataset(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dataset")).args(args).output().unwrap()
}

/// A run's standard output, once it is known to have succeeded (its output and errors shown
/// where it did not).
#[allow(dead_code)]
pub fn ok(r: Output) -> String {
    assert!(r.status.success(), "{}\n{}", String::from_utf8_lossy(&r.stdout), String::from_utf8_lossy(&r.stderr));
    String::from_utf8_lossy(&r.stdout).into_owned()
}

/// A run's standard error, once it is known to have failed.
#[allow(dead_code)]
pub fn refused(r: Output) -> String {
    assert!(!r.status.success(), "expected a refusal: {}", String::from_utf8_lossy(&r.stdout));
    String::from_utf8_lossy(&r.stderr).into_owned()
}

#[allow(dead_code)]
pub mod kill;

/// The files directly in `dir` and in its folders `subs` (`""`: `dir` itself), as paths
/// relative to `dir` with their bytes, in name order: two runs' outputs compare equal exactly
/// when these do.
pub fn files(dir: &Path, subs: &[&str]) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in subs {
        let mut names: Vec<_> =
            std::fs::read_dir(dir.join(sub)).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_file()).collect();
        names.sort();
        out.extend(
            names.into_iter().map(|p| (p.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&p).unwrap())),
        );
    }
    out
}

/// Every file under `dir`, however deep, as [`files`] lists them: two runs wrote the same
/// folder exactly when these compare equal.
#[allow(dead_code)]
pub fn all_files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut subs = vec![String::new()];
    let mut k = 0;
    while k < subs.len() {
        let mut found: Vec<String> = std::fs::read_dir(dir.join(&subs[k]))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_dir())
            .map(|p| p.strip_prefix(dir).unwrap().display().to_string())
            .collect();
        found.sort();
        subs.extend(found);
        k += 1;
    }
    let refs: Vec<&str> = subs.iter().map(String::as_str).collect();
    files(dir, &refs)
}

/// Fails, naming the first file that differs (or is missing), unless the folders `a` and `b`
/// hold the same files with the same bytes; `context` says what made them.
#[allow(dead_code)]
pub fn assert_same_files(a: &Path, b: &Path, context: &str) {
    let (fa, fb) = (all_files(a), all_files(b));
    let names = |f: &[(String, Vec<u8>)]| f.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(&fa), names(&fb), "{context}");
    for ((name, x), (_, y)) in fa.iter().zip(&fb) {
        assert!(x == y, "{name} differs: {context}");
    }
}

/// Starts the `dataset` binary `bin` with `args`, quiet, and returns it once `dir/samples`
/// holds at least `samples` files (a run to kill or to race part way).
#[allow(dead_code)]
pub fn spawn_until(bin: &str, args: &[&str], dir: &Path, samples: usize) -> std::process::Child {
    let child = std::process::Command::new(bin)
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while std::fs::read_dir(dir.join("samples")).map(|d| d.count()).unwrap_or(0) < samples {
        assert!(start.elapsed() < std::time::Duration::from_secs(120), "no progress");
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child
}
