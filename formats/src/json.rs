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
        (a, b) if a != b => out.push(format!("{path}: {} before, {} now", shortened(a), shortened(b))),
        _ => {}
    }
}

/// A value as JSON, cut to a line's length: a refusal over a sensor's radial tables names the
/// setting without printing both tables.
fn shortened(v: &serde_json::Value) -> String {
    const MAX_CHARS: usize = 80;
    let text = v.to_string();
    if text.chars().count() <= MAX_CHARS {
        return text;
    }
    let head: String = text.chars().take(MAX_CHARS).collect();
    format!("{head}... ({} characters)", text.chars().count())
}

/// Writes pretty JSON atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), FormatError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| FormatError::invalid(path, e))?;
    Ok(write_atomic(path, text.as_bytes())?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_name_each_setting_and_keep_long_values_short() {
        let table: Vec<f64> = (0..2000).map(|i| i as f64 * 0.001).collect();
        let mut moved = table.clone();
        moved[1000] += 1.0;
        let old = serde_json::json!({ "a": 1, "radial": { "table": table } });
        let new = serde_json::json!({ "a": 2, "radial": { "table": moved } });
        let d = differences(&old, &new);
        assert_eq!(d.len(), 2, "{d:?}");
        assert_eq!(d[0], "a: 1 before, 2 now");
        assert!(d[1].starts_with("radial.table: [0.0,") && d[1].contains("characters") && d[1].len() < 300, "{}", d[1]);
    }
}
