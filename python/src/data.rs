//! `densetact.Dataset`'s native part: a dataset folder's manifest, and each sample's files read
//! and checked as training reads them (the file and the problem named on failure).

use std::path::{Path, PathBuf};

use formats::dataset::{Manifest, SampleRecord, Split};
use numpy::{PyArray2, PyArray3};
use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;

use crate::arrays::{plane, rgb};
use crate::error;

/// A dataset folder (`dataset generate` or `dataset label`), one split or all.
#[pyclass(module = "densetact", frozen)]
pub(crate) struct NativeDataset {
    dir: PathBuf,
    manifest: Manifest,
    /// The chosen split's records, as indices into the manifest's.
    chosen: Vec<usize>,
}

impl NativeDataset {
    fn record(&self, i: usize) -> PyResult<&SampleRecord> {
        let k = self.chosen.get(i).ok_or_else(|| {
            PyIndexError::new_err(format!("sample index {i} is out of range: the dataset has {}", self.chosen.len()))
        })?;
        Ok(&self.manifest.samples[*k])
    }

    fn crop_px(&self) -> usize {
        self.manifest.sensor.crop_size_px as usize
    }

    /// An image file of the dataset (a sample's camera image or reference) as the crop.
    fn image_at<'py>(&self, py: Python<'py>, rel: &str) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let path = self.dir.join(rel);
        let image = py.detach(|| sensor::frame::read_crop(&path, &self.manifest.sensor)).map_err(error)?;
        Ok(rgb(py, image))
    }
}

#[pymethods]
impl NativeDataset {
    #[new]
    #[pyo3(signature = (path, split = None))]
    fn new(path: PathBuf, split: Option<&str>) -> PyResult<Self> {
        let split = match split {
            None | Some("all") => None,
            Some("train") => Some(Split::Train),
            Some("test") => Some(Split::Test),
            Some(other) => {
                return Err(PyValueError::new_err(format!("split must be 'train', 'test' or None, got {other:?}")));
            }
        };
        let manifest = Manifest::load(&path).map_err(error)?;
        let chosen = manifest.samples.iter().enumerate().filter(|(_, s)| split.is_none_or(|w| s.split == w));
        let chosen = chosen.map(|(k, _)| k).collect();
        Ok(NativeDataset { dir: path, manifest, chosen })
    }

    fn __len__(&self) -> usize {
        self.chosen.len()
    }

    /// Sample `i`'s record (its scene, split, statistics, file names, wrench) as JSON.
    fn record_json(&self, i: usize) -> PyResult<String> {
        serde_json::to_string(self.record(i)?).map_err(error)
    }

    /// Sample `i`'s camera image (HxWx3 uint8 RGB, the crop), or None for a dataset without
    /// images.
    fn image<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyArray3<u8>>>> {
        let record = self.record(i)?;
        record.image.as_deref().map(|rel| self.image_at(py, rel)).transpose()
    }

    /// Sample `i`'s depth label (mm, float32, the crop), from its 16-bit micrometre PNG.
    fn depth<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let path = self.dir.join(&self.record(i)?.depth);
        let depth = py.detach(|| sensor::DepthMap::load_png_um(&path)).map_err(error)?;
        check_size(&path, depth.size_px as usize, self.crop_px())?;
        let n = depth.size_px as usize;
        Ok(plane(py, depth.depth_mm, [n, n]))
    }

    /// Sample `i`'s pressure label (kPa, float32, the crop), or None without force labels.
    fn pressure<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        let Some(rel) = &self.record(i)?.pressure else { return Ok(None) };
        let path = self.dir.join(rel);
        let map = py.detach(|| sensor::PressureMap::load_png(&path)).map_err(error)?;
        check_size(&path, map.size_px as usize, self.crop_px())?;
        let n = map.size_px as usize;
        Ok(Some(plane(py, map.pressure_kpa, [n, n])))
    }

    /// The untouched frame sample `i`'s image is read against: its own (random looks) or the
    /// unit's `unit/reference.png`; None for a dataset without images.
    fn reference<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyArray3<u8>>>> {
        let record = self.record(i)?;
        if record.image.is_none() {
            return Ok(None);
        }
        let rel = record.reference.as_deref().unwrap_or("unit/reference.png");
        if record.reference.is_none() && !self.dir.join(rel).is_file() {
            return Ok(None);
        }
        self.image_at(py, rel).map(Some)
    }

    /// The dataset's sensor description, as JSON.
    fn sensor_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.manifest.sensor).map_err(error)
    }

    /// The folder.
    #[getter]
    fn path(&self) -> PathBuf {
        self.dir.clone()
    }
}

/// Refuses a map of another size than the dataset's crop, naming the file.
fn check_size(path: &Path, size: usize, crop: usize) -> PyResult<()> {
    if size != crop {
        return Err(error(anyhow::anyhow!(
            "{}: the map is {size}x{size} px, the dataset's crop is {crop}x{crop}",
            path.display()
        )));
    }
    Ok(())
}
