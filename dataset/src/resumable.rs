//! Folders filled item by item so that a killed run resumes where it stopped: the generator's
//! datasets, labelled capture sessions and simulated sessions all work this way.
//!
//! A parameters file fixes what the folder holds (a resumed run must ask for the same, and is
//! told which setting differs); each item's files are written atomically, its record last, so a
//! record on disk means a whole item; temporary files a kill left are removed; after a power cut
//! a record that does not parse or names a file that does not end whole is made again.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use formats::fs::{jpeg_is_complete, png_is_complete, remove_temporaries};
use formats::output::{Claim, OutputKind};
use formats::{Progress, read_json, write_json};
use rayon::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;

/// Creates `dir`'s sub-folders (removing temporaries a killed run left in them), and writes the
/// parameters file `params_name`, or checks that the one there says the same; `what` and `flag`
/// name the folder's kind and the option that chose it in the refusal.
/// The folder is claimed first (`formats::output`): new, empty or of this `kind`, and none of
/// `inputs`; it is held until the returned claim is dropped.
#[allow(clippy::too_many_arguments)]
pub(crate) fn prepare<P: Serialize + DeserializeOwned>(
    dir: &Path,
    kind: OutputKind,
    inputs: &[&Path],
    subs: &[&str],
    params_name: &str,
    params: &P,
    what: &str,
    flag: &str,
) -> Result<Claim> {
    let claim = formats::output::claim_dir(dir, kind, inputs)?;
    for sub in std::iter::once("").chain(subs.iter().copied()) {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).with_context(|| format!("{}: cannot create folder", d.display()))?;
        remove_temporaries(&d)?;
    }
    let path = dir.join(params_name);
    if path.exists() {
        // Read as the type it is (filling defaults of settings added since), then compared.
        let existing = serde_json::to_value(read_json::<P>(&path)?)?;
        let wanted = serde_json::to_value(params)?;
        let differences = formats::json::differences(&existing, &wanted);
        if !differences.is_empty() {
            bail!(
                "{}: this folder holds {what} made with other settings ({}); use another {flag}, or remove the \
                 folder to start again",
                path.display(),
                differences.join("; ")
            );
        }
    } else {
        write_json(&path, params)?;
    }
    Ok(claim)
}

/// Whether an image file was written whole (PNG or JPEG, by extension).
pub(crate) fn image_is_complete(path: &Path) -> bool {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("jpg" | "jpeg") => jpeg_is_complete(path),
        _ => png_is_complete(path),
    }
}

/// The records of items (`what`: "samples", "frames") finished by an earlier run, by id:
/// `record(id)` is an item's record
/// path, `files(&record)` the files it needs whole, `belongs(id, &record)` whether it is this
/// folder's item `id` (a record that is not is an error, not something to overwrite).
pub(crate) fn finished<R: DeserializeOwned>(
    what: &str,
    ids: impl Iterator<Item = u32>,
    record: impl Fn(u32) -> PathBuf,
    files: impl Fn(&R) -> Vec<PathBuf>,
    belongs: impl Fn(u32, &R) -> bool,
) -> Result<BTreeMap<u32, R>> {
    let mut done = BTreeMap::new();
    let mut damaged = 0;
    for id in ids {
        let path = record(id);
        if !path.exists() {
            continue;
        }
        // After a power cut a record or its files may be short: such an item is made again.
        let Ok(r) = read_json::<R>(&path) else {
            damaged += 1;
            std::fs::remove_file(&path).with_context(|| format!("{}: cannot remove", path.display()))?;
            continue;
        };
        if !belongs(id, &r) {
            bail!("{}: record does not match item {id} of this folder", path.display());
        }
        if !files(&r).iter().all(|f| image_is_complete(f)) {
            damaged += 1;
            std::fs::remove_file(&path).with_context(|| format!("{}: cannot remove", path.display()))?;
            continue;
        }
        done.insert(id, r);
    }
    if damaged > 0 {
        eprintln!("{damaged} {what} left incomplete by an interrupted run will be made again");
    }
    Ok(done)
}

/// Removes from `done` the items an earlier run finished whose inputs or files changed since
/// (`current(id, &record)` false: a row edited, a frame replaced), checked on all cores, and
/// returns their ids in order: they are made again, so that a resumed run gives what a fresh
/// run of the folder's inputs as they now stand gives.
pub(crate) fn drop_changed<R: Sync>(done: &mut BTreeMap<u32, R>, current: impl Fn(u32, &R) -> bool + Sync) -> Vec<u32> {
    let changed: Vec<u32> = done.par_iter().filter(|(id, r)| !current(**id, r)).map(|(id, _)| *id).collect();
    for id in &changed {
        done.remove(id);
    }
    changed
}

/// Removes, in `dir`'s folders `subs`, the items' files (named by their id, `NNNNNN.*`) whose
/// id `keep` refuses: what an earlier run made for items this run no longer has. Other files
/// are left alone.
pub(crate) fn remove_others(dir: &Path, subs: &[&str], keep: impl Fn(u32) -> bool) -> Result<()> {
    for sub in subs {
        let d = dir.join(sub);
        let entries = std::fs::read_dir(&d).with_context(|| format!("{}: cannot list", d.display()))?;
        for entry in entries {
            let path = entry.with_context(|| format!("{}: cannot list", d.display()))?.path();
            let id = path
                .file_stem()
                .and_then(|s| s.to_str())
                .filter(|s| s.len() == 6 && s.bytes().all(|b| b.is_ascii_digit()));
            if let Some(id) = id.and_then(|s| s.parse::<u32>().ok())
                && !keep(id)
            {
                std::fs::remove_file(&path).with_context(|| format!("{}: cannot remove", path.display()))?;
            }
        }
    }
    Ok(())
}

/// Makes the items `todo` on all cores, with progress; the first error stops the run.
pub(crate) fn make_all<R: Send>(todo: &[u32], label: &str, make: impl Fn(u32) -> Result<R> + Sync) -> Result<Vec<R>> {
    let progress = Progress::new(label, todo.len() as u64);
    let made = todo
        .par_iter()
        .map(|&id| {
            let r = make(id)?;
            progress.inc(1);
            Ok(r)
        })
        .collect::<Result<_>>();
    progress.finish();
    made
}
