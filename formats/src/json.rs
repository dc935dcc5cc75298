//! JSON files that name themselves in every error.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::fs::{FsError, write_atomic};

/// A file that could not be read, parsed or written.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl FormatError {
    pub fn invalid(path: &Path, message: impl std::fmt::Display) -> Self {
        FormatError::Invalid { path: path.to_path_buf(), message: message.to_string() }
    }
}

impl From<FsError> for FormatError {
    fn from(e: FsError) -> Self {
        FormatError::Io { path: e.path, source: e.source }
    }
}

/// Reads and parses a JSON file, naming the file in every error.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, FormatError> {
    let text = std::fs::read_to_string(path).map_err(|source| FormatError::Io { path: path.into(), source })?;
    serde_json::from_str(&text).map_err(|e| FormatError::invalid(path, e))
}

/// The settings in which `old` and `new` differ, each as `path: old value vs new value`
/// (objects compared key by key, anything else as a whole).
pub fn differences(old: &serde_json::Value, new: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    diff_into("", old, new, &mut out);
    out
}

fn diff_into(path: &str, old: &serde_json::Value, new: &serde_json::Value, out: &mut Vec<String>) {
    use serde_json::Value;
    match (old, new) {
        (Value::Object(a), Value::Object(b)) => {
            let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            for k in keys {
                let sub = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                let missing = Value::String("(absent)".into());
                diff_into(&sub, a.get(k).unwrap_or(&missing), b.get(k).unwrap_or(&missing), out);
            }
        }
        (a, b) if a != b => out.push(format!("{path}: {a} before, {b} now")),
        _ => {}
    }
}

/// Writes pretty JSON atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), FormatError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| FormatError::invalid(path, e))?;
    Ok(write_atomic(path, text.as_bytes())?)
}
