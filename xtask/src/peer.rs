//! The Python peers under `xtask/peers/`: where their scripts are, running one to its end, and
//! reading the `key=value` fields of what it printed. One definition for every benchmark.

use std::process::Command;

use anyhow::{Context, Result, bail};

/// The path of `xtask/peers/NAME`, wherever the workspace was checked out.
pub fn script(name: &str) -> String {
    format!("{}/peers/{name}", env!("CARGO_MANIFEST_DIR"))
}

/// Runs `peers/NAME` with `python` and `args`; its standard output. A peer that fails is an
/// error carrying its standard error.
pub fn run(python: &str, name: &str, args: &[&str]) -> Result<String> {
    let script = script(name);
    let out =
        Command::new(python).arg(&script).args(args).output().with_context(|| format!("running {python} {script}"))?;
    if !out.status.success() {
        bail!("peer {script} failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The number after `key` (which ends in `=`) in a peer's output, if one is there.
pub fn field(text: &str, key: &str) -> Option<f64> {
    text.split_whitespace().find_map(|w| w.strip_prefix(key)).and_then(|v| v.parse::<f64>().ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_read_by_their_whole_key() {
        let line = "batch=4 forward_ms=12.5 forward_q1_ms=11 version=1.2";
        assert_eq!(field(line, "batch="), Some(4.0));
        assert_eq!(field(line, "forward_ms="), Some(12.5));
        assert_eq!(field(line, "forward_q1_ms="), Some(11.0));
        assert_eq!(field(line, "forward_q3_ms="), None);
        assert_eq!(field(line, "version="), Some(1.2));
        assert_eq!(field("x=abc", "x="), None);
    }

    #[test]
    fn every_peer_script_is_where_script_says() {
        for name in ["onnx_runtime.py", "densedepth_torch.py", "raycast_open3d.py"] {
            assert!(std::path::Path::new(&script(name)).is_file(), "{name}");
        }
    }

    #[test]
    fn a_failing_peer_is_an_error_naming_it() {
        // `false` exits non-zero whatever it is given.
        let err = run("false", "onnx_runtime.py", &[]).unwrap_err().to_string();
        assert!(err.contains("onnx_runtime.py"), "{err}");
    }
}
