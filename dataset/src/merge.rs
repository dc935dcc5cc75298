//! `dataset merge`: the shares of a generation or a labelling that ran as a job array
//! (`--shard K/N`) joined into the dataset one run would have written, file for file and byte
//! for byte. Every sample is made from its id alone, so a share's files are the whole run's;
//! what the merge adds is the parameters file without the shard and the manifest over all.
//!
//! It refuses what one run would not have made: shares of different runs (their settings are
//! named), a share missing or given twice, a share that has not finished (its manifest is
//! written last), files of the shared `unit/` folder that differ between shares.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use formats::dataset::{GeneratorFile, Manifest, SampleRecord, Split, SplitSummary, sample_name};
use formats::fs::write_atomic_unsynced;
use formats::{Shard, read_json, write_json};
use rayon::prelude::*;

use crate::label::{LABEL_JSON, LabelFile};

/// The parameters file of a generated dataset.
pub const GENERATOR_JSON: &str = "generator.json";

/// What a share was made by, as its parameters file says.
#[derive(Clone)]
enum Made {
    Generated(GeneratorFile),
    Labelled(LabelFile),
}

impl Made {
    fn read(dir: &Path) -> Result<Made> {
        let (generated, labelled) = (dir.join(GENERATOR_JSON), dir.join(LABEL_JSON));
        if generated.is_file() {
            Ok(Made::Generated(read_json(&generated)?))
        } else if labelled.is_file() {
            Ok(Made::Labelled(read_json(&labelled)?))
        } else {
            bail!(
                "{}: neither {GENERATOR_JSON} nor {LABEL_JSON}: not a dataset folder written by `dataset generate` or \
                 `dataset label`",
                dir.display()
            )
        }
    }

    fn shard(&self) -> Option<Shard> {
        match self {
            Made::Generated(f) => f.params.shard,
            Made::Labelled(f) => f.params.shard,
        }
    }

    /// The same run without the shard: what one run would have written.
    fn whole(&self) -> Made {
        let mut whole = self.clone();
        match &mut whole {
            Made::Generated(f) => f.params.shard = None,
            Made::Labelled(f) => f.params.shard = None,
        }
        whole
    }

    fn value(&self) -> serde_json::Value {
        match self {
            Made::Generated(f) => serde_json::to_value(f),
            Made::Labelled(f) => serde_json::to_value(f),
        }
        .expect("parameters serialise")
    }

    fn file_name(&self) -> &'static str {
        match self {
            Made::Generated(_) => GENERATOR_JSON,
            Made::Labelled(_) => LABEL_JSON,
        }
    }

    /// The ids a finished share holds, where the run fixes them (a generation; a labelling
    /// may skip bad rows).
    fn expected_ids(&self) -> Option<Vec<u32>> {
        match self {
            Made::Generated(f) => Some(Shard::ids(f.params.shard, f.params.count).collect()),
            Made::Labelled(_) => None,
        }
    }

    /// Files a sample has beside those its record names.
    fn unrecorded_files(&self, id: u32) -> Vec<String> {
        match self {
            Made::Generated(f) => f.params.unrecorded_files(id),
            Made::Labelled(_) => Vec::new(),
        }
    }
}

/// What a merge did.
pub struct MergeReport {
    pub shards: usize,
    pub samples: usize,
    pub files: usize,
    /// `generator.json` or `label.json`: what kind of dataset it is.
    pub made_by: &'static str,
}

/// One share, read and checked.
struct Share {
    dir: PathBuf,
    shard: Shard,
    manifest: Manifest,
}

/// Joins the shares in `dirs` into the dataset folder `out`.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<MergeReport> {
    if dirs.is_empty() {
        bail!("nothing to merge: name the shares' folders");
    }
    let mut shares = Vec::new();
    let mut whole: Option<(Made, PathBuf)> = None;
    for dir in dirs {
        let made = Made::read(dir)?;
        let Some(shard) = made.shard() else {
            bail!("{}: made without --shard: a whole dataset, nothing to merge it with", dir.display());
        };
        match &whole {
            None => whole = Some((made.whole(), dir.clone())),
            Some((first, first_dir)) => {
                let differences = formats::json::differences(&first.value(), &made.whole().value());
                if !differences.is_empty() {
                    bail!(
                        "{} and {} are shares of different runs ({}): merge the shares of one command",
                        first_dir.display(),
                        dir.display(),
                        differences.join("; ")
                    );
                }
            }
        }
        let manifest = Manifest::load(dir).with_context(|| {
            format!(
                "{}: share {shard} has not finished (its manifest is written last): run its command again",
                dir.display()
            )
        })?;
        let ids: Vec<u32> = manifest.samples.iter().map(|s| s.id).collect();
        match made.expected_ids() {
            Some(expected) if expected != ids => bail!(
                "{}: share {shard} holds {} of its {} samples: it has not finished; run its command again",
                dir.display(),
                ids.iter().filter(|id| expected.binary_search(id).is_ok()).count(),
                expected.len()
            ),
            _ => {}
        }
        if let Some(id) = ids.iter().find(|&&id| !shard.holds(id)) {
            bail!(
                "{}: sample {id} is not share {shard}'s: the folder was not written by that share alone",
                dir.display()
            );
        }
        shares.push(Share { dir: dir.clone(), shard, manifest });
    }
    let (whole, _) = whole.expect("at least one share");
    let count = shares[0].shard.count;
    let mut seen: BTreeMap<u32, &Path> = BTreeMap::new();
    for s in &shares {
        if s.shard.count != count {
            bail!(
                "{} is share {} and {} share {}: every share of a run is cut into the same number",
                shares[0].dir.display(),
                shares[0].shard,
                s.dir.display(),
                s.shard
            );
        }
        if let Some(other) = seen.insert(s.shard.index, &s.dir) {
            bail!("{} and {} are both share {}", other.display(), s.dir.display(), s.shard);
        }
    }
    let missing: Vec<String> = (0..count).filter(|k| !seen.contains_key(k)).map(|k| format!("{k}/{count}")).collect();
    if !missing.is_empty() {
        bail!("shares {} are missing: merge all {count} shares of the run", missing.join(", "));
    }
    let first = &shares[0].manifest;
    for s in &shares[1..] {
        if s.manifest.labelled != first.labelled || s.manifest.sensor != first.sensor {
            bail!(
                "{} and {}: their manifests name other sessions or sensors",
                shares[0].dir.display(),
                s.dir.display()
            );
        }
    }

    // The shared folder (the unit's files) must be the same in every share.
    let unit = unit_files(&shares[0].dir)?;
    for s in &shares[1..] {
        if unit_files(&s.dir)? != unit {
            bail!(
                "{} and {}: their unit/ folders differ: shares of one run write the same unit files",
                shares[0].dir.display(),
                s.dir.display()
            );
        }
    }

    let inputs: Vec<&Path> = shares.iter().map(|s| s.dir.as_path()).collect();
    let copies: Vec<(PathBuf, String)> = shares
        .iter()
        .flat_map(|s| {
            s.manifest.samples.iter().flat_map(|r| {
                let mut files: Vec<String> = r.files().cloned().collect();
                files.push(format!("samples/{}.json", sample_name(r.id)));
                files.extend(whole.unrecorded_files(r.id));
                files.into_iter().map(|f| (s.dir.clone(), f))
            })
        })
        .collect();
    let mut subs: BTreeSet<&str> = copies.iter().filter_map(|(_, f)| f.split_once('/').map(|(d, _)| d)).collect();
    if !unit.is_empty() {
        subs.insert("unit");
    }
    let subs: Vec<&str> = subs.into_iter().collect();
    let _claim = match &whole {
        Made::Generated(f) => crate::resumable::prepare(
            out,
            formats::output::OutputKind::Dataset,
            &inputs,
            &subs,
            GENERATOR_JSON,
            f,
            "a dataset",
            "--out",
        )?,
        Made::Labelled(f) => crate::resumable::prepare(
            out,
            formats::output::OutputKind::Dataset,
            &inputs,
            &subs,
            LABEL_JSON,
            f,
            "a labelled session",
            "--out",
        )?,
    };
    for (name, bytes) in &unit {
        formats::fs::write_atomic(&out.join("unit").join(name), bytes)?;
    }
    let progress = formats::Progress::new("merging", copies.len() as u64);
    copies.par_iter().try_for_each(|(dir, rel)| -> Result<()> {
        let from = dir.join(rel);
        let bytes = std::fs::read(&from).with_context(|| format!("{}: cannot read", from.display()))?;
        write_atomic_unsynced(&out.join(rel), &bytes)?;
        progress.inc(1);
        Ok(())
    })?;
    progress.finish();

    let (format_version, sensor, labelled) = (first.format_version, first.sensor.clone(), first.labelled.clone());
    let mut samples: Vec<SampleRecord> = shares.into_iter().flat_map(|s| s.manifest.samples).collect();
    samples.sort_by_key(|s| s.id);
    let kept: BTreeSet<u32> = samples.iter().map(|s| s.id).collect();
    // Samples a previous merge into this folder left that this one does not hold.
    crate::resumable::remove_others(out, &subs, |id| kept.contains(&id))?;
    let mut summary = BTreeMap::new();
    for split in [Split::Train, Split::Test] {
        summary.insert(split, SplitSummary::of(samples.iter().filter(|s| s.split == split)));
    }
    let manifest = Manifest {
        format_version,
        sensor,
        generator: match &whole {
            Made::Generated(f) => Some(f.params.clone()),
            Made::Labelled(_) => None,
        },
        labelled,
        samples,
        summary,
    };
    let report = MergeReport {
        shards: count as usize,
        samples: manifest.samples.len(),
        files: copies.len(),
        made_by: whole.file_name(),
    };
    write_json(&out.join("manifest.json"), &manifest)?;
    Ok(report)
}

/// The files of a share's `unit/` folder by name, with their bytes (none without the folder).
fn unit_files(dir: &Path) -> Result<BTreeMap<String, Vec<u8>>> {
    let unit = dir.join("unit");
    let mut files = BTreeMap::new();
    if !unit.is_dir() {
        return Ok(files);
    }
    for entry in std::fs::read_dir(&unit).with_context(|| format!("{}: cannot list", unit.display()))? {
        let path = entry?.path();
        if path.is_file()
            && let Some(name) = path.file_name().and_then(|n| n.to_str())
            && !formats::fs::is_temporary(name)
        {
            files.insert(
                name.to_string(),
                std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?,
            );
        }
    }
    Ok(files)
}
