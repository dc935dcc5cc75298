//! What the dataset's end-to-end tests share.

use std::path::Path;

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

/// Starts the `dataset` binary `bin` with `args`, quiet, and returns it once `dir/samples`
/// holds at least `samples` files (a run to kill or to race part way).
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
