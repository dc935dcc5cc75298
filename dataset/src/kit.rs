//! Calibration kits: the authors' DenseTact kit on disk, or the embedded procedural one.
//! Either way a kit is a set of indicators and indenters plus trials (which indenters go into
//! which indicator at which angles), split into train and test by combination as in the paper.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use formats::Split;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::mesh::{LoadOptions, Mesh, MeshError};
use crate::procedural::ProceduralKit;
use crate::scene::{Indenter, Indicator, SceneError};

/// One row of a kit's index: an indicator with up to two indenters at given angles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trial {
    pub split: Split,
    /// The index's trial number (1-based, per split).
    pub number: u32,
    /// Index into `Kit::indicators`.
    pub indicator: usize,
    /// Indices into `Kit::indenters`, each with its angle about the hole's axis (degrees).
    pub indenters: Vec<(usize, f32)>,
}

#[derive(Debug, thiserror::Error)]
pub enum KitError {
    #[error("{path}: {message}")]
    Layout { path: PathBuf, message: String },
    #[error("{path}: row {row}: {message}")]
    Index { path: PathBuf, row: usize, message: String },
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("{path}: {source}")]
    Scene { path: PathBuf, source: SceneError },
}

/// A loaded kit.
pub struct Kit {
    /// "procedural" or the kit's folder.
    pub source: String,
    pub indicators: Vec<Indicator>,
    pub indenters: Vec<Indenter>,
    pub trials: Vec<Trial>,
}

impl Kit {
    /// The embedded kit: every indicator with every indenter (and pairs in two-hole shells),
    /// each combination in exactly one split.
    pub fn procedural(radius_mm: f32) -> Kit {
        let ProceduralKit { indicators, indenters } = ProceduralKit::new(radius_mm);
        let mut trials = Vec::new();
        let n = indenters.len();
        // A combination's split is fixed; a pair of indenters joins a split only if both of its
        // combinations belong to it.
        let is_test = |i: usize, j: usize| (i + 2 * j) % 7 == 3;
        let mut numbers = BTreeMap::<Split, u32>::new();
        let mut push = |indicator: usize, list: Vec<(usize, f32)>| {
            let split = if is_test(indicator, list[0].0) { Split::Test } else { Split::Train };
            let number = numbers.entry(split).or_default();
            *number += 1;
            trials.push(Trial { split, number: *number, indicator, indenters: list });
        };
        for (i, indicator) in indicators.iter().enumerate() {
            for j in 0..n {
                let angle = ((i * 37 + j * 53) % 180) as f32;
                push(i, vec![(j, angle)]);
                if indicator.holes.len() >= 2 {
                    let partner = (5..n + 5).map(|o| (j + o) % n).find(|&k| k != j && is_test(i, k) == is_test(i, j));
                    if let Some(k) = partner {
                        push(i, vec![(j, angle), (k, (angle + 90.0) % 180.0)]);
                    }
                }
            }
        }
        Kit { source: "procedural".into(), indicators, indenters, trials }
    }

    /// Loads the authors' kit: `stl/indicators/3Dindicator_verN.STL`, `stl/indenters/indent_verN.STL`,
    /// `Index_training.csv` and `Index_test.csv`. Only the meshes the index uses are loaded.
    pub fn load_dir(dir: &Path) -> Result<Kit, KitError> {
        Self::load_dir_scaled(dir, 1.0)
    }

    /// The kit `name` names, as `--kit` takes it: `procedural` (the embedded kit, for a dome of
    /// `radius_mm`) or a kit folder ([`Kit::open_dir`]); `what` names the argument in errors.
    pub fn open(name: &str, scale_to_mm: f32, radius_mm: f32, what: &str) -> anyhow::Result<Kit> {
        match name {
            "procedural" => Ok(Kit::procedural(radius_mm)),
            dir => Kit::open_dir(Path::new(dir), scale_to_mm, what),
        }
    }

    /// The kit in `dir`, known by its absolute path (recorded in what is made from it, so that
    /// a run resumes from any working folder); `what` names the argument in errors.
    pub fn open_dir(dir: &Path, scale_to_mm: f32, what: &str) -> anyhow::Result<Kit> {
        use anyhow::Context;
        let dir = absolute_dir(dir, what)?;
        Kit::load_dir_scaled(&dir, scale_to_mm).with_context(|| format!("loading the kit in {}", dir.display()))
    }

    /// [`Kit::load_dir`] with the files' coordinates multiplied by `scale_to_mm` (25.4 for a kit
    /// exported in inches). Parts whose size fits no kit, or indicators whose dome does not
    /// point along the file's Y axis, are refused with the file and the fix.
    pub fn load_dir_scaled(dir: &Path, scale_to_mm: f32) -> Result<Kit, KitError> {
        if !dir.is_dir() {
            return Err(KitError::Layout { path: dir.into(), message: "kit folder not found".into() });
        }
        let mut rows = Vec::new();
        for (split, file) in [(Split::Train, "Index_training.csv"), (Split::Test, "Index_test.csv")] {
            rows.extend(read_index(&dir.join(file), split)?);
        }
        let mut indicator_ids: Vec<u32> = rows.iter().map(|r| r.indicator).collect();
        let mut indenter_ids: Vec<u32> = rows.iter().flat_map(|r| r.indenters.iter().map(|x| x.0)).collect();
        indicator_ids.sort_unstable();
        indicator_ids.dedup();
        indenter_ids.sort_unstable();
        indenter_ids.dedup();
        let opts = LoadOptions { scale_to_mm, ..LoadOptions::default() };
        let indicators = indicator_ids
            .par_iter()
            .map(|&id| {
                let path = dir.join(format!("stl/indicators/3Dindicator_ver{id}.STL"));
                let mesh = Mesh::load(&path, opts)?;
                check_scale(&path, &mesh, INDICATOR_EXTENT_MM, "an indicator shell", scale_to_mm)?;
                check_dome_up(&path, &mesh)?;
                Indicator::new(format!("indicator-{id}"), mesh).map_err(|source| KitError::Scene { path, source })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let indenters = indenter_ids
            .par_iter()
            .map(|&id| {
                let path = dir.join(format!("stl/indenters/indent_ver{id}.STL"));
                let mesh = Mesh::load(&path, opts)?;
                check_scale(&path, &mesh, INDENTER_EXTENT_MM, "an indenter", scale_to_mm)?;
                Ok(Indenter { name: format!("indenter-{id}"), mesh })
            })
            .collect::<Result<Vec<_>, KitError>>()?;
        let trials = rows
            .into_iter()
            .map(|r| Trial {
                split: r.split,
                number: r.number,
                indicator: indicator_ids.binary_search(&r.indicator).unwrap(),
                indenters: r.indenters.iter().map(|&(id, a)| (indenter_ids.binary_search(&id).unwrap(), a)).collect(),
            })
            .collect();
        Ok(Kit { source: dir.display().to_string(), indicators, indenters, trials })
    }

    /// Trial `number` of the `split` index, if the kit has it.
    pub fn trial(&self, split: Split, number: u32) -> Option<&Trial> {
        self.trials.iter().find(|t| t.split == split && t.number == number)
    }

    pub fn trials_in(&self, split: Split) -> Vec<&Trial> {
        self.trials.iter().filter(|t| t.split == split).collect()
    }

    /// Indicator x indenter combinations that occur in both splits (the paper has none).
    pub fn shared_combinations(&self) -> Vec<(String, String)> {
        let combos = |split| -> std::collections::BTreeSet<(usize, usize)> {
            self.trials_in(split).iter().flat_map(|t| t.indenters.iter().map(move |&(j, _)| (t.indicator, j))).collect()
        };
        let test = combos(Split::Test);
        combos(Split::Train)
            .intersection(&test)
            .map(|&(i, j)| (self.indicators[i].name.clone(), self.indenters[j].name.clone()))
            .collect()
    }
}

/// How large (largest side, mm) a kit's parts are: the authors' shells are 53.5 mm across and
/// their indenters 25-31 mm, for a 25 mm sensor; a 15 mm variant scales them down.
const INDICATOR_EXTENT_MM: std::ops::RangeInclusive<f32> = 25.0..=150.0;
const INDENTER_EXTENT_MM: std::ops::RangeInclusive<f32> = 3.0..=80.0;

/// Refuses a part whose size fits no kit, suggesting the unit the file seems to be in.
fn check_scale(
    path: &Path,
    mesh: &Mesh,
    expected: std::ops::RangeInclusive<f32>,
    what: &str,
    scale_to_mm: f32,
) -> Result<(), KitError> {
    let (lo, hi) = mesh.bounds();
    let extent = (hi - lo).max_element();
    if expected.contains(&extent) {
        return Ok(());
    }
    let units = [(25.4, "inches"), (10.0, "centimetres"), (1000.0, "metres"), (0.001, "micrometres")];
    let hint = match units.iter().find(|(f, _)| expected.contains(&(extent * f))) {
        Some((f, unit)) => {
            format!("it looks like the file is in {unit}: load the kit with --kit-scale {}", f * scale_to_mm)
        }
        None => "check the file's units (millimetres expected)".to_string(),
    };
    Err(KitError::Layout {
        path: path.into(),
        message: format!(
            "the mesh is {extent:.3} mm across, but {what} is {:.0}..{:.0} mm across; {hint}",
            expected.start(),
            expected.end()
        ),
    })
}

/// Refuses an indicator whose dome does not point up (the sensor frame's `+z`, the file's `+Y`):
/// a file exported Z-up would press its side into the sensor.
fn check_dome_up(path: &Path, mesh: &Mesh) -> Result<(), KitError> {
    let n = mesh.vertices.len().max(1) as f32;
    let c = mesh.vertices.iter().copied().sum::<glam::Vec3>() / n;
    if c.z > 0.0 && c.z >= c.x.abs().max(c.y.abs()) {
        return Ok(());
    }
    // The sensor frame's axes back in the file's (x, y, z) -> (x, -z, y).
    let axis = [(c.x, "+X"), (-c.x, "-X"), (-c.y, "+Z"), (c.y, "-Z"), (-c.z, "-Y")]
        .into_iter()
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map_or("?", |a| a.1);
    Err(KitError::Layout {
        path: path.into(),
        message: format!(
            "the indicator's dome points along the file's {axis} axis, not +Y: the kit's files are Y-up (the \
             shell's axis along Y, its flat base at the bottom); export it Y-up"
        ),
    })
}

/// A parsed index row, with the kit's own part numbers.
struct IndexRow {
    split: Split,
    number: u32,
    indicator: u32,
    indenters: Vec<(u32, f32)>,
}

fn read_index(path: &Path, split: Split) -> Result<Vec<IndexRow>, KitError> {
    let err = |row: usize, message: String| KitError::Index { path: path.into(), row, message };
    let text = std::fs::read_to_string(path)
        .map_err(|e| KitError::Layout { path: path.into(), message: format!("cannot read the kit's index: {e}") })?;
    let mut reader = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(text.as_bytes());
    let mut rows = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let row = i + 2; // 1-based, after the header line
        let record = record.map_err(|e| err(row, e.to_string()))?;
        let field = |k: usize| record.get(k).map(str::trim).unwrap_or("");
        if (0..record.len()).all(|k| field(k).is_empty()) {
            continue;
        }
        let int = |k: usize, what: &str| -> Result<u32, KitError> {
            field(k).parse().map_err(|_| err(row, format!("{what} must be a whole number, got {:?}", field(k))))
        };
        let angle = |k: usize| -> Result<f32, KitError> {
            let a: f32 = if field(k).is_empty() {
                0.0
            } else {
                field(k).parse().map_err(|_| err(row, format!("angle must be a number, got {:?}", field(k))))?
            };
            if a.is_finite() { Ok(a) } else { Err(err(row, "angle must be finite".into())) }
        };
        let mut indenters = vec![(int(2, "first indenter")?, angle(3)?)];
        if !field(4).is_empty() {
            indenters.push((int(4, "second indenter")?, angle(5)?));
        }
        rows.push(IndexRow { split, number: int(0, "trial number")?, indicator: int(1, "indicator")?, indenters });
    }
    if rows.is_empty() {
        return Err(KitError::Layout { path: path.into(), message: "the index lists no trials".into() });
    }
    Ok(rows)
}

/// `path` made absolute and free of `..` and links; `what` names it if it does not exist.
pub fn absolute_dir(path: &Path, what: &str) -> anyhow::Result<PathBuf> {
    use anyhow::Context;
    std::fs::canonicalize(path).with_context(|| format!("{}: cannot open the folder of {what}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn procedural_splits_are_disjoint_by_combination() {
        let kit = Kit::procedural(25.0);
        assert!(kit.shared_combinations().is_empty());
        let (train, test) = (kit.trials_in(Split::Train).len(), kit.trials_in(Split::Test).len());
        assert!(test > 10 && train > 5 * test, "train {train} test {test}");
        for t in &kit.trials {
            assert!(t.indenters.len() <= kit.indicators[t.indicator].holes.len());
        }
    }

    #[test]
    fn bad_index_rows_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("Index_test.csv");
        std::fs::write(&path, "Trial,Indicator,first,angle,second,angle\n1,72,37,0,,\n2,72,x,0,,\n").unwrap();
        let e = read_index(&path, Split::Test).err().unwrap().to_string();
        assert!(e.contains("Index_test.csv") && e.contains("row 3") && e.contains("\"x\""), "{e}");
        let e = Kit::load_dir(&dir.path().join("missing")).err().unwrap().to_string();
        assert!(e.contains("kit folder not found"), "{e}");
    }
}
