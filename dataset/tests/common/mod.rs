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
