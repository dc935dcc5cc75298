//! Evaluation as in the paper: per-image errors in millimetres over useful pixels (and over
//! contact pixels), beside the zero predictor's, summarised per split and drawn as violins.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use formats::dataset::{Manifest, SampleRecord, Split};
use formats::fs::write_atomic;
use formats::output::OutputKind;
use serde::Serialize;

use crate::Predictor;

pub use sensor::CONTACT_THRESHOLD_MM;

/// The uncertainty of 3D-printed ground truth (mm), drawn on the violin plot as in the paper.
pub const GROUND_TRUTH_UNCERTAINTY_MM: f64 = 0.11;

/// One image's errors.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageErrors {
    pub id: u32,
    pub split: String,
    /// Mean absolute error over useful pixels (mm).
    pub l1_mm: f64,
    /// Mean squared error over useful pixels (mm^2), the paper's "L2".
    pub l2_mm: f64,
    /// Mean absolute error over true contact pixels (mm); NaN without contact.
    pub contact_l1_mm: f64,
    /// The zero predictor's mean absolute error over useful pixels (mm).
    pub zero_l1_mm: f64,
    /// The zero predictor's over true contact pixels (mm); NaN without contact.
    pub zero_contact_l1_mm: f64,
    pub contact_pixels: usize,
}

impl ImageErrors {
    pub fn of(id: u32, split: &str, pred_mm: &[f32], true_mm: &[f32], mask: &[bool]) -> Self {
        let (mut n, mut l1, mut l2, mut zero) = (0usize, 0f64, 0f64, 0f64);
        let (mut nc, mut cl1, mut czero) = (0usize, 0f64, 0f64);
        for ((&p, &t), &m) in pred_mm.iter().zip(true_mm).zip(mask) {
            if !m {
                continue;
            }
            let e = (p - t).abs() as f64;
            n += 1;
            l1 += e;
            l2 += e * e;
            zero += t.abs() as f64;
            if t > CONTACT_THRESHOLD_MM {
                nc += 1;
                cl1 += e;
                czero += t as f64;
            }
        }
        let n = n.max(1) as f64;
        let per_contact = |s: f64| if nc > 0 { s / nc as f64 } else { f64::NAN };
        ImageErrors {
            id,
            split: split.to_string(),
            l1_mm: l1 / n,
            l2_mm: l2 / n,
            contact_l1_mm: per_contact(cl1),
            zero_l1_mm: zero / n,
            zero_contact_l1_mm: per_contact(czero),
            contact_pixels: nc,
        }
    }
}

/// Summary statistics of a set of values (NaNs left out).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    pub n: usize,
    pub mean: f64,
    pub sd: f64,
    pub median: f64,
    pub q1: f64,
    pub q3: f64,
    pub min: f64,
    pub max: f64,
}

impl Summary {
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 {
            return Summary {
                n,
                mean: f64::NAN,
                sd: f64::NAN,
                median: f64::NAN,
                q1: f64::NAN,
                q3: f64::NAN,
                min: f64::NAN,
                max: f64::NAN,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        // Sample standard deviation (n - 1), zero for one value.
        let sd = if n > 1 { (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt() } else { 0.0 };
        Summary {
            n,
            mean,
            sd,
            median: quantile(&v, 0.5),
            q1: quantile(&v, 0.25),
            q3: quantile(&v, 0.75),
            min: v[0],
            max: v[n - 1],
        }
    }
}

/// Linear-interpolation quantile of sorted values (numpy's default).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < sorted.len() { sorted[i] * (1.0 - f) + sorted[i + 1] * f } else { sorted[i] }
}

/// `stats.json` for one split.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SplitStats {
    pub l1_mm: Summary,
    pub l2_mm: Summary,
    pub contact_l1_mm: Summary,
    pub zero_l1_mm: Summary,
    pub zero_contact_l1_mm: Summary,
    /// Frames the contact gate answered without running the network.
    pub skipped_frames: usize,
}

impl SplitStats {
    pub fn of(images: &[ImageErrors], skipped_frames: usize) -> Self {
        let s = |f: fn(&ImageErrors) -> f64| Summary::of(images.iter().map(f));
        SplitStats {
            l1_mm: s(|e| e.l1_mm),
            l2_mm: s(|e| e.l2_mm),
            contact_l1_mm: s(|e| e.contact_l1_mm),
            zero_l1_mm: s(|e| e.zero_l1_mm),
            zero_contact_l1_mm: s(|e| e.zero_contact_l1_mm),
            skipped_frames,
        }
    }
}

/// Evaluates `predictor` on the named splits of a dataset folder (with images), printing one
/// line per split, and writes `out/stats.json` (keyed by split), `errors.csv` and `violin.svg`.
pub fn evaluate_dataset(
    predictor: &Predictor,
    data: &Path,
    splits: &[Split],
    out: &Path,
) -> Result<BTreeMap<String, SplitStats>> {
    formats::output::check_dir(out, OutputKind::Evaluation, &[data, &predictor.dir])?;
    let manifest = Manifest::load(data)?;
    let crop = predictor.file.sensor.crop_size_px;
    let mut stats = BTreeMap::new();
    let mut rows = Vec::new();
    let mut groups = Vec::new();
    for &split in splits {
        let name = split.name();
        let (mut errors, mut skipped) = (Vec::new(), 0);
        let chosen: Vec<&SampleRecord> = manifest.split(Some(split)).collect();
        if chosen.is_empty() {
            anyhow::bail!("{}: the dataset has no {name} samples to evaluate", data.join("manifest.json").display());
        }
        for (k, s) in chosen.iter().enumerate() {
            let id = s.id;
            let image_rel = s.image.as_ref().with_context(|| format!("sample {id} has no image"))?;
            let image_path = data.join(image_rel);
            let frame = predictor.read_frame(&image_path)?;
            let depth_path = data.join(&s.depth);
            let truth = sensor::DepthMap::load_png_um(&depth_path)?;
            if truth.size_px != crop {
                anyhow::bail!(
                    "{}: depth map is {}x{0}, the bundle's crop is {crop}",
                    depth_path.display(),
                    truth.size_px
                );
            }
            let (pred, ran) = predictor.predict_gated(&frame).with_context(|| format!("{}", image_path.display()))?;
            if !ran {
                skipped += 1;
            }
            errors.push(ImageErrors::of(id, name, &pred.depth_mm, &truth.depth_mm, &predictor.mask));
            if (k + 1) % 50 == 0 {
                eprintln!("{name}: {}/{}", k + 1, chosen.len());
            }
        }
        let s = SplitStats::of(&errors, skipped);
        println!(
            "{name:5}: {} images, L1 {:.4} mm (zeros {:.4}), contact L1 {:.4} mm (zeros {:.4}), L2 {:.5} mm^2; {skipped} frames without contact",
            s.l1_mm.n, s.l1_mm.mean, s.zero_l1_mm.mean, s.contact_l1_mm.mean, s.zero_contact_l1_mm.mean, s.l2_mm.mean
        );
        groups.push((name, errors.iter().map(|e| e.l1_mm).collect::<Vec<_>>()));
        stats.insert(name.to_string(), s);
        rows.extend(errors);
    }
    let stats_json = serde_json::to_string_pretty(&stats)?;
    let mut csv = String::from("id,split,l1_mm,l2_mm,contact_l1_mm,zero_l1_mm,zero_contact_l1_mm,contact_pixels\n");
    for e in &rows {
        csv += &format!(
            "{},{},{},{},{},{},{},{}\n",
            e.id, e.split, e.l1_mm, e.l2_mm, e.contact_l1_mm, e.zero_l1_mm, e.zero_contact_l1_mm, e.contact_pixels
        );
    }
    let groups: Vec<(&str, Vec<f64>)> = groups.into_iter().collect();
    let violin = crate::plot::violin_svg(&groups)?;
    // The three files replace a previous evaluation together, or not at all.
    formats::fs::write_dir_atomic(out, |tmp| -> Result<()> {
        write_atomic(&tmp.join("stats.json"), stats_json.as_bytes())?;
        write_atomic(&tmp.join("errors.csv"), csv.as_bytes())?;
        write_atomic(&tmp.join("violin.svg"), violin.as_bytes())?;
        formats::output::mark(tmp, OutputKind::Evaluation)?;
        Ok(())
    })?;
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_of_a_hand_made_prediction() {
        // Four useful pixels (one masked out): truth 0, 0, 1, 2 mm; prediction 0.5, 0, 1.5, 1.
        let truth = [0.0, 0.0, 1.0, 2.0, 9.0];
        let pred = [0.5, 0.0, 1.5, 1.0, 0.0];
        let mask = [true, true, true, true, false];
        let e = ImageErrors::of(3, "test", &pred, &truth, &mask);
        assert!((e.l1_mm - 2.0 / 4.0).abs() < 1e-12);
        assert!((e.l2_mm - (0.25 + 0.25 + 1.0) / 4.0).abs() < 1e-12);
        assert!((e.contact_l1_mm - 1.5 / 2.0).abs() < 1e-12);
        assert!((e.zero_l1_mm - 3.0 / 4.0).abs() < 1e-12);
        assert!((e.zero_contact_l1_mm - 1.5).abs() < 1e-12);
        assert_eq!(e.contact_pixels, 2);
        let none = ImageErrors::of(4, "test", &[0.0; 2], &[0.0; 2], &[true; 2]);
        assert!(none.contact_l1_mm.is_nan() && none.l1_mm == 0.0);
    }

    #[test]
    fn summaries_match_hand_computed_values() {
        let s = Summary::of([4.0, 1.0, 3.0, 2.0, f64::NAN]);
        assert_eq!((s.n, s.min, s.max), (4, 1.0, 4.0));
        assert!((s.mean - 2.5).abs() < 1e-12);
        assert!((s.sd - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert!((s.median - 2.5).abs() < 1e-12);
        assert!((s.q1 - 1.75).abs() < 1e-12 && (s.q3 - 3.25).abs() < 1e-12);
    }
}
