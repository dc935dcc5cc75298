//! A labelling killed, its capture log edited, then resumed: the mutated log replaces the
//! session's, the folder an earlier run labelled (its manifest gone, as a kill before the end
//! leaves it) is resumed, and the result must be what a fresh labelling of the edited session
//! writes, file for file, or a refusal that names the log.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{Context, Result};
use dataset::Kit;
use dataset::label::{Labeller, OnBadRow};
use formats::session::CAPTURES_CSV;
use sensor::Sensor;

use super::{Check, Outcome};

/// The check, with its fixed session (in `work/resume`) and the folder labelled from it once.
/// The session stays at one path, which the labelled folder records; each case writes its log
/// there, so cases run one at a time (a lock).
pub fn resume_check(work: &Path, session: &Path, sensor: Sensor, kit: Kit) -> Result<Check> {
    let dir = work.join("resume");
    let fixed = dir.join("session");
    copy_dir(session, &fixed)?;
    let labelled = dir.join("labelled");
    label(&fixed, &labelled, &sensor, &kit)?;
    std::fs::remove_file(labelled.join("manifest.json"))?;
    let log = std::fs::read(fixed.join(CAPTURES_CSV))?;
    let lock = Mutex::new(());
    Ok(Arc::new(move |_path: &Path, bytes: &[u8]| {
        let _one_at_a_time = lock.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let outcome = one_case(&fixed, &labelled, bytes, |out| label(&fixed, out, &sensor, &kit));
        // The next case starts from the session as it was.
        if let Err(e) = std::fs::write(fixed.join(CAPTURES_CSV), &log) {
            return Outcome::Invalid(format!("cannot restore the log: {e}"));
        }
        outcome
    }))
}

/// Labels `session` into `out`, leaving bad rows out (so that edits reach past the first).
fn label(session: &Path, out: &Path, sensor: &Sensor, kit: &Kit) -> Result<()> {
    let labeller = Labeller {
        session: session.to_path_buf(),
        out: out.to_path_buf(),
        sensor,
        kit,
        on_bad_row: OnBadRow::Skip,
        z: Default::default(),
        force: None,
        shard: None,
        register: false,
    };
    labeller.run().map(|_| ())
}

/// One case: the log written, a copy of the labelled folder resumed, a fresh folder labelled.
fn one_case(session: &Path, labelled: &Path, log: &[u8], label: impl Fn(&Path) -> Result<()>) -> Outcome {
    let tmp = match tempfile::tempdir() {
        Ok(t) => t,
        Err(e) => return Outcome::Invalid(format!("no temporary folder: {e}")),
    };
    let (resumed, fresh) = (tmp.path().join("resumed"), tmp.path().join("fresh"));
    let prepared = std::fs::write(session.join(CAPTURES_CSV), log)
        .map_err(anyhow::Error::from)
        .and_then(|()| copy_dir(labelled, &resumed));
    if let Err(e) = prepared {
        return Outcome::Invalid(format!("cannot prepare the case: {e:#}"));
    }
    if let Err(e) = label(&resumed) {
        return Outcome::Refused(format!("{e:#}"));
    }
    if let Err(e) = label(&fresh) {
        return Outcome::Invalid(format!("the resumed labelling ran but a fresh one fails: {e:#}"));
    }
    match (listing(&resumed), listing(&fresh)) {
        (Ok(a), Ok(b)) if a == b => Outcome::Accepted,
        (Ok(a), Ok(b)) => {
            let names = |l: &[(PathBuf, Vec<u8>)]| l.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
            let which = if names(&a) != names(&b) {
                format!("files {:?} against {:?}", names(&a), names(&b))
            } else {
                let (name, _) = a.iter().zip(&b).find(|(x, y)| x.1 != y.1).expect("a file differs").0;
                format!("{} differs", name.display())
            };
            Outcome::Invalid(format!("the resumed labelling is not the fresh one: {which}"))
        }
        (Err(e), _) | (_, Err(e)) => Outcome::Invalid(format!("cannot list the results: {e:#}")),
    }
}

/// Every file under `dir` (relative path, bytes), in name order.
fn listing(dir: &Path) -> Result<Vec<(PathBuf, Vec<u8>)>> {
    let mut out = Vec::new();
    let mut folders = vec![dir.to_path_buf()];
    while let Some(d) = folders.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| d.display().to_string())? {
            let path = entry?.path();
            if path.is_dir() {
                folders.push(path);
            } else {
                let bytes = std::fs::read(&path).with_context(|| path.display().to_string())?;
                out.push((path.strip_prefix(dir)?.to_path_buf(), bytes));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// A copy of the folder `from` (and its folders) at `to`.
fn copy_dir(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).with_context(|| to.display().to_string())?;
    for entry in std::fs::read_dir(from).with_context(|| from.display().to_string())? {
        let path = entry?.path();
        let target = to.join(path.file_name().expect("a listed entry has a name"));
        if path.is_dir() {
            copy_dir(&path, &target)?;
        } else {
            std::fs::copy(&path, &target).with_context(|| path.display().to_string())?;
        }
    }
    Ok(())
}
