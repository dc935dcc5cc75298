//! How much contact changes a unit's frames: the measurement its reference difference's gain is
//! fitted to ([`model::InputEncoding::fitted`]). Gels differ: where they are pressed, the
//! project's renderer's units change by 0.019 to 0.029 of the range on average, the
//! independently modelled gels (`gelcam`) by 0.007 to 0.017 (BENCHMARKS.md), and a fixed gain
//! would hand the network one unit's contact at a third of the size of another's.

use std::path::Path;

use anyhow::Result;
use formats::dataset::{Manifest, Split};
use image::RgbImage;
use rayon::prelude::*;
use sensor::{CONTACT_THRESHOLD_MM, Sensor};

use crate::gate::read_labelled;

/// Train frames with contact read for the measurement, spread evenly over the split, so that
/// it costs under a second (0.25 to 0.5 s at the quickstart's 128x128 on this project's 2-core
/// machine).
pub(crate) const GAIN_SAMPLES: usize = 64;

/// Sum and count of the per-pixel change over one frame's labelled contact pixels.
type Tally = (f64, u64);

/// The mean over the labelled contact pixels of the unit in `dir` of |frame - reference| (the
/// three channels' mean, in [0, 1]) at the network's input size `hw`, each frame read against
/// its own untouched frame where it has one and against `reference` otherwise; from up to
/// [`GAIN_SAMPLES`] train frames with contact. `None` where the split has no contact pixel. A
/// frame or depth map that cannot be decoded is left out (training reports it by its own rule);
/// a failing read is an error.
pub(crate) fn contact_change(dir: &Path, sensor: &Sensor, hw: [usize; 2], reference: &RgbImage) -> Result<Option<f64>> {
    let manifest = Manifest::load(dir)?;
    let touched: Vec<_> =
        manifest.split(Some(Split::Train)).filter(|s| s.image.is_some() && s.stats.contact_fraction > 0.0).collect();
    let n = touched.len();
    let picked: Vec<_> = (0..n.min(GAIN_SAMPLES)).map(|k| touched[k * n / n.min(GAIN_SAMPLES)]).collect();
    let crop = sensor.crop_size_px;
    let inside = sensor::resample::covered_mask(&sensor.valid_mask(), crop as usize, hw);
    let unit_reference = model::input::resized(reference, hw);
    let tallies: Vec<Result<Option<Tally>>> = picked
        .par_iter()
        .map(|s| {
            let Some(l) = read_labelled(dir, s, sensor, true)? else { return Ok(None) };
            if l.depth.size_px != crop {
                return Ok(None);
            }
            let own = l.own_reference.map(|own| model::input::resized(&own, hw));
            let depth = sensor::resample::resize_plane(&l.depth.depth_mm, [crop as usize; 2], hw);
            let frame = model::input::resized(&l.frame, hw);
            Ok(Some(tally(&frame, own.as_ref().unwrap_or(&unit_reference), &depth, &inside)))
        })
        .collect();
    let (mut sum, mut count) = (0.0, 0);
    for t in tallies {
        if let Some((s, c)) = t? {
            sum += s;
            count += c;
        }
    }
    Ok((count > 0).then(|| sum / count as f64))
}

/// The change summed over the pixels of `frame` that are inside and labelled in contact.
fn tally(frame: &RgbImage, reference: &RgbImage, depth_mm: &[f32], inside: &[bool]) -> Tally {
    let (mut sum, mut count) = (0.0, 0);
    for (k, (a, b)) in frame.pixels().zip(reference.pixels()).enumerate() {
        if inside[k] && depth_mm[k] > CONTACT_THRESHOLD_MM {
            let d: u32 = (0..3).map(|c| a.0[c].abs_diff(b.0[c]) as u32).sum();
            sum += d as f64 / (3.0 * 255.0);
            count += 1;
        }
    }
    (sum, count)
}
