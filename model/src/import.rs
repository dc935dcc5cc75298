//! PyTorch weight import: a DenseDepth `state_dict` (pickled or safetensors), or a torchvision DenseNet checkpoint for
//! the encoder alone (what a user downloads to start from ImageNet, as the paper did).
//!
//! Both key styles are read: `denselayer1.norm1.weight` and the legacy `denselayer1.norm.1.weight`
//! of torchvision's published files. The DenseNet's configuration is read off the tensor shapes,
//! so no config file is needed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::store::{ApplyError, ApplyResult, ModuleStore, PyTorchToBurnAdapter, PytorchStore, SafetensorsStore};
use burn::tensor::Device;

use crate::InputChannels;
use crate::network::{DenseDepth, DenseDepthConfig, DenseNetConfig};

#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("{path}: cannot read PyTorch weights: {message}")]
    Read { path: PathBuf, message: String },
    #[error("{path}: not a DenseNet (torchvision) or DenseDepth state_dict: {message}")]
    NotDenseNet { path: PathBuf, message: String },
    #[error("{path}: missing tensor(s): {}", names.join(", "))]
    Missing { path: PathBuf, names: Vec<String> },
    #[error("{path}: unexpected tensor(s) the model has no place for: {}", names.join(", "))]
    Unexpected { path: PathBuf, names: Vec<String> },
    #[error("{path}: {}", problems.join("; "))]
    Mismatch { path: PathBuf, problems: Vec<String> },
}

/// What was imported.
pub struct Imported {
    pub config: DenseDepthConfig,
    pub model: DenseDepth,
    /// True for a torchvision DenseNet checkpoint: the decoder keeps its fresh initialisation.
    pub encoder_only: bool,
}

/// Key rules from PyTorch's names to this crate's module paths (applied in order).
const KEY_RULES: [(&str, &str); 6] = [
    // DenseDepth's encoder wraps torchvision's model.
    (r"^encoder\.original_model\.features\.", "encoder."),
    // A bare torchvision DenseNet.
    (r"^features\.", "encoder."),
    // Legacy torchvision keys: `norm.1` -> `norm1`, `conv.2` -> `conv2`.
    (r"(denselayer\d+)\.(norm|relu|conv)\.([12])\.", "$1.$2$3."),
    // `denselayerN` (1-based) -> `layers.N`, made 0-based by the store's contiguous index mapping.
    (r"\.denselayer(\d+)\.", ".layers.$1."),
    (r"\.convA\.", ".conv_a."),
    (r"\.convB\.", ".conv_b."),
];

/// A PyTorch `state_dict` on disk: pickled (`torch.save`) or safetensors
/// (`safetensors.torch.save_file`, or `train export --torch-names`), told apart by content.
enum Store {
    Pickle(PytorchStore),
    Safetensors(SafetensorsStore),
}

impl Store {
    /// `allow_partial` and no validation: what fits is applied, the rest reported.
    fn open(path: &Path, lenient: bool) -> Store {
        if is_safetensors(path) {
            let store = SafetensorsStore::from_file(path)
                .with_from_adapter(PyTorchToBurnAdapter)
                .skip_enum_variants(true)
                .map_indices_contiguous(true);
            let store = KEY_RULES.iter().fold(store, |store, (from, to)| store.with_key_remapping(from, *to));
            Store::Safetensors(if lenient { store.allow_partial(true).validate(false) } else { store })
        } else {
            let store = KEY_RULES
                .iter()
                .fold(PytorchStore::from_file(path), |store, (from, to)| store.with_key_remapping(from, *to));
            Store::Pickle(if lenient { store.allow_partial(true).validate(false) } else { store })
        }
    }

    fn shapes(&mut self) -> Result<BTreeMap<String, Vec<usize>>, String> {
        let shapes = |all: &BTreeMap<String, burn::store::burn_pack::Tensor>| {
            all.iter().map(|(k, t)| (k.clone(), t.shape.to_vec())).collect()
        };
        match self {
            Store::Pickle(s) => s.get_all_tensors().map(shapes).map_err(|e| e.to_string()),
            Store::Safetensors(s) => s.get_all_tensors().map(shapes).map_err(|e| e.to_string()),
        }
    }

    fn apply_to(&mut self, model: &mut DenseDepth) -> Result<ApplyResult, String> {
        match self {
            Store::Pickle(s) => s.apply_to(model).map_err(|e| e.to_string()),
            Store::Safetensors(s) => s.apply_to(model).map_err(|e| e.to_string()),
        }
    }
}

/// Whether the file starts like safetensors: an 8-byte little-endian header length, then `{`.
fn is_safetensors(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 9];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut head)).is_ok() && head[8] == b'{'
}

/// A module path in PyTorch's words, for messages: `encoder.denseblock2.layers.1.norm1.gamma`
/// -> `features.denseblock2.denselayer2.norm1.weight`.
pub fn torch_name(path: &str) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut after_layers = false;
    for (i, seg) in path.split('.').enumerate() {
        let seg = match seg {
            "encoder" if i == 0 => "features".to_string(),
            "layers" => {
                after_layers = true;
                continue;
            }
            s if after_layers => {
                after_layers = false;
                s.parse::<usize>().map(|n| format!("denselayer{}", n + 1)).unwrap_or_else(|_| s.to_string())
            }
            "gamma" => "weight".to_string(),
            "beta" => "bias".to_string(),
            "conv_a" => "convA".to_string(),
            "conv_b" => "convB".to_string(),
            s => s.to_string(),
        };
        parts.push(seg);
    }
    parts.join(".")
}

fn both_names(path: &str) -> String {
    format!("{} (PyTorch {})", path, torch_name(path))
}

/// Tensors a checkpoint may carry that the model does not use.
fn ignorable(name: &str) -> bool {
    name.ends_with("num_batches_tracked") || name.starts_with("classifier.") || name.contains(".classifier.")
}

/// Reads the DenseNet configuration (and decoder width) off the tensor shapes.
fn read_config(path: &Path, shapes: &BTreeMap<String, Vec<usize>>) -> Result<(DenseDepthConfig, bool), ImportError> {
    let not = |message: String| ImportError::NotDenseNet { path: path.into(), message };
    let shape = |key: &str| shapes.get(key).ok_or_else(|| not(format!("no tensor {}", torch_name(key))));
    let stem = shape("encoder.conv0.weight")?;
    // Three input channels is the reference model; six is ours reading the reference difference.
    let input =
        [InputChannels::Rgb, InputChannels::RgbDifference].into_iter().find(|i| stem.get(1) == Some(&i.count()));
    let input = match (stem.len(), input, stem.get(2), stem.get(3)) {
        (4, Some(input), Some(7), Some(7)) => input,
        _ => {
            return Err(not(format!(
                "encoder.conv0.weight has shape {stem:?}, expected [C, 3, 7, 7] (or [C, 6, 7, 7])"
            )));
        }
    };
    let growth_shape = shape("encoder.denseblock1.layers.0.conv2.weight")?;
    let bottleneck_shape = shape("encoder.denseblock1.layers.0.conv1.weight")?;
    let growth = growth_shape[0];
    if growth == 0 || bottleneck_shape[0] % growth != 0 {
        return Err(not(format!("dense layer widths {growth_shape:?} and {bottleneck_shape:?} do not fit a DenseNet")));
    }
    let mut blocks = [0usize; 4];
    for (b, count) in blocks.iter_mut().enumerate() {
        while shapes.contains_key(&format!("encoder.denseblock{}.layers.{}.conv1.weight", b + 1, *count)) {
            *count += 1;
        }
        if *count == 0 {
            return Err(not(format!("dense block {} has no layers", b + 1)));
        }
    }
    let encoder = DenseNetConfig::new(growth, blocks, stem[0], bottleneck_shape[0] / growth);
    let (_, bottleneck) = encoder.skip_channels();
    let mut config = DenseDepthConfig::new(encoder)
        .with_input(input)
        .with_full_resolution(shapes.contains_key("decoder.up5.conv_a.weight"))
        .with_pressure(shapes.contains_key("decoder.pressure.weight"))
        .with_force_head(shapes.get("decoder.force.conv.weight").map(|s| s[0]))
        .with_force_head_skip(shapes.contains_key("decoder.force.skip.weight").then_some(true));
    let encoder_only = !shapes.contains_key("decoder.conv2.weight");
    if !encoder_only {
        let width = shape("decoder.conv2.weight")?[0];
        // Shapes give int(bottleneck * w); prefer the customary widths that reproduce it.
        config.decoder_width = [0.5, 0.25, 1.0, 0.75]
            .into_iter()
            .find(|w| (bottleneck as f64 * w) as usize == width)
            .unwrap_or((width as f64 + 0.5) / bottleneck as f64);
        if config.decoder_channels()[0] != width {
            return Err(not(format!("decoder.conv2 has {width} channels for a {bottleneck}-channel bottleneck")));
        }
    }
    Ok((config, encoder_only))
}

/// Loads a DenseDepth `state_dict` or a torchvision DenseNet checkpoint. Every tensor of the file
/// must find its place (apart from the classifier and BatchNorm counters) and every parameter of
/// the model must be filled (apart from the decoder, for an encoder-only checkpoint).
pub fn load_pytorch(path: &Path, device: &Device) -> Result<Imported, ImportError> {
    let read = |e: &dyn std::fmt::Display| ImportError::Read { path: path.into(), message: e.to_string() };
    if !path.is_file() {
        return Err(read(&"no such file"));
    }
    let shapes = Store::open(path, false).shapes().map_err(|e| read(&e))?;
    let (config, encoder_only) = read_config(path, &shapes)?;
    let mut model = config.init(device);
    let result = Store::open(path, true).apply_to(&mut model).map_err(|e| read(&e))?;

    let problems: Vec<String> = result
        .errors
        .iter()
        .map(|e| match e {
            ApplyError::ShapeMismatch { path, expected, found } => {
                format!(
                    "tensor {} has shape {:?}, the model expects {:?}",
                    both_names(path),
                    found.to_vec(),
                    expected.to_vec()
                )
            }
            other => other.to_string(),
        })
        .collect();
    if !problems.is_empty() {
        return Err(ImportError::Mismatch { path: path.into(), problems });
    }
    let missing: Vec<String> = result
        .missing
        .iter()
        .map(|(p, _)| p.clone())
        .filter(|p| !(encoder_only && p.starts_with("decoder.")))
        .map(|p| both_names(&p))
        .collect();
    if !missing.is_empty() {
        return Err(ImportError::Missing { path: path.into(), names: missing });
    }
    let unexpected: Vec<String> = result.unused.iter().filter(|n| !ignorable(n)).map(|n| both_names(n)).collect();
    if !unexpected.is_empty() {
        return Err(ImportError::Unexpected { path: path.into(), names: unexpected });
    }
    Ok(Imported { config, model, encoder_only })
}
