//! The unit's elastomer fitted to its force labels when the bundle is made: inference then
//! solves the contact on each predicted depth map (`mechanics`) for pressure and wrench, which
//! measured better than a pressure output trained into the network (BENCHMARKS.md).

use std::path::Path;

use anyhow::{Context, Result};
use formats::dataset::{Manifest, Split};
use formats::stats::Summary;
use mechanics::{Dome, GridConfig, Material, force_label};
use model::bundle::ElastomerRecord;
use rayon::prelude::*;

/// Train samples the fit reads at most (evenly spaced): each costs one contact solve.
const MAX_SAMPLES: usize = 256;

/// Below this solved force (N at 1 MPa) a sample says little about the material: a graze
/// whose force is mostly the discretisation's.
const MIN_SOLVED_N: f64 = 0.5;

/// E* from the train split of `data`: the median of |F| / |F solved at 1 MPa| over its samples
/// with a wrench (the measured one where a sample has it, else the label). `None` where no
/// train sample has a wrench and contact. With `skip_bad`, a depth map that cannot be decoded
/// is left out; a failing read is an error either way.
pub fn fit_elastomer(data: &Path, skip_bad: bool) -> Result<Option<ElastomerRecord>> {
    let manifest = Manifest::load(data)?;
    let with_wrench: Vec<_> = manifest
        .split(Some(Split::Train))
        .filter_map(|s| s.measured_wrench().map(|w| (s, *w, true)).or_else(|| s.force_label().map(|w| (s, *w, false))))
        .collect();
    if with_wrench.is_empty() {
        return Ok(None);
    }
    let step = with_wrench.len().div_ceil(MAX_SAMPLES);
    let chosen: Vec<_> = with_wrench.into_iter().step_by(step).collect();
    let dome = Dome::new(&manifest.sensor);
    let unit = Material::with_effective_modulus(1.0);
    let ratios: Vec<Option<(f64, bool)>> = chosen
        .par_iter()
        .map(|(s, wrench, measured)| -> Result<Option<(f64, bool)>> {
            let path = data.join(&s.depth);
            let Some(depth) = crate::gate::read_depth(&path, skip_bad)? else { return Ok(None) };
            let solved = force_label(&dome, &depth, &unit, &GridConfig::default())
                .with_context(|| format!("{}: solving its contact", path.display()))?
                .wrench
                .force_magnitude_n();
            let f = wrench.force_magnitude_n();
            Ok((solved >= MIN_SOLVED_N && f > 0.0).then_some((f / solved, *measured)))
        })
        .collect::<Result<_>>()?;
    let ratios: Vec<(f64, bool)> = ratios.into_iter().flatten().collect();
    if ratios.is_empty() {
        return Ok(None);
    }
    let summary = Summary::of(ratios.iter().map(|r| r.0));
    Ok(Some(ElastomerRecord {
        effective_modulus_mpa: summary.median,
        quartiles_mpa: [summary.q1, summary.q3],
        samples: ratios.len(),
        measured: ratios.iter().filter(|r| r.1).count(),
    }))
}

/// One line for people: what the fit found.
pub fn report_line(record: &ElastomerRecord) -> String {
    format!(
        "elastomer fitted to {} train samples' wrenches ({} measured): E* {:.4} MPa [quartiles {:.4}, {:.4}]; \
         inference solves each predicted contact with it for pressure and force",
        record.samples, record.measured, record.effective_modulus_mpa, record.quartiles_mpa[0], record.quartiles_mpa[1]
    )
}
