//! Weights out to PyTorch: a `state_dict` under the reference DenseDepth model's key names
//! (`encoder.original_model.features...`, `decoder.up1.convA...`), as safetensors, so that
//!
//! ```python
//! from safetensors.torch import load_file
//! model.load_state_dict(load_file("weights.safetensors"), strict=True)
//! ```
//!
//! loads it into the reference model. [`crate::import::load_pytorch`] reads such a file back.
//!
//! Reading uses burn-store's `PytorchStore`/`SafetensorsStore` with its PyTorch adapter and regex
//! key remapping ([`crate::import`]). Writing does not, for two reasons a save through
//! `SafetensorsStore` with `BurnToPyTorchAdapter` cannot meet: the reference names its layers from
//! one (`denselayer1`) where Burn's vectors count from zero (`layers.0`), a shift no regex
//! replacement can make; and a strict `load_state_dict` asks for tensors the module does not hold
//! (each BatchNorm's `num_batches_tracked`, torchvision's classifier), which the store writes only
//! from the module. `tests/torch_names.rs` checks the result against the PyTorch fixture's keys.

use std::collections::HashMap;

use burn::store::ModuleSnapshot;

use crate::InputChannels;
use crate::import::torch_name;
use crate::network::{DenseDepth, DenseDepthConfig};

/// The reference DenseDepth's key for one of this crate's module paths:
/// `encoder.denseblock1.layers.0.norm1.gamma` -> `encoder.original_model.features.denseblock1.denselayer1.norm1.weight`,
/// `decoder.up1.conv_a.weight` -> `decoder.up1.convA.weight`.
pub fn densedepth_key(path: &str) -> String {
    let name = torch_name(path);
    if name.starts_with("features.") { format!("encoder.original_model.{name}") } else { name }
}

/// How `config` differs from the reference DenseDepth's architecture, for people: each entry
/// is what a PyTorch user must change in the reference model before loading. Empty: it loads
/// as it is.
pub fn differences_from_reference(config: &DenseDepthConfig) -> Vec<String> {
    let mut out = Vec::new();
    if config.input != InputChannels::Rgb {
        out.push(format!(
            "the network reads {} channels ({}): conv0 takes {} input channels, not 3",
            config.input.count(),
            config.input.name(),
            config.input.count()
        ));
    }
    if config.full_resolution {
        out.push(
            "the output is at the input's resolution: a fifth up block (decoder.up5, skip = the input) before conv3"
                .to_string(),
        );
    }
    if config.pressure {
        out.push("the network has a pressure output: a second 3x3 convolution (decoder.pressure) beside conv3".into());
    }
    if let Some(hidden) = config.force_head {
        let skip = if config.force_head_reads_transition2() {
            format!(
                ", plus the same on relu(transition2) through its own 1x1 convolution to {hidden} channels \
                 (decoder.force.skip)"
            )
        } else {
            String::new()
        };
        out.push(format!(
            "the network has a force head (decoder.force): a 1x1 convolution to {hidden} channels on relu(norm5), \
             LeakyReLU(0.2), the mean over the image{skip}, a linear map to 3"
        ));
    }
    out
}

/// The classes of torchvision's DenseNet classifier (ImageNet's), which the reference model keeps.
const CLASSES: usize = 1000;
const CLASSIFIER_WEIGHT: &str = "encoder.original_model.classifier.weight";
const CLASSIFIER_BIAS: &str = "encoder.original_model.classifier.bias";

/// A tensor that could not be written out.
#[derive(Debug, thiserror::Error)]
pub enum TorchExportError {
    /// A tensor's data could not be read or converted to f32.
    #[error("{name}: {message}")]
    Tensor { name: String, message: String },
    /// The safetensors encoder refused the collection.
    #[error("safetensors: {0}")]
    Encode(#[from] safetensors::SafeTensorError),
}

/// The model's weights as a safetensors `state_dict` under the reference model's names, with
/// what PyTorch's own `state_dict` has beside them: each BatchNorm's `num_batches_tracked` (0,
/// int64) and the encoder's unused ImageNet classifier (zeros).
pub fn state_dict_safetensors(model: &DenseDepth) -> Result<Vec<u8>, TorchExportError> {
    let mut tensors: Vec<(String, safetensors::Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    for t in model.collect(None, None, true) {
        let path = t.name.clone();
        let failed = |message: String| TorchExportError::Tensor { name: path.clone(), message };
        let data = burn::store::bridge::into_data(t).map_err(|e| failed(e.to_string()))?;
        let mut shape = data.shape().to_vec();
        let mut values = data.convert::<f32>().try_into_vec::<f32>().map_err(|e| failed(format!("{e:?}")))?;
        if let (&[inputs, outputs], true) = (shape.as_slice(), path.ends_with(".linear.weight")) {
            // Burn's Linear holds [in, out]; PyTorch's nn.Linear [out, in].
            values = (0..inputs * outputs).map(|k| values[(k % inputs) * outputs + k / inputs]).collect();
            shape = vec![outputs, inputs];
        }
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let key = densedepth_key(&path);
        if let Some(norm) = key.strip_suffix(".running_var") {
            tensors.push((
                format!("{norm}.num_batches_tracked"),
                safetensors::Dtype::I64,
                vec![],
                0i64.to_le_bytes().to_vec(),
            ));
        }
        if key == "encoder.original_model.features.norm5.running_var" {
            // torchvision's DenseNet carries an ImageNet classifier that DenseDepth never runs
            // but whose keys a strict load asks for: zeros of its shape.
            let features = shape[0];
            let zeros = |n: usize| vec![0u8; 4 * n];
            tensors.push((
                CLASSIFIER_WEIGHT.into(),
                safetensors::Dtype::F32,
                vec![CLASSES, features],
                zeros(CLASSES * features),
            ));
            tensors.push((CLASSIFIER_BIAS.into(), safetensors::Dtype::F32, vec![CLASSES], zeros(CLASSES)));
        }
        tensors.push((key, safetensors::Dtype::F32, shape, bytes));
    }
    let views = tensors
        .iter()
        .map(|(k, dtype, shape, bytes)| {
            safetensors::tensor::TensorView::new(*dtype, shape.clone(), bytes).map(|v| (k.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()?;
    // `format: pt` is what `safetensors.torch.save_file` writes.
    let metadata = HashMap::from([("format".to_string(), "pt".to_string())]);
    Ok(safetensors::serialize(views, Some(metadata))?)
}
