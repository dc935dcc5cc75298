//! Outputs never destroy what is not theirs.
//!
//! A command that writes a folder first claims it: the folder may be new, empty, or a previous
//! output of the same kind (its marker file, `.densetact-output`, says which kind wrote it), and
//! it may be none of the command's inputs nor hold one of them. Anything else is refused before
//! any work, naming the path and what it holds. A file output may not be one of the inputs.
//! A claimed folder is held for as long as its command writes: a second command claiming it
//! meanwhile (two runs resuming into one folder) is refused rather than mixing their files.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The marker file a command leaves in each folder it writes.
pub const MARKER: &str = ".densetact-output";

/// The file a command holds an OS lock on while it writes the folder (released however the
/// process ends, `kill -9` included).
pub const LOCK: &str = ".densetact-lock";

/// A claimed folder, held: while this lives, claims of the same folder by other processes (or
/// other claims in this one) are refused.
#[must_use = "the folder is held only while the claim lives"]
#[derive(Debug)]
pub struct Claim {
    _lock: std::fs::File,
}

/// What a folder holds, as the command that wrote it says.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// `dataset generate --out`, `dataset label --out`.
    Dataset,
    /// `dataset generate --session`: a simulated capture session.
    Session,
    /// `train fit|finetune --out`: checkpoints and metrics.
    Run,
    /// `train --bundle`, `train export|import --out`.
    Bundle,
    /// `infer eval --out`.
    Evaluation,
    /// `infer stream --out`: per-frame depth and clouds, the stream's latency report.
    Stream,
    /// The quickstart's and the benchmarks' own folders.
    Work,
}

impl OutputKind {
    pub fn name(self) -> &'static str {
        match self {
            OutputKind::Dataset => "a dataset",
            OutputKind::Session => "a simulated session",
            OutputKind::Run => "a training run",
            OutputKind::Bundle => "a bundle",
            OutputKind::Evaluation => "an evaluation",
            OutputKind::Stream => "a stream's results",
            OutputKind::Work => "a work folder",
        }
    }
}

#[derive(Serialize, Deserialize)]
struct Marker {
    kind: OutputKind,
}

/// An output refused: the path, and why.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {why}")]
pub struct OutputError {
    pub path: PathBuf,
    pub why: String,
}

/// `path` made absolute and, where it exists, with its links resolved; where it does not, its
/// nearest existing ancestor is resolved and the rest appended (so that `out/../data` and
/// `data` compare equal before `out` exists).
fn resolved(path: &Path) -> PathBuf {
    let joined = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().map(|d| d.join(path)).unwrap_or_else(|_| path.to_path_buf())
    };
    // `.` and `..` lexically first: `x/../run` is `run` even while `x` does not exist.
    let mut absolute = PathBuf::new();
    for part in joined.components() {
        match part {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                absolute.pop();
            }
            other => absolute.push(other),
        }
    }
    let mut rest = Vec::new();
    let mut head = absolute.as_path();
    loop {
        if let Ok(real) = head.canonicalize() {
            return rest.iter().rev().fold(real, |p, part| p.join(part));
        }
        match (head.file_name(), head.parent()) {
            (Some(name), Some(parent)) => {
                rest.push(name.to_os_string());
                head = parent;
            }
            _ => return absolute,
        }
    }
}

/// Refuses an output file that is one of `inputs`, lies inside an input folder, or lies in a
/// folder a command of this project owns (a bundle, a dataset, a session, a run, an
/// evaluation, a stream's results): a file added there (or over one of its files) leaves the
/// folder other than its command wrote it, or unloadable.
pub fn check_file(out: &Path, inputs: &[&Path]) -> Result<(), OutputError> {
    let o = resolved(out);
    let refuse = |why: String| Err(OutputError { path: out.to_path_buf(), why });
    for input in inputs {
        let i = resolved(input);
        if i == o {
            return refuse(format!("is also an input ({}); writing it would destroy it", input.display()));
        }
        if i.is_dir() && o.starts_with(&i) {
            return refuse(format!("lies in an input folder ({}); write it elsewhere", input.display()));
        }
    }
    for folder in o.ancestors().skip(1) {
        if let Some(kind) = marker_kind(folder).filter(|&k| k != OutputKind::Work) {
            return refuse(format!(
                "lies in {} ({}), which only its own command writes; write it elsewhere",
                kind.name(),
                folder.display()
            ));
        }
    }
    Ok(())
}

/// Refuses two outputs that are the same file.
pub fn check_distinct(outputs: &[&Path]) -> Result<(), OutputError> {
    for (i, a) in outputs.iter().enumerate() {
        for b in &outputs[..i] {
            if resolved(a) == resolved(b) {
                return Err(OutputError { path: a.to_path_buf(), why: "is named as two outputs".into() });
            }
        }
    }
    Ok(())
}

/// Whether `dir` holds nothing but this tool's temporary files (none at all included).
fn holds_only_temporaries(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|mut d| {
        d.all(|e| {
            e.is_ok_and(|e| {
                e.file_type().is_ok_and(|t| t.is_file()) && crate::fs::is_temporary(&e.file_name().to_string_lossy())
            })
        })
    })
}

/// What a folder holds, for a refusal: its entry count and a few names.
fn contents(dir: &Path) -> String {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| {
                    let dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
                    format!("{}{}", e.file_name().to_string_lossy(), if dir { "/" } else { "" })
                })
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    let n = names.len();
    let shown = names.into_iter().take(4).collect::<Vec<_>>().join(", ");
    format!("{n} entr{} ({shown}{})", if n == 1 { "y" } else { "ies" }, if n > 4 { ", ..." } else { "" })
}

/// Claims the folder `dir` for an output of `kind`: it may be new, empty or a previous output of
/// the same kind, and neither one of `inputs` nor a folder holding one. Creates it and leaves
/// the marker, and holds the folder until the returned claim is dropped. The refusal names the
/// path and what it holds, or that another process is writing it.
pub fn claim_dir(dir: &Path, kind: OutputKind, inputs: &[&Path]) -> Result<Claim, OutputError> {
    check_dir(dir, kind, inputs)?;
    std::fs::create_dir_all(dir)
        .map_err(|e| OutputError { path: dir.to_path_buf(), why: format!("cannot create: {e}") })?;
    mark(dir, kind)?;
    let path = dir.join(LOCK);
    let refuse = |why: String| OutputError { path: dir.to_path_buf(), why };
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| refuse(format!("cannot open its lock file {LOCK}: {e}")))?;
    match file.try_lock() {
        Ok(()) => Ok(Claim { _lock: file }),
        Err(std::fs::TryLockError::WouldBlock) => Err(refuse(format!(
            "another process is writing {} here (it holds {LOCK}); wait for it to end, or use another path",
            kind.name()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(refuse(format!("cannot lock {LOCK}: {e}"))),
    }
}

/// [`claim_dir`]'s checks alone, for a folder that is written elsewhere and renamed into place.
pub fn check_dir(dir: &Path, kind: OutputKind, inputs: &[&Path]) -> Result<(), OutputError> {
    let d = resolved(dir);
    let refuse = |why: String| Err(OutputError { path: dir.to_path_buf(), why });
    for input in inputs {
        let i = resolved(input);
        if i == d {
            return refuse(format!(
                "is also an input ({}); writing {} there would destroy it",
                input.display(),
                kind.name()
            ));
        }
        if i.starts_with(&d) {
            return refuse(format!(
                "holds an input ({}); writing {} there could destroy it",
                input.display(),
                kind.name()
            ));
        }
    }
    if !dir.exists() {
        return Ok(());
    }
    if !dir.is_dir() {
        return refuse(format!("is a file, not a folder for {}", kind.name()));
    }
    match marker_kind(dir) {
        Some(k) if k == kind => Ok(()),
        Some(k) => refuse(format!("holds {}, not {}; use another path", k.name(), kind.name())),
        // Empty, or holding only what a claim killed before its marker's rename leaves.
        None if holds_only_temporaries(dir) => Ok(()),
        None => refuse(format!(
            "holds {} that this tool did not write as {}; use another path, or an empty folder",
            contents(dir),
            kind.name()
        )),
    }
}

/// The kind of output a folder's marker says it holds; for a folder written before markers
/// existed, the kind its own files show (`generator.json`, `checkpoint/`, `bundle.json`...).
pub fn marker_kind(dir: &Path) -> Option<OutputKind> {
    if let Ok(text) = std::fs::read_to_string(dir.join(MARKER)) {
        return serde_json::from_str::<Marker>(&text).ok().map(|m| m.kind);
    }
    let has = |name: &str| dir.join(name).exists();
    if has(".simulation") {
        Some(OutputKind::Session)
    } else if has("generator.json") || has("label.json") {
        Some(OutputKind::Dataset)
    } else if has("bundle.json") {
        Some(OutputKind::Bundle)
    } else if has("checkpoint") || has("checkpoint.old") {
        Some(OutputKind::Run)
    } else if has("stats.json") && has("errors.csv") {
        Some(OutputKind::Evaluation)
    } else {
        None
    }
}

/// Leaves the marker of `kind` in `dir` (written atomically).
pub fn mark(dir: &Path, kind: OutputKind) -> Result<(), OutputError> {
    let text = serde_json::to_string(&Marker { kind }).expect("marker serialises");
    crate::fs::write_atomic(&dir.join(MARKER), text.as_bytes())
        .map_err(|e| OutputError { path: e.path, why: e.source.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_new_empty_or_same_kind_folders_are_claimed() {
        let tmp = tempfile::tempdir().unwrap();
        let new = tmp.path().join("new");
        drop(claim_dir(&new, OutputKind::Bundle, &[]).unwrap());
        assert_eq!(marker_kind(&new), Some(OutputKind::Bundle));
        let held = claim_dir(&new, OutputKind::Bundle, &[]).unwrap();
        // Held: a second claim (another run resuming into it) is refused until the first ends.
        let e = claim_dir(&new, OutputKind::Bundle, &[]).unwrap_err().to_string();
        assert!(e.contains("new") && e.contains("another process is writing a bundle"), "{e}");
        drop(held);
        drop(claim_dir(&new, OutputKind::Bundle, &[]).unwrap());
        let e = claim_dir(&new, OutputKind::Dataset, &[]).unwrap_err().to_string();
        assert!(e.contains("new") && e.contains("holds a bundle, not a dataset"), "{e}");

        let empty = tmp.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        drop(claim_dir(&empty, OutputKind::Run, &[]).unwrap());

        // A claim killed between its marker's temporary file and the rename: still empty.
        let killed = tmp.path().join("killed");
        std::fs::create_dir(&killed).unwrap();
        std::fs::write(crate::fs::temp_path(&killed.join(MARKER)), b"{\"ki").unwrap();
        drop(claim_dir(&killed, OutputKind::Run, &[]).unwrap());
        assert_eq!(marker_kind(&killed), Some(OutputKind::Run));
        // A temporary file beside someone else's file does not make it ours.
        let mixed = tmp.path().join("mixed");
        std::fs::create_dir(&mixed).unwrap();
        std::fs::write(crate::fs::temp_path(&mixed.join(MARKER)), b"").unwrap();
        std::fs::write(mixed.join("notes.txt"), b"mine").unwrap();
        assert!(check_dir(&mixed, OutputKind::Run, &[]).is_err());

        let theirs = tmp.path().join("theirs");
        std::fs::create_dir(&theirs).unwrap();
        std::fs::write(theirs.join("thesis.tex"), b"years of work").unwrap();
        let e = check_dir(&theirs, OutputKind::Bundle, &[]).unwrap_err().to_string();
        assert!(e.contains("theirs") && e.contains("1 entry (thesis.tex)"), "{e}");
        assert!(theirs.join("thesis.tex").is_file());

        let file = tmp.path().join("f");
        std::fs::write(&file, b"x").unwrap();
        assert!(check_dir(&file, OutputKind::Evaluation, &[]).unwrap_err().to_string().contains("is a file"));
    }

    #[test]
    fn an_input_or_a_folder_holding_one_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("run");
        let _claim = claim_dir(&run, OutputKind::Run, &[]).unwrap();
        // `export --run R --out R`: the same folder, spelt differently.
        let same = tmp.path().join("x/../run");
        let e = check_dir(&same, OutputKind::Bundle, &[&run]).unwrap_err().to_string();
        assert!(e.contains("is also an input"), "{e}");
        let e = check_dir(tmp.path(), OutputKind::Work, &[&run]).unwrap_err().to_string();
        assert!(e.contains("holds an input"), "{e}");
        // A bundle inside a run folder is fine: nothing of the run is replaced.
        check_dir(&run.join("bundle"), OutputKind::Bundle, &[&run]).unwrap();

        let image = tmp.path().join("f.png");
        std::fs::write(&image, b"png").unwrap();
        let e = check_file(&tmp.path().join("./f.png"), &[&image]).unwrap_err().to_string();
        assert!(e.contains("is also an input"), "{e}");
        check_file(&tmp.path().join("d.png"), &[&image]).unwrap();
        // Not into an input folder, nor into a folder another command owns; a work folder is
        // anyone's.
        std::fs::create_dir(tmp.path().join("in")).unwrap();
        let e = check_file(&tmp.path().join("in/x.png"), &[&tmp.path().join("in")]).unwrap_err().to_string();
        assert!(e.contains("input folder"), "{e}");
        for (kind, refused) in [(OutputKind::Bundle, true), (OutputKind::Dataset, true), (OutputKind::Work, false)] {
            let dir = tmp.path().join(kind.name().replace(' ', "-"));
            drop(claim_dir(&dir, kind, &[]).unwrap());
            std::fs::create_dir_all(dir.join("sub")).unwrap();
            for out in [dir.join("x.png"), dir.join("sub/x.png")] {
                assert_eq!(check_file(&out, &[]).is_err(), refused, "{kind:?} {}", out.display());
            }
        }
        assert!(check_distinct(&[&image, &tmp.path().join("f.png")]).is_err());
    }
}
