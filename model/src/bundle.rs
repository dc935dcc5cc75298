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
use formats::output::OutputKind;
use formats::training::TrainingRecord;
use sensor::Sensor;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use crate::{DenseDepth, DenseDepthConfig, DepthScale, InputEncoding};

pub const BUNDLE_FORMAT_VERSION: u32 = 1;
pub const BUNDLE_JSON: &str = "bundle.json";
pub const WEIGHTS_BURNPACK: &str = "weights.bpk";
pub const WEIGHTS_SAFETENSORS: &str = "weights.safetensors";
pub const REFERENCE_PNG: &str = "reference.png";
/// Largest network input side a bundle may name (the sensor's 570 px crop fits many times).
pub const MAX_INPUT_SIDE_PX: usize = 4096;

/// `bundle.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BundleFile {
    pub format_version: u32,
    pub model: DenseDepthConfig,
    /// Network input (the crop is resized to it); output is half of each side.
    pub input_height_px: usize,
    pub input_width_px: usize,
    /// Input pixels: [`InputEncoding::text`] (RGB, each channel divided by 255, no mean or
    /// deviation subtracted; then, if the model reads it, the reference difference times the
    /// gain fitted to the unit's data).
    pub input_encoding: String,
    pub depth_scale: DepthScale,
    pub sensor: Sensor,
    /// File name of the unit's no-contact image in the bundle, if there is one.
    pub reference_image: Option<String>,
    /// How the weights came to be: a training run (its data, settings, per-epoch metrics and
    /// test error) or an import.
    #[serde(default)]
    pub training: Option<TrainingRecord>,
    /// SHA-256 (hex) of every file the bundle names ([`BundleFile::files`]: both weights files
    /// and the reference image), checked whenever the bundle is read: a damaged, cut or
    /// replaced file is an error, not different predictions, and a file without one is refused
    /// (`train sign` records them for a bundle edited by hand). Older bundles recorded the
    /// weights' only, as `weights_sha256`.
    #[serde(default, alias = "weights_sha256", skip_serializing_if = "BTreeMap::is_empty")]
    pub sha256: BTreeMap<String, String>,
    /// Whose tensor names `weights.safetensors` uses (Burn's module paths unless exported with
    /// `--torch-names`). Inference reads the burnpack file, which this does not touch.
    #[serde(default)]
    pub safetensors_keys: SafetensorsKeys,
    /// The contact gate fitted to the unit's labelled frames, with what it does on each split;
    /// `None` (imported or older bundles, datasets without a reference frame): no gate, the
    /// network runs on every frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_gate: Option<GateRecord>,
    /// The elastomer's stiffness fitted to the unit's force labels (or its force-torque
    /// readings) when the bundle is made: inference solves the contact on each predicted depth
    /// map with it for the pressure and the wrench. `None` (older or imported bundles, data
    /// without force labels): force only from a network with the pressure output.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elastomer: Option<ElastomerRecord>,
}

/// A unit's elastomer as its force labels show it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ElastomerRecord {
    /// `E / (1 - nu^2)` (MPa): the one constant a frictionless linear contact's pressure scales
    /// with; the median over the fitting samples of |F_label| / |F_solved at 1 MPa|.
    pub effective_modulus_mpa: f64,
    /// The quartiles of those ratios (MPa): how well one linear material explains the labels.
    pub quartiles_mpa: [f64; 2],
    /// Train samples fitted on, and how many of them carry a measured wrench (a force-torque
    /// sensor's, preferred over the model's label where a sample has both).
    pub samples: usize,
    pub measured: usize,
}

impl ElastomerRecord {
    /// An elastomer given rather than fitted here (an indentation test, a force-torque fit made
    /// elsewhere): no samples, its quartiles the value itself.
    pub fn given(effective_modulus_mpa: f64) -> Self {
        ElastomerRecord { effective_modulus_mpa, quartiles_mpa: [effective_modulus_mpa; 2], samples: 0, measured: 0 }
    }
}

/// A bundle's contact gate and its tally on the training data's splits.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateRecord {
    pub gate: sensor::gate::ContactGate,
    pub train: sensor::gate::Tally,
    pub test: sensor::gate::Tally,
}

/// The key names of a bundle's `weights.safetensors`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SafetensorsKeys {
    /// This crate's module paths (`encoder.denseblock1.layers.0.norm1.gamma`), for Burn's
    /// `SafetensorsStore`.
    #[default]
    Burn,
    /// The reference DenseDepth's `state_dict` keys (`encoder.original_model.features...`),
    /// for `load_state_dict(..., strict=True)` in PyTorch; see [`crate::torch`].
    Pytorch,
}

pub use formats::fs::sha256_hex;

/// The parameters of `model` that hold a NaN or an infinity, by name (`None`: all finite).
pub fn non_finite_tensors(model: &DenseDepth) -> Option<Vec<String>> {
    let bad: Vec<String> = model
        .collect(None, None, false)
        .into_iter()
        .filter_map(|t| {
            let name = t.name.clone();
            let data = burn::store::bridge::into_data(t).ok()?;
            let values = data.convert::<f32>().try_into_vec::<f32>().ok()?;
            values.iter().any(|v| !v.is_finite()).then_some(name)
        })
        .collect();
    (!bad.is_empty()).then_some(bad)
}

/// `names` for a message: the first few, then how many more.
fn some_names(names: &[String]) -> String {
    let shown = names.iter().take(5).cloned().collect::<Vec<_>>().join(", ");
    if names.len() > 5 { format!("{shown} and {} more", names.len() - 5) } else { shown }
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
    /// The description of `model` reading `[h, w]` inputs for `sensor`: no reference image, no
    /// training record, Burn's tensor names (set the rest with struct update syntax).
    pub fn new(model: DenseDepthConfig, [h, w]: [usize; 2], sensor: Sensor, depth_scale: DepthScale) -> Self {
        BundleFile {
            format_version: BUNDLE_FORMAT_VERSION,
            input_encoding: InputEncoding::new(model.input).text(),
            model,
            input_height_px: h,
            input_width_px: w,
            depth_scale,
            sensor,
            reference_image: None,
            training: None,
            sha256: BTreeMap::new(),
            safetensors_keys: SafetensorsKeys::Burn,
            contact_gate: None,
            elastomer: None,
        }
    }

    /// The input encoding `input_encoding` names, checked against the model's input and the
    /// reference image; the error says what is wrong.
    pub fn encoding(&self) -> Result<InputEncoding, String> {
        let Some(encoding) = InputEncoding::parse(&self.input_encoding) else {
            return Err(format!("unknown input encoding {:?}", self.input_encoding));
        };
        let c = encoding.channels;
        if c != self.model.input {
            return Err(format!(
                "input encoding {:?} does not match the model's input ({})",
                self.input_encoding,
                self.model.input.name()
            ));
        }
        if c.needs_reference() && self.reference_image.is_none() {
            return Err(format!("the model's input ({}) needs a reference image and the bundle names none", c.name()));
        }
        Ok(encoding)
    }

    /// Reads and checks `DIR/bundle.json`, and the bundle whole: every file it names lies in
    /// the folder and has the SHA-256 recorded for it ([`BundleFile::verify`]).
    pub fn read(dir: &Path) -> Result<Self, BundleError> {
        let file = Self::read_unverified(dir)?;
        file.verify(dir)?;
        Ok(file)
    }

    /// `DIR/bundle.json` alone, checked as a description but with its files unread: for
    /// `train sign`, which records their digests.
    pub fn read_unverified(dir: &Path) -> Result<Self, BundleError> {
        let path = dir.join(BUNDLE_JSON);
        let bytes = std::fs::read(&path).map_err(|e| err(&path, e))?;
        Self::parse(&path, &bytes)
    }

    /// The files the bundle names, by their names in it: its weights in both formats and its
    /// reference image.
    pub fn files(&self) -> Vec<&str> {
        let mut names = vec![WEIGHTS_BURNPACK, WEIGHTS_SAFETENSORS];
        names.extend(self.reference_image.as_deref());
        names
    }

    /// Checks that every file the bundle names is a plain name inside `dir` (never a path out of
    /// it) whose bytes have the SHA-256 recorded for it.
    pub fn verify(&self, dir: &Path) -> Result<(), BundleError> {
        for name in self.files() {
            let path = dir.join(name);
            let plain = !name.is_empty()
                && Path::new(name).components().count() == 1
                && matches!(Path::new(name).components().next(), Some(std::path::Component::Normal(_)));
            if !plain {
                return Err(err(
                    &dir.join(BUNDLE_JSON),
                    format!("names the file {name:?}, which is not a file inside the bundle's folder"),
                ));
            }
            let bytes = std::fs::read(&path).map_err(|e| err(&path, e))?;
            let got = sha256_hex(&bytes);
            match self.sha256.get(name) {
                None => {
                    return Err(err(
                        &path,
                        format!(
                            "bundle.json records no SHA-256 for it, so the bundle cannot be checked whole; if its files \
                             are as they were exported (or edited on purpose), record them with `train sign --bundle {}`",
                            dir.display()
                        ),
                    ));
                }
                Some(want) if *want != got => {
                    return Err(err(
                        &path,
                        format!(
                            "its SHA-256 is {got}, but bundle.json records {want}: the file was damaged, cut or \
                             replaced; export the bundle again"
                        ),
                    ));
                }
                Some(_) => {}
            }
        }
        Ok(())
    }

    /// Parses and checks a `bundle.json`'s bytes; `path` names it in errors.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self, BundleError> {
        let text = std::str::from_utf8(bytes).map_err(|e| err(path, format!("not UTF-8 text: {e}")))?;
        // The version first: a newer bundle is refused as newer, not as malformed.
        #[derive(Deserialize)]
        struct Version {
            #[serde(default)]
            format_version: u32,
        }
        let Version { format_version: version } = serde_json::from_str(text).map_err(|e| err(path, e))?;
        if version > BUNDLE_FORMAT_VERSION {
            return Err(err(
                path,
                format!("bundle format {version} is newer than this program understands ({BUNDLE_FORMAT_VERSION})"),
            ));
        }
        let file: BundleFile = serde_json::from_str(text).map_err(|e| err(path, e))?;
        file.sensor.validate().map_err(|e| err(path, e))?;
        DenseDepthConfig::check_input_hw([file.input_height_px, file.input_width_px]).map_err(|e| err(path, e))?;
        if file.input_height_px > MAX_INPUT_SIDE_PX || file.input_width_px > MAX_INPUT_SIDE_PX {
            return Err(err(
                path,
                format!(
                    "input {}x{} is larger than {MAX_INPUT_SIDE_PX} px a side",
                    file.input_height_px, file.input_width_px
                ),
            ));
        }
        file.model.check().map_err(|e| err(path, format!("model: {e}")))?;
        file.depth_scale.check().map_err(|e| err(path, format!("depth_scale: {e}")))?;
        file.encoding().map_err(|e| err(path, e))?;
        Ok(file)
    }
}

/// Writes a bundle to `dir` atomically, replacing only a bundle that is there (never a folder
/// of something else, nor one of `inputs`: see `formats::output`). Weights that are not finite
/// are refused, naming the tensors, and nothing is written.
pub fn write_bundle(
    dir: &Path,
    model: &DenseDepth,
    file: &BundleFile,
    reference_png: Option<&[u8]>,
    inputs: &[&Path],
) -> Result<(), BundleError> {
    formats::output::check_dir(dir, OutputKind::Bundle, inputs).map_err(|e| err(&e.path, e.why))?;
    if file.model.input.needs_reference() && reference_png.is_none() {
        return Err(err(
            dir,
            format!("not written: the model's input ({}) needs the unit's reference image", file.model.input.name()),
        ));
    }
    if let Some(names) = non_finite_tensors(model) {
        return Err(err(
            dir,
            format!("not written: {} tensor(s) hold NaN or infinite values: {}", names.len(), some_names(&names)),
        ));
    }
    let mut file = file.clone();
    file.reference_image = reference_png.map(|_| REFERENCE_PNG.to_string());
    file.encoding().map_err(|e| err(dir, format!("not written: {e}")))?;
    formats::fs::write_dir_atomic(dir, |tmp| {
        if let Some(bytes) = reference_png {
            std::fs::write(tmp.join(REFERENCE_PNG), bytes).map_err(|e| err(&tmp.join(REFERENCE_PNG), e))?;
        }
        let bpk = tmp.join(WEIGHTS_BURNPACK);
        model.clone().save_file(&bpk).map_err(|e| err(&bpk, e))?;
        let st = tmp.join(WEIGHTS_SAFETENSORS);
        match file.safetensors_keys {
            SafetensorsKeys::Burn => model.save_into(&mut SafetensorsStore::from_file(&st)).map_err(|e| err(&st, e))?,
            SafetensorsKeys::Pytorch => {
                let bytes = crate::torch::state_dict_safetensors(model).map_err(|e| err(&st, e))?;
                std::fs::write(&st, bytes).map_err(|e| err(&st, e))?;
            }
        }
        sign_files(tmp, &mut file)?;
        let json = tmp.join(BUNDLE_JSON);
        let text = serde_json::to_string_pretty(&file).expect("bundle serialises");
        std::fs::write(&json, text).map_err(|e| err(&json, e))?;
        // The weights' writers create their files private (0600); a bundle is read by others
        // (a ROS node's user, a container): every file as the system makes ordinary ones.
        let ordinary = std::fs::metadata(&json).map_err(|e| err(&json, e))?.permissions();
        for path in [&bpk, &st] {
            std::fs::set_permissions(path, ordinary.clone()).map_err(|e| err(path, e))?;
        }
        formats::output::mark(tmp, OutputKind::Bundle).map_err(|e| err(&e.path, e.why))?;
        Ok(())
    })
}

/// Records the SHA-256 of every file `file` names in `dir` (whose files must be there).
fn sign_files(dir: &Path, file: &mut BundleFile) -> Result<(), BundleError> {
    let names: Vec<String> = file.files().into_iter().map(String::from).collect();
    file.sha256.clear();
    for name in names {
        let path = dir.join(&name);
        let bytes = std::fs::read(&path).map_err(|e| err(&path, e))?;
        file.sha256.insert(name, sha256_hex(&bytes));
    }
    Ok(())
}

/// `train sign`: records the SHA-256 of every file a bundle names in its `bundle.json`
/// (written atomically), for a bundle whose files were edited on purpose or that predates
/// them. Its description and every named path are checked first; the weights must load.
pub fn sign_bundle(dir: &Path, device: &Device) -> Result<(), BundleError> {
    let mut file = BundleFile::read_unverified(dir)?;
    sign_files(dir, &mut file).and_then(|()| file.verify(dir))?;
    let text = serde_json::to_string_pretty(&file).expect("bundle serialises");
    // Loads with the new digests before they are written: weights that do not load are not signed.
    let bpk = dir.join(WEIGHTS_BURNPACK);
    let bytes = std::fs::read(&bpk).map_err(|e| err(&bpk, e))?;
    load_weights(&file, &bpk, bytes, device)?;
    formats::fs::write_atomic(&dir.join(BUNDLE_JSON), text.as_bytes())?;
    Ok(())
}

/// The bundle's reference frame (its unit untouched, the crop's size), where it has one: what
/// the predictor reads every frame against.
pub fn load_reference(dir: &Path, file: &BundleFile) -> Result<Option<image::RgbImage>, sensor::frame::FrameError> {
    match &file.reference_image {
        Some(name) => Ok(Some(sensor::frame::read_reference(&dir.join(name), file.sensor.crop_size_px)?)),
        None => Ok(None),
    }
}

/// Loads a bundle's network (weights from the burnpack file) on `device`; the bundle is checked
/// whole first ([`BundleFile::read`]).
pub fn load_bundle(dir: &Path, device: &Device) -> Result<(DenseDepth, BundleFile), BundleError> {
    let file = BundleFile::read(dir)?;
    let bpk = dir.join(WEIGHTS_BURNPACK);
    let bytes = std::fs::read(&bpk).map_err(|e| err(&bpk, e))?;
    let model = load_weights(&file, &bpk, bytes, device)?;
    Ok((model, file))
}

fn load_weights(file: &BundleFile, bpk: &Path, bytes: Vec<u8>, device: &Device) -> Result<DenseDepth, BundleError> {
    let record = ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes)).map_err(|e| err(bpk, e))?;
    let model = file.model.init(device).try_load_record(record).map_err(|e| err(bpk, e))?;
    if let Some(names) = non_finite_tensors(&model) {
        return Err(err(
            bpk,
            format!(
                "{} tensor(s) hold NaN or infinite values: {}; the model cannot be used",
                names.len(),
                some_names(&names)
            ),
        ));
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DenseNetConfig;
    use burn::tensor::{Distribution, Tensor};

    fn bundle_file() -> BundleFile {
        BundleFile::new(
            DenseDepthConfig::new(DenseNetConfig::tiny()),
            [64, 64],
            Sensor::default(),
            DepthScale::paper(9.4),
        )
    }

    #[test]
    fn round_trip_gives_identical_predictions() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &bundle_file(), Some(b"png"), &[]).unwrap();
        // Writing again replaces the bundle.
        write_bundle(&dir, &model, &bundle_file(), Some(b"png"), &[]).unwrap();
        let (loaded, file) = load_bundle(&dir, &device).unwrap();
        assert_eq!(file.reference_image.as_deref(), Some(REFERENCE_PNG));
        assert!(dir.join(WEIGHTS_SAFETENSORS).is_file());
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = |name: &str| std::fs::metadata(dir.join(name)).unwrap().permissions().mode() & 0o777;
            for name in [WEIGHTS_SAFETENSORS, WEIGHTS_BURNPACK, REFERENCE_PNG] {
                assert_eq!(mode(name), mode(BUNDLE_JSON), "{name} is as readable as bundle.json");
            }
        }
        let x = Tensor::<4>::random([1, 3, 64, 64], Distribution::Uniform(0.0, 1.0), &device);
        let (a, b) = (model.forward(x.clone()), loaded.forward(x));
        assert_eq!(a.into_data().try_to_vec::<f32>().unwrap(), b.into_data().try_to_vec::<f32>().unwrap());
    }

    /// Every file a bundle names is checked at load: a cut safetensors file, a reference image
    /// replaced or named outside the folder, digests removed (refused with the command that
    /// records them; after it, the bundle loads).
    #[test]
    fn bundles_are_checked_whole() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &bundle_file(), Some(b"png"), &[]).unwrap();
        let json = dir.join(BUNDLE_JSON);
        let original = std::fs::read_to_string(&json).unwrap();
        let edit = |f: &dyn Fn(&mut BundleFile)| {
            let mut file: BundleFile = serde_json::from_str(&original).unwrap();
            f(&mut file);
            std::fs::write(&json, serde_json::to_string(&file).unwrap()).unwrap();
        };
        let refusal = || load_bundle(&dir, &device).expect_err("refused").to_string();

        let st = dir.join(WEIGHTS_SAFETENSORS);
        let bytes = std::fs::read(&st).unwrap();
        std::fs::write(&st, &bytes[..1000]).unwrap();
        let e = refusal();
        assert!(e.contains("weights.safetensors") && e.contains("SHA-256"), "{e}");
        std::fs::write(&st, &bytes).unwrap();

        std::fs::write(dir.join(REFERENCE_PNG), b"another png").unwrap();
        let e = refusal();
        assert!(e.contains("reference.png") && e.contains("SHA-256"), "{e}");
        std::fs::write(dir.join(REFERENCE_PNG), b"png").unwrap();

        let elsewhere = tmp.path().join("elsewhere.png");
        std::fs::write(&elsewhere, b"png").unwrap();
        for name in [elsewhere.to_str().unwrap(), "../elsewhere.png", "sub/reference.png", "."] {
            edit(&|f| {
                f.reference_image = Some(name.to_string());
                f.sha256.insert(name.to_string(), sha256_hex(b"png"));
            });
            let e = refusal();
            assert!(e.contains("not a file inside the bundle"), "{name}: {e}");
        }

        // Digests gone (an older bundle, or one edited by hand): refused, naming the command.
        for names in [&[][..], &[WEIGHTS_BURNPACK][..]] {
            edit(&|f| f.sha256.retain(|k, _| names.contains(&k.as_str())));
            let e = refusal();
            assert!(e.contains("records no SHA-256") && e.contains("train sign --bundle"), "{e}");
        }
        sign_bundle(&dir, &device).unwrap();
        load_bundle(&dir, &device).unwrap();
        // Signing checks what it signs: weights that do not load are not signed.
        edit(&|f| f.sha256.clear());
        std::fs::write(dir.join(WEIGHTS_BURNPACK), b"not weights").unwrap();
        assert!(sign_bundle(&dir, &device).is_err());
        assert!(!std::fs::read_to_string(&json).unwrap().contains(WEIGHTS_SAFETENSORS), "nothing was signed");
    }

    #[test]
    fn bad_bundles_are_named_errors() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &bundle_file(), None, &[]).unwrap();
        // A newer format.
        let json = dir.join(BUNDLE_JSON);
        let text = std::fs::read_to_string(&json).unwrap();
        std::fs::write(&json, text.replace("\"format_version\": 1", "\"format_version\": 7")).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("bundle.json") && e.contains("newer"), "{e}");
        std::fs::write(&json, &text).unwrap();
        // 4 KB overwritten in the middle of the weights: the checksum says so.
        let bpk = dir.join(WEIGHTS_BURNPACK);
        let mut bytes = std::fs::read(&bpk).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle..middle + 4096].fill(0x5a);
        std::fs::write(&bpk, &bytes).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk") && e.contains("SHA-256") && e.contains("damaged"), "{e}");
        // The checks below reach past the checksum: bundle.json records the new file's.
        let rerecord = || {
            let mut file: BundleFile = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            file.sha256.insert(WEIGHTS_BURNPACK.into(), sha256_hex(&std::fs::read(&bpk).unwrap()));
            std::fs::write(&json, serde_json::to_string(&file).unwrap()).unwrap();
        };
        // Weights of another architecture: a mis-shaped tensor.
        let other = DenseDepthConfig::new(DenseNetConfig::compact()).init(&device);
        other.save_file(&bpk).unwrap();
        rerecord();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk") && e.contains("shape"), "{e}");
        // One tensor left out of the file: named.
        let mut store = burn::store::BurnpackStore::from_file(&bpk)
            .overwrite(true)
            .with_filter(burn::store::PathFilter::new().with_predicate(|path, _| !path.ends_with("conv3.weight")));
        model.save_into(&mut store).unwrap();
        rerecord();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk") && e.contains("conv3.weight"), "{e}");
        // Non-finite weights: refused at load, naming the tensor.
        let mut broken = model.clone();
        broken.decoder.conv3.weight =
            burn::module::Param::from_tensor(broken.decoder.conv3.weight.val().mul_scalar(f32::NAN));
        broken.clone().save_file(&bpk).unwrap();
        rerecord();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("NaN") && e.contains("conv3.weight"), "{e}");
        // ... and refused at export, writing nothing.
        let e = write_bundle(&tmp.path().join("nan"), &broken, &bundle_file(), None, &[]).unwrap_err().to_string();
        assert!(e.contains("NaN") && e.contains("conv3.weight"), "{e}");
        assert!(!tmp.path().join("nan").exists());
        // A folder of something else is never replaced by a bundle.
        let data = tmp.path().join("data");
        std::fs::create_dir(&data).unwrap();
        std::fs::write(data.join("manifest.json"), b"{}").unwrap();
        let e = write_bundle(&data, &model, &bundle_file(), None, &[]).unwrap_err().to_string();
        assert!(e.contains("manifest.json") && e.contains("did not write"), "{e}");
        assert!(data.join("manifest.json").is_file());
        // Missing weights.
        std::fs::remove_file(dir.join(WEIGHTS_BURNPACK)).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("weights.bpk"), "{e}");
    }

    #[test]
    fn the_input_encoding_is_kept_and_checked_against_the_model() {
        let device = crate::backend::default_device();
        let config = DenseDepthConfig::new(DenseNetConfig::tiny()).with_input(crate::InputChannels::RgbDifference);
        let model = config.init(&device);
        let tmp = tempfile::tempdir().unwrap();
        let mut png = Vec::new();
        image::RgbImage::from_pixel(8, 8, image::Rgb([90, 120, 150]))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let fitted = InputEncoding { channels: config.input, difference_gain: 9.37 };
        let file = BundleFile {
            input_encoding: fitted.text(),
            ..BundleFile::new(config, [64, 64], Sensor::default(), DepthScale::paper(9.4))
        };
        // The unit's gain goes into the bundle and comes back as it was.
        let dir = tmp.path().join("b");
        write_bundle(&dir, &model, &file, Some(&png), &[]).unwrap();
        let (_, read) = load_bundle(&dir, &device).unwrap();
        assert_eq!(read.encoding(), Ok(fitted));
        assert_eq!(read.input_encoding, "rgb/255,9.37*(rgb-reference)/255");
        // An encoding that is no encoding, or not the model's, is written by nobody...
        for (text, why) in [("rgb/255,0*(rgb-reference)/255", "unknown input encoding"), ("rgb/255", "does not match")]
        {
            let bad = BundleFile { input_encoding: text.into(), ..file.clone() };
            let e = write_bundle(&tmp.path().join("no"), &model, &bad, Some(&png), &[]).unwrap_err().to_string();
            assert!(e.contains("not written") && e.contains(why), "{text}: {e}");
            assert!(!tmp.path().join("no").exists());
        }
        // ... and refused when read, naming the file.
        let json = dir.join(BUNDLE_JSON);
        let text = std::fs::read_to_string(&json).unwrap();
        std::fs::write(&json, text.replace("9.37*", "nan*")).unwrap();
        let e = load_bundle(&dir, &device).unwrap_err().to_string();
        assert!(e.contains("bundle.json") && e.contains("unknown input encoding"), "{e}");
    }
}
