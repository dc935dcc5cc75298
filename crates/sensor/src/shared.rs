//! Locating the project's shared data (`shared/` beside the checkout: the authors' calibration
//! kit, PyTorch fixtures) for tests and benchmarks.

use std::path::PathBuf;

/// `$env_var` if set, else `shared/<name>` beside the workspace. `None` when the folder is
/// absent, so that a test can skip; in CI (`CI` set) its absence is a failure instead.
pub fn shared_dir_for_tests(env_var: &str, name: &str) -> Option<PathBuf> {
    let dir = std::env::var_os(env_var)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")).join(name));
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(std::env::var_os("CI").is_none(), "CI must provide {} (or ${env_var})", dir.display());
    eprintln!("skipped: no {} (set ${env_var})", dir.display());
    None
}
