//! The bundle's contact gate, fitted to the unit's own labelled frames when the bundle is made
//! (`sensor::gate`), and what it does on each split.

use std::path::Path;

use anyhow::{Context, Result};
use formats::dataset::{Manifest, SampleRecord, Split};
use image::RgbImage;
use model::bundle::GateRecord;
use rayon::prelude::*;
use sensor::gate::{GateFrame, Tally, fit};
use sensor::{DepthMap, Sensor};

/// The gate for the dataset `data` (its train split) with its tally on each split; `None`
/// where the dataset has no reference frame or no train frame with contact (no gate: the
/// network runs on every frame). With `skip_bad`, a frame or depth map that cannot be decoded
/// is left out (training counted and reported it); a failing read is an error either way.
pub fn fit_gate(data: &Path, skip_bad: bool) -> Result<Option<GateRecord>> {
    let manifest = Manifest::load(data)?;
    let reference_path = data.join("unit/reference.png");
    if !reference_path.is_file() {
        return Ok(None);
    }
    let sensor = &manifest.sensor;
    let reference = sensor::frame::read_reference(&reference_path, sensor.crop_size_px)?;
    let mask = sensor.valid_mask();
    let measure = |split: Split| -> Result<Vec<GateFrame>> {
        let records: Vec<_> = manifest.split(Some(split)).collect();
        let measured: Vec<Result<Option<GateFrame>>> = records
            .par_iter()
            .filter(|s| s.image.is_some())
            .map(|s| {
                let Some(l) = read_labelled(data, s, sensor, skip_bad)? else { return Ok(None) };
                // A sample under its own look is gated against its own untouched frame.
                let own = l.own_reference.as_ref().unwrap_or(&reference);
                Ok(Some(GateFrame::labelled(&l.frame, own, &mask, &l.depth)))
            })
            .collect();
        Ok(measured.into_iter().collect::<Result<Vec<_>>>()?.into_iter().flatten().collect())
    };
    let train = measure(Split::Train)?;
    let Some(gate) = fit(&train) else { return Ok(None) };
    let test = measure(Split::Test)?;
    Ok(Some(GateRecord { gate, train: Tally::of(&gate, &train), test: Tally::of(&gate, &test) }))
}

/// A labelled sample as read from its dataset: its crop, its own untouched frame where it was
/// rendered under its own look, and its depth map.
pub(crate) struct Labelled {
    pub(crate) frame: RgbImage,
    pub(crate) own_reference: Option<RgbImage>,
    pub(crate) depth: DepthMap,
}

/// Sample `s` (which has an image) of the dataset in `data`: `None` where one of its files
/// cannot be decoded and `skip_bad` leaves it out; a failing read is an error either way.
pub(crate) fn read_labelled(
    data: &Path,
    s: &SampleRecord,
    sensor: &Sensor,
    skip_bad: bool,
) -> Result<Option<Labelled>> {
    let image = s.image.as_ref().context("the sample has no camera image")?;
    let Some(frame) = readable(sensor::frame::read_crop(&data.join(image), sensor), skip_bad)? else {
        return Ok(None);
    };
    let Some(depth) = read_depth(&data.join(&s.depth), skip_bad)? else { return Ok(None) };
    let own_reference = match &s.reference {
        Some(rel) => {
            let Some(own) = readable(sensor::frame::read_reference(&data.join(rel), sensor.crop_size_px), skip_bad)?
            else {
                return Ok(None);
            };
            Some(own)
        }
        None => None,
    };
    Ok(Some(Labelled { frame, own_reference, depth }))
}

/// The depth map at `path`: `None` where it cannot be decoded and `skip_bad` leaves it out; a
/// failing read is an error either way.
pub(crate) fn read_depth(path: &Path, skip_bad: bool) -> Result<Option<DepthMap>> {
    let bytes = std::fs::read(path).with_context(|| format!("{}", path.display()))?;
    match DepthMap::decode_png_um(path, &bytes) {
        Ok(d) => Ok(Some(d)),
        Err(_) if skip_bad => Ok(None),
        Err(e) => Err(e.into()),
    }
}

/// A frame that was read: `None` where it cannot be decoded and `skip_bad` leaves it out; a
/// failing read is an error either way.
pub(crate) fn readable<T>(read: Result<T, sensor::frame::FrameError>, skip_bad: bool) -> Result<Option<T>> {
    match read {
        Ok(v) => Ok(Some(v)),
        Err(e @ sensor::frame::FrameError::Io { .. }) => Err(e.into()),
        Err(_) if skip_bad => Ok(None),
        Err(e) => Err(e.into()),
    }
}

/// One line per split: what the gate does there.
pub fn report_lines(record: &GateRecord) -> Vec<String> {
    let line = |name: &str, t: &Tally| {
        format!(
            "contact gate on {name}: {} frames with contact, {} of them missed; {} untouched, {} opened on",
            t.contact, t.misses, t.untouched, t.false_opens
        )
    };
    vec![
        format!(
            "contact gate fitted to the unit's frames: {} useful pixels differing by more than {} grey levels",
            record.gate.min_pixels, record.gate.grey_levels
        ),
        line("train", &record.train),
        line("test", &record.test),
    ]
}
