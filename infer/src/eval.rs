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

pub use crate::plot::GROUND_TRUTH_UNCERTAINTY_MM;
pub use formats::stats::Summary;

/// One image's errors.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageErrors {
    pub id: u32,
    pub split: formats::Split,
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
    /// Mean absolute error over the contact boundary: useful pixels within [`BOUNDARY_PX`] of
    /// a true contact edge (mm), where a blurred prediction errs most; NaN without an edge.
    pub boundary_l1_mm: f64,
    /// The zero predictor's over the same pixels (mm).
    pub zero_boundary_l1_mm: f64,
    pub boundary_pixels: usize,
    /// The force figures of a bundle with the pressure output, for a sample with a wrench
    /// label ([`ImageErrors::with_force`]); NaN otherwise. The true total force |F| (N).
    pub force_n: f64,
    /// The predicted |F| (N).
    pub pred_force_n: f64,
    /// |F_pred - F_true| (N): direction and size.
    pub force_error_n: f64,
    /// ||F_pred| - |F_true|| (N): the total normal force's error.
    pub force_magnitude_error_n: f64,
    /// Mean absolute pressure error over useful pixels (kPa), where the sample has a pressure map.
    pub pressure_l1_kpa: f64,
}

/// Crop pixels on either side of a true contact edge that count as the contact boundary.
pub const BOUNDARY_PX: usize = 3;

/// The contact boundary of a square depth map (row-major, side `size`): pixels within
/// `radius` (Chebyshev distance) of a pixel whose contact state differs from one of its four
/// neighbours'. Two running-window passes, linear in the pixel count.
pub fn boundary_band(true_mm: &[f32], size: usize, radius: usize) -> Vec<bool> {
    let contact = |i: usize| true_mm[i] > CONTACT_THRESHOLD_MM;
    let mut edge = vec![false; size * size];
    for y in 0..size {
        for x in 0..size {
            let i = y * size + x;
            let c = contact(i);
            let right = x + 1 < size && contact(i + 1) != c;
            let down = y + 1 < size && contact(i + size) != c;
            if right {
                edge[i] = true;
                edge[i + 1] = true;
            }
            if down {
                edge[i] = true;
                edge[i + size] = true;
            }
        }
    }
    // Dilate along rows, then along columns: a window of 2 radius + 1 holds an edge pixel.
    let dilate = |src: &[bool], stride: usize, step: usize| -> Vec<bool> {
        let mut out = vec![false; size * size];
        for line in 0..size {
            let at = |k: usize| line * stride + k * step;
            let mut count = 0usize;
            for k in 0..size.min(radius + 1) {
                count += src[at(k)] as usize;
            }
            for k in 0..size {
                out[at(k)] = count > 0;
                if k + radius + 1 < size {
                    count += src[at(k + radius + 1)] as usize;
                }
                if k >= radius {
                    count -= src[at(k - radius)] as usize;
                }
            }
        }
        out
    };
    let rows = dilate(&edge, size, 1);
    dilate(&rows, 1, size)
}

impl ImageErrors {
    pub fn of(id: u32, split: formats::Split, pred_mm: &[f32], true_mm: &[f32], mask: &[bool]) -> Self {
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
        let size = (true_mm.len() as f64).sqrt() as usize;
        let (mut nb, mut bl1, mut bzero) = (0usize, 0f64, 0f64);
        if size * size == true_mm.len() && nc > 0 {
            let band = boundary_band(true_mm, size, BOUNDARY_PX);
            for (((&p, &t), &m), &b) in pred_mm.iter().zip(true_mm).zip(mask).zip(&band) {
                if m && b {
                    nb += 1;
                    bl1 += (p - t).abs() as f64;
                    bzero += t.abs() as f64;
                }
            }
        }
        let n = n.max(1) as f64;
        let per_contact = |s: f64| if nc > 0 { s / nc as f64 } else { f64::NAN };
        let per_boundary = |s: f64| if nb > 0 { s / nb as f64 } else { f64::NAN };
        ImageErrors {
            id,
            split,
            l1_mm: l1 / n,
            l2_mm: l2 / n,
            contact_l1_mm: per_contact(cl1),
            zero_l1_mm: zero / n,
            zero_contact_l1_mm: per_contact(czero),
            contact_pixels: nc,
            boundary_l1_mm: per_boundary(bl1),
            zero_boundary_l1_mm: per_boundary(bzero),
            boundary_pixels: nb,
            force_n: f64::NAN,
            pred_force_n: f64::NAN,
            force_error_n: f64::NAN,
            force_magnitude_error_n: f64::NAN,
            pressure_l1_kpa: f64::NAN,
        }
    }

    /// Adds the force figures: `pred` against the sample's wrench and, where it has one, its
    /// pressure map (kPa, crop grid; over the `mask`'s pixels).
    pub fn with_force(
        mut self,
        pred: &crate::Force,
        truth: &sensor::Wrench,
        pressure: Option<&[f32]>,
        mask: &[bool],
    ) -> Self {
        self.force_n = truth.force_magnitude_n();
        self.pred_force_n = pred.wrench.force_magnitude_n();
        self.force_error_n = pred.wrench.force_distance_n(truth);
        self.force_magnitude_error_n = (self.pred_force_n - self.force_n).abs();
        if let Some(p) = pressure {
            let (mut n, mut sum) = (0usize, 0f64);
            for ((&a, &b), &m) in pred.pressure.pressure_kpa.iter().zip(p).zip(mask) {
                if m {
                    n += 1;
                    sum += (a - b).abs() as f64;
                }
            }
            self.pressure_l1_kpa = sum / n.max(1) as f64;
        }
        self
    }
}

/// The keys of each split's figures in `stats.json`, in the order [`SplitStats`] writes them.
pub const STAT_KEYS: [&str; 7] =
    ["contact_l1_mm", "zero_contact_l1_mm", "l1_mm", "zero_l1_mm", "l2_mm", "boundary_l1_mm", "zero_boundary_l1_mm"];

/// `stats.json` for one split: contact first (where the sensor is pressed), then the paper's
/// useful-pixel figures, then the contact boundary.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct SplitStats {
    pub contact_l1_mm: Summary,
    pub zero_contact_l1_mm: Summary,
    pub l1_mm: Summary,
    pub zero_l1_mm: Summary,
    pub l2_mm: Summary,
    pub boundary_l1_mm: Summary,
    pub zero_boundary_l1_mm: Summary,
    /// Frames the contact gate answered without running the network.
    pub skipped_frames: usize,
    /// Of those, frames whose ground truth has contact: answered with zeros by mistake.
    pub gated_contact_frames: usize,
    /// The force figures, for a bundle with the pressure output and samples with wrench labels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force: Option<ForceStats>,
}

/// A split's force figures (see [`ImageErrors`]'s force fields).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct ForceStats {
    /// The true total force |F| (N).
    pub force_n: Summary,
    pub force_error_n: Summary,
    pub force_magnitude_error_n: Summary,
    /// The mean total-force error as a percentage of the split's mean total force.
    pub force_magnitude_error_pct: f64,
    pub pressure_l1_kpa: Summary,
    /// Frames with a force label whose predicted contact the solver could not settle: they
    /// have no predicted force, so the figures above leave them out; counted here so that
    /// they are not lost silently.
    #[serde(default)]
    pub unsolved_frames: usize,
}

impl ForceStats {
    fn of(images: &[ImageErrors], unsolved_frames: usize) -> Option<Self> {
        let s = |f: fn(&ImageErrors) -> f64| Summary::of(images.iter().map(f));
        let force_n = s(|e| e.force_n);
        let magnitude = s(|e| e.force_magnitude_error_n);
        (force_n.n > 0 || unsolved_frames > 0).then(|| ForceStats {
            unsolved_frames,
            force_magnitude_error_pct: 100.0 * magnitude.mean / force_n.mean,
            force_error_n: s(|e| e.force_error_n),
            force_magnitude_error_n: magnitude,
            pressure_l1_kpa: s(|e| e.pressure_l1_kpa),
            force_n,
        })
    }

    /// The split's force headline.
    pub fn headline(&self) -> String {
        let unsolved = match self.unsolved_frames {
            0 => String::new(),
            n => format!("; {n} frames left out: their predicted contact could not be solved"),
        };
        format!(
            "total force error {:.3} N ({:.1} % of the mean {:.2} N), force vector error {:.3} N, pressure L1 {:.2} kPa{unsolved}",
            self.force_magnitude_error_n.mean,
            self.force_magnitude_error_pct,
            self.force_n.mean,
            self.force_error_n.mean,
            self.pressure_l1_kpa.mean
        )
    }
}

impl SplitStats {
    /// The summaries by their keys in `stats.json` ([`STAT_KEYS`]).
    pub fn summaries(&self) -> [(&'static str, &Summary); 7] {
        let all = [
            &self.contact_l1_mm,
            &self.zero_contact_l1_mm,
            &self.l1_mm,
            &self.zero_l1_mm,
            &self.l2_mm,
            &self.boundary_l1_mm,
            &self.zero_boundary_l1_mm,
        ];
        std::array::from_fn(|k| (STAT_KEYS[k], all[k]))
    }

    /// `unsolved_force_frames`: see [`ForceStats::unsolved_frames`].
    pub fn of(
        images: &[ImageErrors],
        skipped_frames: usize,
        gated_contact_frames: usize,
        unsolved_force_frames: usize,
    ) -> Self {
        let s = |f: fn(&ImageErrors) -> f64| Summary::of(images.iter().map(f));
        SplitStats {
            contact_l1_mm: s(|e| e.contact_l1_mm),
            zero_contact_l1_mm: s(|e| e.zero_contact_l1_mm),
            l1_mm: s(|e| e.l1_mm),
            zero_l1_mm: s(|e| e.zero_l1_mm),
            l2_mm: s(|e| e.l2_mm),
            boundary_l1_mm: s(|e| e.boundary_l1_mm),
            zero_boundary_l1_mm: s(|e| e.zero_boundary_l1_mm),
            skipped_frames,
            gated_contact_frames,
            force: ForceStats::of(images, unsolved_force_frames),
        }
    }

    /// Contact L1 as a fraction of the zero predictor's (1: no better than answering zero).
    pub fn contact_ratio(&self) -> f64 {
        self.contact_l1_mm.mean / self.zero_contact_l1_mm.mean
    }

    /// The split's headline: contact L1 and its ratio to zeros, useful-pixel L1, boundary L1.
    pub fn headline(&self) -> String {
        format!(
            "contact L1 {:.4} mm ({:.2} of zeros' {:.4}), L1 {:.4} mm (zeros {:.4}), boundary L1 {:.4} mm (zeros {:.4})",
            self.contact_l1_mm.mean,
            self.contact_ratio(),
            self.zero_contact_l1_mm.mean,
            self.l1_mm.mean,
            self.zero_l1_mm.mean,
            self.boundary_l1_mm.mean,
            self.zero_boundary_l1_mm.mean
        )
    }
}

/// What differs between the dataset's sensor and the bundle's, when they are not the same unit
/// (a base model read on a unit it was not made for is a legitimate test, but not a silent one).
pub fn other_unit(data: &sensor::Sensor, bundle: &sensor::Sensor) -> Option<String> {
    if data == bundle {
        return None;
    }
    let (a, b) = (&data.correspondence, &bundle.correspondence);
    let centre_px = (a.centre_u_px - b.centre_u_px).hypot(a.centre_v_px - b.centre_v_px);
    Some(format!(
        "its sensor is not the bundle's (optical centres {centre_px:.2} px apart{}); frames are read through the \
         bundle's geometry and scored against the dataset's labels",
        if a.radial == b.radial { "" } else { ", other lens maps" }
    ))
}

/// Evaluates `predictor` on the named splits of a dataset folder (with images), printing one
/// line per split, and writes `out/stats.json` (keyed by split), `errors.csv` and `violin.svg`.
pub fn evaluate_dataset(
    predictor: &Predictor,
    data: &Path,
    splits: &[Split],
    out: &Path,
) -> Result<BTreeMap<Split, SplitStats>> {
    formats::output::check_dir(out, OutputKind::Evaluation, &[data, &predictor.dir])?;
    let manifest = Manifest::load(data)?;
    if let Some(note) = other_unit(&manifest.sensor, &predictor.file.sensor) {
        eprintln!("note: {}: {note}", data.join("manifest.json").display());
    }
    let crop = predictor.file.sensor.crop_size_px;
    let mut stats = BTreeMap::new();
    let mut rows = Vec::new();
    let (mut groups, mut force_groups) = (Vec::new(), Vec::new());
    for &split in splits {
        let name = split.name();
        let (mut errors, mut skipped, mut gated_contact, mut unsolved) = (Vec::new(), 0, 0, 0);
        let chosen: Vec<&SampleRecord> = manifest.split(Some(split)).collect();
        if chosen.is_empty() {
            anyhow::bail!("{}: the dataset has no {name} samples to evaluate", data.join("manifest.json").display());
        }
        // Samples rendered under their own looks are read against their own untouched frames.
        let mut restyled = chosen.iter().any(|s| s.reference.is_some()).then(|| predictor.clone());
        for (k, s) in chosen.iter().enumerate() {
            let id = s.id;
            let predictor = match (&mut restyled, &s.reference) {
                (Some(own), Some(rel)) => {
                    let path = data.join(rel);
                    let reference = sensor::frame::read_reference(&path, crop)?;
                    own.set_reference(reference).with_context(|| format!("{}", path.display()))?;
                    &*own
                }
                _ => predictor,
            };
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
            let pred = predictor.predict_all(&frame).with_context(|| format!("{}", image_path.display()))?;
            if !pred.network_ran {
                skipped += 1;
                gated_contact += usize::from(truth.depth_mm.iter().any(|&d| d > sensor::CONTACT_THRESHOLD_MM));
            }
            let mut e = ImageErrors::of(id, split, &pred.depth.depth_mm, &truth.depth_mm, &predictor.mask);
            if predictor.has_force() && pred.force.is_none() && s.force_label().is_some() {
                unsolved += 1;
            }
            if let (Some(force), Some(wrench)) = (&pred.force, s.force_label()) {
                let pressure = match &s.pressure {
                    Some(rel) => {
                        let path = data.join(rel);
                        let p = sensor::PressureMap::load_png(&path)?;
                        if p.size_px != crop {
                            anyhow::bail!(
                                "{}: pressure map is {}x{0}, the bundle's crop is {crop}",
                                path.display(),
                                p.size_px
                            );
                        }
                        Some(p)
                    }
                    None => None,
                };
                e = e.with_force(force, wrench, pressure.as_ref().map(|p| p.pressure_kpa.as_slice()), &predictor.mask);
            }
            errors.push(e);
            if (k + 1) % 50 == 0 {
                eprintln!("{name}: {}/{}", k + 1, chosen.len());
            }
        }
        let s = SplitStats::of(&errors, skipped, gated_contact, unsolved);
        println!(
            "{name:5}: {} images, {}, L2 {:.5} mm^2; {skipped} frames answered by the contact gate, {gated_contact} of \
             them with contact",
            s.l1_mm.n,
            s.headline(),
            s.l2_mm.mean
        );
        if let Some(f) = &s.force {
            println!("{name:5}: {} images with force labels, {}", f.force_n.n, f.headline());
        }
        groups.push((name, errors.iter().map(|e| e.l1_mm).collect::<Vec<_>>()));
        force_groups.push((name, errors.iter().map(|e| e.force_error_n).collect::<Vec<_>>()));
        stats.insert(split, s);
        rows.extend(errors);
    }
    let stats_json = serde_json::to_string_pretty(&stats)?;
    let mut csv = csv::Writer::from_writer(Vec::new());
    csv.write_record([
        "id",
        "split",
        "contact_l1_mm",
        "zero_contact_l1_mm",
        "contact_pixels",
        "l1_mm",
        "zero_l1_mm",
        "l2_mm",
        "boundary_l1_mm",
        "zero_boundary_l1_mm",
        "boundary_pixels",
        "force_n",
        "pred_force_n",
        "force_error_n",
        "force_magnitude_error_n",
        "pressure_l1_kpa",
    ])?;
    for e in &rows {
        csv.write_record([
            e.id.to_string(),
            e.split.name().to_string(),
            e.contact_l1_mm.to_string(),
            e.zero_contact_l1_mm.to_string(),
            e.contact_pixels.to_string(),
            e.l1_mm.to_string(),
            e.zero_l1_mm.to_string(),
            e.l2_mm.to_string(),
            e.boundary_l1_mm.to_string(),
            e.zero_boundary_l1_mm.to_string(),
            e.boundary_pixels.to_string(),
            e.force_n.to_string(),
            e.pred_force_n.to_string(),
            e.force_error_n.to_string(),
            e.force_magnitude_error_n.to_string(),
            e.pressure_l1_kpa.to_string(),
        ])?;
    }
    let csv = csv.into_inner().map_err(|e| anyhow::anyhow!("errors.csv: {e}"))?;
    let groups: Vec<(&str, Vec<f64>)> = groups.into_iter().collect();
    let violin = crate::plot::violin_svg(&groups)?;
    let with_force = stats.values().any(|s: &SplitStats| s.force.is_some());
    let force_violin = match with_force {
        true => Some(crate::plot::violin_svg_on(&force_groups, &crate::plot::ViolinAxis::force())?),
        false => None,
    };
    // The three files replace a previous evaluation together, or not at all.
    formats::fs::write_dir_atomic(out, |tmp| -> Result<()> {
        write_atomic(&tmp.join("stats.json"), stats_json.as_bytes())?;
        write_atomic(&tmp.join("errors.csv"), &csv)?;
        write_atomic(&tmp.join("violin.svg"), violin.as_bytes())?;
        if let Some(svg) = &force_violin {
            write_atomic(&tmp.join("force_violin.svg"), svg.as_bytes())?;
        }
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
        let e = ImageErrors::of(3, formats::Split::Test, &pred, &truth, &mask);
        assert!((e.l1_mm - 2.0 / 4.0).abs() < 1e-12);
        assert!((e.l2_mm - (0.25 + 0.25 + 1.0) / 4.0).abs() < 1e-12);
        assert!((e.contact_l1_mm - 1.5 / 2.0).abs() < 1e-12);
        assert!((e.zero_l1_mm - 3.0 / 4.0).abs() < 1e-12);
        assert!((e.zero_contact_l1_mm - 1.5).abs() < 1e-12);
        assert_eq!(e.contact_pixels, 2);
        let none = ImageErrors::of(4, formats::Split::Test, &[0.0; 2], &[0.0; 2], &[true; 2]);
        assert!(none.contact_l1_mm.is_nan() && none.l1_mm == 0.0);
    }

    #[test]
    fn the_boundary_of_a_square_patch_is_a_ring() {
        // A 10x10 contact patch at [5, 15) in a 20x20 map: its edge pixels are its own outer ring
        // and the ring around it less that ring's four corners (they touch the patch diagonally
        // only); within 1 px of them lie rows and columns 3..=16, less the inside 7..=12 and the
        // four outermost corners.
        let size = 20;
        let mut truth = vec![0f32; size * size];
        for y in 5..15 {
            for x in 5..15 {
                truth[y * size + x] = 1.0;
            }
        }
        let band = boundary_band(&truth, size, 1);
        assert_eq!(band.iter().filter(|&&b| b).count(), 14 * 14 - 6 * 6 - 4);
        assert!(band[3 * size + 4] && band[16 * size + 15] && !band[3 * size + 3] && !band[2 * size + 5]);
        assert!(!band[10 * size + 10] && band[7 * size + 6] && !band[7 * size + 7]);
        assert_eq!(
            boundary_band(&truth, size, 0).iter().filter(|&&b| b).count(),
            10 * 10 - 8 * 8 + 12 * 12 - 10 * 10 - 4
        );
        // A prediction right inside and outside but 0.5 mm off on the edge pixels' band.
        let mut pred = truth.clone();
        let band3 = boundary_band(&truth, size, BOUNDARY_PX);
        for (p, &b) in pred.iter_mut().zip(&band3) {
            if b {
                *p += 0.5;
            }
        }
        let e = ImageErrors::of(1, formats::Split::Test, &pred, &truth, &vec![true; size * size]);
        assert!((e.boundary_l1_mm - 0.5).abs() < 1e-6, "{e:?}");
        assert_eq!(e.boundary_pixels, band3.iter().filter(|&&b| b).count());
        // Zeros err by the true depth on the band: 1 mm on its contact half, 0 outside.
        let inside = band3.iter().zip(&truth).filter(|&(&b, &t)| b && t > 0.0).count();
        assert!((e.zero_boundary_l1_mm - inside as f64 / e.boundary_pixels as f64).abs() < 1e-9);
        let flat = ImageErrors::of(2, formats::Split::Test, &[0.0; 16], &[0.0; 16], &[true; 16]);
        assert!(flat.boundary_l1_mm.is_nan() && flat.boundary_pixels == 0);
    }

    #[test]
    fn stat_keys_are_the_written_ones() {
        let stats =
            SplitStats::of(&[ImageErrors::of(1, formats::Split::Test, &[0.0; 4], &[1.0; 4], &[true; 4])], 0, 0, 0);
        let json = serde_json::to_value(&stats).unwrap();
        let counts = ["skipped_frames", "gated_contact_frames"];
        let keys: Vec<&String> = json.as_object().unwrap().keys().filter(|k| !counts.contains(&k.as_str())).collect();
        assert_eq!(keys.len(), STAT_KEYS.len());
        assert!(STAT_KEYS.iter().all(|k| json[*k]["mean"].is_number() || json[*k]["n"] == 0), "{json}");
    }

    /// Frames whose predicted contact was not solved are counted beside the force figures,
    /// which are taken over the solved frames only; a split of such frames alone still says so.
    #[test]
    fn unsolved_force_frames_are_counted_not_dropped() {
        let wrench = |fz: f64| sensor::Wrench { force_n: [0.0, 0.0, fz], torque_nmm: [0.0; 3] };
        let force = |fz: f64| crate::Force {
            pressure: sensor::PressureMap { size_px: 2, pressure_kpa: vec![0.0; 4] },
            wrench: wrench(fz),
        };
        let image = |id: u32| ImageErrors::of(id, formats::Split::Test, &[0.0; 4], &[1.0; 4], &[true; 4]);
        let solved = [
            image(1).with_force(&force(-9.0), &wrench(-10.0), None, &[true; 4]),
            image(2).with_force(&force(-33.0), &wrench(-30.0), None, &[true; 4]),
            image(3),
        ];
        let stats = SplitStats::of(&solved, 0, 0, 2).force.expect("force figures");
        assert_eq!((stats.force_n.n, stats.unsolved_frames), (2, 2));
        assert!((stats.force_magnitude_error_pct - 100.0 * 2.0 / 20.0).abs() < 1e-9, "{stats:?}");
        assert!(stats.headline().contains("2 frames left out"), "{}", stats.headline());
        let json = serde_json::to_value(&stats).unwrap();
        assert_eq!(json["unsolved_frames"], 2);
        assert!(!SplitStats::of(&solved, 0, 0, 0).force.unwrap().headline().contains("left out"));
        let none = SplitStats::of(&[image(4)], 0, 0, 1).force.expect("an unsolved frame alone is reported");
        assert_eq!((none.force_n.n, none.unsolved_frames), (0, 1));
        assert!(SplitStats::of(&[image(4)], 0, 0, 0).force.is_none());
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

#[cfg(test)]
mod unit_tests {
    use super::*;

    #[test]
    fn another_units_dataset_is_named() {
        let a = sensor::Sensor::default();
        assert_eq!(other_unit(&a, &a), None);
        let mut b = a.clone();
        b.correspondence.centre_u_px += 3.0;
        b.correspondence.centre_v_px += 4.0;
        let note = other_unit(&b, &a).expect("another unit");
        assert!(note.contains("5.00 px apart") && !note.contains("lens"), "{note}");
    }
}
