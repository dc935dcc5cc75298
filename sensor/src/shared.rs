//! Locating the project's shared data (`shared/` beside the checkout: the authors' calibration
//! kit, PyTorch fixtures) for tests and benchmarks.
//!
//! Tests that read it are marked `#[ignore = "needs ../shared"]`: outside CI they show as
//! ignored rather than passing having checked nothing, and CI runs them with
//! `--include-ignored`, where a missing folder fails them.

use std::path::PathBuf;

/// `$env_var` if set, else `shared/<name>` beside the workspace; panics, naming both, when the
/// folder is absent.
pub fn shared_dir(env_var: &str, name: &str) -> PathBuf {
    let dir = std::env::var_os(env_var)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared")).join(name));
    assert!(dir.is_dir(), "this test needs {} (or ${env_var} set to the folder)", dir.display());
    dir
}
