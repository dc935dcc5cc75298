//! The exported bundle: the only contract between training and deployment.
//!
//! ```text
//! BUNDLE/bundle.json          format version, model config, input size, depth scale, sensor
//!                             description with its correspondence, training metadata, metrics
//! BUNDLE/weights.bpk          the weights, Burn's burnpack format (what `infer` loads)
//! BUNDLE/weights.safetensors  the same weights for other tools
//! BUNDLE/reference.png        optional: the unit's no-contact image
//! ```
//!
//! A bundle is written into a temporary folder beside its destination and renamed into place,
//! so a reader never sees half a bundle.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::store::{ModuleRecord, ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;
use formats::training::TrainingRecord;
use sensor::Sensor;
use serde::{Deserialize, Serialize};

use crate::{DenseDepth, DenseDepthConfig, DepthScale};

pub const BUNDLE_FORMAT_VERSION: u32 = 1;
pub const BUNDLE_JSON: &str = "bundle.json";
pub const WEIGHTS_BURNPACK: &str = "weights.bpk";
pub const WEIGHTS_SAFETENSORS: &str = "weights.safetensors";
pub const REFERENCE_PNG: &str = "reference.png";

/// `bundle.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BundleFile {
    pub format_version: u32,
    pub model: DenseDepthConfig,
    /// Network input (the crop is resized to it); output is half of each side.
    pub input_height_px: usize,
    pub input_width_px: usize,
    /// Input pixels: RGB, each channel divided by 255, no mean or deviation subtracted.
    pub input_encoding: String,
    pub depth_scale: DepthScale,
    pub sensor: Sensor,
    /// File name of the unit's no-contact image in the bundle, if there is one.
    pub reference_image: Option<String>,
    /// How the weights came to be: a training run (its data, settings, per-epoch metrics and
    /// test error) or an import.
    #[serde(default)]
    pub training: Option<TrainingRecord>,
}

/// The input encoding every bundle of this version uses.
pub const INPUT_ENCODING: &str = "rgb/255";

/// A sensor crop as the network's input ([`INPUT_ENCODING`]): resized to `[h, w]` (triangle
/// filter), channel-major R, G, B planes, values / 255. Training and inference both call this,
/// so the two cannot drift apart.
pub fn encode_input(img: &image::RgbImage, [h, w]: [usize; 2]) -> Vec<f32> {
    let small = image::imageops::resize(img, w as u32, h as u32, image::imageops::FilterType::Triangle);
    let mut input = vec![0f32; 3 * h * w];
    for (k, px) in small.pixels().enumerate() {
        for c in 0..3 {
            input[c * h * w + k] = px.0[c] as f32 / 255.0;
        }
    }
    input
}

#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
}

impl From<formats::FsError> for BundleError {
    fn from(e: formats::FsError) -> Self {
        BundleError::File { path: e.path, message: e.source.to_string() }
    }
}

fn err(path: &Path, message: impl std::fmt::Display) -> BundleError {
    BundleError::File { path: path.to_path_buf(), message: message.to_string() }
}

impl BundleFile {
    /// Reads and checks `DIR/bundle.json`.
    pub fn read(dir: &Path) -> Result<Self, BundleError> {
        let path = dir.join(BUNDLE_JSON);
        let text = std::fs::read_to_string(&path).map_err(|e| err(&path, e))?;
        // The version first: a newer bundle is refused as newer, not as malformed.
        #[derive(Deserialize)]
        struct Version {
            #[serde(default)]
            format_version: u32,
        }
        let Version { format_version: version } = serde_json::from_str(&text).map_err(|e| err(&path, e))?;
        if version > BUNDLE_FORMAT_VERSION {
            return Err(err(
                &path,
                format!("bundle format {version} is newer than this program understands ({BUNDLE_FORMAT_VERSION})"),
            ));
        }
        let file: BundleFile = serde_json::from_str(&text).map_err(|e| err(&path, e))?;
        file.sensor.validate().map_err(|e| err(&path, e))?;
        let stride = DenseDepthConfig::STRIDE;
        if file.input_height_px == 0
            || file.input_width_px == 0
            || !file.input_height_px.is_multiple_of(stride)
            || !file.input_width_px.is_multiple_of(stride)
        {
            return Err(err(
                &path,
                format!(
                    "input {}x{} must be positive multiples of {stride}",
                    file.input_height_px, file.input_width_px
                ),
            ));
        }
        if file.input_encoding != INPUT_ENCODING {
            return Err(err(&path, format!("unknown input encoding {:?}", file.input_encoding)));
        }
        Ok(file)
    }
}

/// Writes a bundle to `dir` (replacing one that is there) atomically.
pub fn write_bundle(
    dir: &Path,
    model: &DenseDepth,
    file: &BundleFile,
    reference_png: Option<&[u8]>,
) -> Result<(), BundleError> {
    formats::fs::write_dir_atomic(dir, |tmp| {
        let mut file = file.clone();
        file.reference_image = reference_png.map(|_| REFERENCE_PNG.to_string());
        if let Some(bytes) = reference_png {
            std::fs::write(tmp.join(REFERENCE_PNG), bytes).map_err(|e| err(&tmp.join(REFERENCE_PNG), e))?;
        }
        let bpk = tmp.join(WEIGHTS_BURNPACK);
        model.clone().save_file(&bpk).map_err(|e| err(&bpk, e))?;
        let st = tmp.join(WEIGHTS_SAFETENSORS);
        model.save_into(&mut SafetensorsStore::from_file(&st)).map_err(|e| err(&st, e))?;
        let json = tmp.join(BUNDLE_JSON);
        let text = serde_json::to_string_pretty(&file).expect("bundle serialises");
        std::fs::write(&json, text).map_err(|e| err(&json, e))?;
        Ok(())
    })
}

/// Loads a bundle's network (weights from the burnpack file) on `device`.
pub fn load_bundle(dir: &Path, device: &Device) -> Result<(DenseDepth, BundleFile), BundleError> {
    let file = BundleFile::read(dir)?;
    let bpk = dir.join(WEIGHTS_BURNPACK);
    let record = ModuleRecord::load(&bpk).map_err(|e| err(&bpk, e))?;
    let model = file.model.init(device).try_load_record(record).map_err(|e| err(&bpk, e))?;
    Ok((model, file))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DenseNetConfig;
    use burn::tensor::{Distribution, Tensor};

    fn bundle_file() -> BundleFile {
        BundleFile {
            format_version: BUNDLE_FORMAT_VERSION,
            model: DenseDepthConfig::new(DenseNetConfig::tiny()),
            input_height_px: 64,
            input_width_px: 64,
            input_encoding: INPUT_ENCODING.into(),
            depth_scale: DepthScale::paper(9.4),
            sensor: Sensor::default(),
            reference_image: None,
            training: None,
        }
    }

    #[test]
    fn round_trip_gives_identical_predictions() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &bundle_file(), Some(b"png")).unwrap();
        // Writing again replaces the bundle.
        write_bundle(&dir, &model, &bundle_file(), Some(b"png")).unwrap();
        let (loaded, file) = load_bundle(&dir, &device).unwrap();
        assert_eq!(file.reference_image.as_deref(), Some(REFERENCE_PNG));
        assert!(dir.join(WEIGHTS_SAFETENSORS).is_file());
        let x = Tensor::<4>::random([1, 3, 64, 64], Distribution::Uniform(0.0, 1.0), &device);
        let (a, b) = (model.forward(x.clone()), loaded.forward(x));
        assert_eq!(a.into_data().try_to_vec::<f32>().unwrap(), b.into_data().try_to_vec::<f32>().unwrap());
    }

    #[test]
    fn bad_bundles_are_named_errors() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &bundle_file(), None).unwrap();
        // A newer format.
        let json = dir.join(BUNDLE_JSON);
        let text = std::fs::read_to_string(&json).unwrap();
        std::fs::write(&json, text.replace("\"format_version\": 1", "\"format_version\": 7")).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("bundle.json") && e.contains("newer"), "{e}");
        std::fs::write(&json, &text).unwrap();
        // Weights of another architecture: a mis-shaped tensor.
        let other = DenseDepthConfig::new(DenseNetConfig::compact()).init(&device);
        other.save_file(dir.join(WEIGHTS_BURNPACK)).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk") && e.contains("shape"), "{e}");
        // One tensor left out of the file: named.
        let mut store = burn::store::BurnpackStore::from_file(dir.join(WEIGHTS_BURNPACK))
            .overwrite(true)
            .with_filter(burn::store::PathFilter::new().with_predicate(|path, _| !path.ends_with("conv3.weight")));
        model.save_into(&mut store).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk") && e.contains("conv3.weight"), "{e}");
        // Missing weights.
        std::fs::remove_file(dir.join(WEIGHTS_BURNPACK)).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk"), "{e}");
    }
}
