//! Weights out under PyTorch's names: the reference fixture's `state_dict` comes back key for
//! key (shapes included) and bit for bit, and import -> export -> import is exact for our own architectures too.

use crate::common;

use std::collections::BTreeMap;

use burn::store::{ModuleSnapshot, ModuleStore, PytorchStore};
use common::fixtures;
use model::import::load_pytorch;
use model::torch::{densedepth_key, differences_from_reference, state_dict_safetensors};
use model::{DenseDepth, DenseDepthConfig, DenseNetConfig, InputChannels};

/// Every tensor of `model` by its path: shape and the f32 values' bits.
fn tensors(model: &DenseDepth) -> BTreeMap<String, (Vec<usize>, Vec<u32>)> {
    model
        .collect(None, None, true)
        .into_iter()
        .map(|t| {
            let name = t.name.clone();
            let data = burn::store::bridge::into_data(t).unwrap();
            let shape = data.shape().to_vec();
            (name, (shape, data.try_into_vec::<f32>().unwrap().iter().map(|v| v.to_bits()).collect()))
        })
        .collect()
}

/// Exports `model` under PyTorch's names to a file in `dir` and imports it again.
fn round_trip(model: &DenseDepth, dir: &std::path::Path) -> (Vec<u8>, model::import::Imported) {
    let bytes = state_dict_safetensors(model).unwrap();
    let path = dir.join("weights.safetensors");
    std::fs::write(&path, &bytes).unwrap();
    let back = load_pytorch(&path, &model::backend::default_device()).unwrap();
    (bytes, back)
}

#[test]
fn keys_follow_the_reference_model() {
    assert_eq!(
        densedepth_key("encoder.denseblock1.layers.0.norm1.gamma"),
        "encoder.original_model.features.denseblock1.denselayer1.norm1.weight"
    );
    assert_eq!(densedepth_key("encoder.norm5.running_var"), "encoder.original_model.features.norm5.running_var");
    assert_eq!(densedepth_key("decoder.up1.conv_a.weight"), "decoder.up1.convA.weight");
    assert_eq!(densedepth_key("decoder.conv3.bias"), "decoder.conv3.bias");
}

#[test]
fn our_architectures_round_trip_exactly_and_say_how_they_differ() {
    let tmp = tempfile::tempdir().unwrap();
    let device = model::backend::default_device();
    for (input, full, force, skip) in [
        (InputChannels::Rgb, false, false, false),
        (InputChannels::RgbDifference, true, false, false),
        (InputChannels::Rgb, false, true, false),
        (InputChannels::Rgb, false, true, true),
    ] {
        device.seed(5);
        let config = DenseDepthConfig::new(DenseNetConfig::tiny())
            .with_input(input)
            .with_full_resolution(full)
            .with_pressure(force)
            .with_force_head(force.then_some(8))
            .with_force_head_skip(skip.then_some(true));
        let model = config.init(&device);
        let (bytes, back) = round_trip(&model, tmp.path());
        assert_eq!(back.config, config, "the configuration read off the shapes");
        assert!(!back.encoder_only);
        assert_eq!(tensors(&back.model), tensors(&model), "{input:?}, full {full}: not bit-exact");
        // One num_batches_tracked per BatchNorm, int64, as PyTorch's state_dict has.
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let norms = tensors(&model).keys().filter(|k| k.ends_with("running_var")).count();
        let counters: Vec<_> = st.names().into_iter().filter(|n| n.ends_with("num_batches_tracked")).collect();
        assert_eq!(counters.len(), norms);
        assert_eq!(st.tensor(counters[0]).unwrap().dtype(), safetensors::Dtype::I64);
        let bottleneck = config.encoder.skip_channels().1;
        assert_eq!(st.tensor("encoder.original_model.classifier.weight").unwrap().shape(), [1000, bottleneck]);
        let differences = differences_from_reference(&config);
        let want = usize::from(input != InputChannels::Rgb) + usize::from(full) + 2 * usize::from(force);
        assert_eq!(differences.len(), want, "{differences:?}");
        if force {
            // PyTorch's nn.Linear holds [out, in]; Burn's [in, out].
            let key = "decoder.force.linear.weight";
            assert_eq!(st.tensor(key).unwrap().shape(), [3, 8]);
            let burn = &tensors(&model)[key].1;
            let torch: Vec<u32> =
                st.tensor(key).unwrap().data().chunks(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
            assert_eq!(torch[1], burn[3], "[0][1] of PyTorch's is [1][0] of Burn's");
            let transition2 = config.encoder.skip_channels().0[3];
            let skip_shape = st.tensor("decoder.force.skip.weight").map(|t| t.shape().to_vec()).ok();
            assert_eq!(skip_shape, skip.then(|| vec![8, transition2, 1, 1]));
            assert_eq!(differences.iter().any(|d| d.contains("decoder.force.skip")), skip);
        }
    }
}

#[test]
#[ignore = "needs ../shared"]
fn the_reference_state_dict_comes_back_key_for_key_and_bit_for_bit() {
    let pth = fixtures().join("densedepth_tiny.pth");
    let device = model::backend::default_device();
    let imported = load_pytorch(&pth, &device).unwrap();
    assert!(differences_from_reference(&imported.config).is_empty());
    let tmp = tempfile::tempdir().unwrap();
    let (bytes, back) = round_trip(&imported.model, tmp.path());
    assert_eq!(tensors(&back.model), tensors(&imported.model));

    // The exported file against the PyTorch file itself, read without any renaming.
    let mut original = PytorchStore::from_file(&pth).map_indices_contiguous(false);
    let original = original.get_all_tensors().unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut exported: Vec<String> = st.names().into_iter().map(str::to_string).collect();
    exported.sort();
    let want: Vec<String> = original.keys().cloned().collect();
    assert_eq!(exported, want, "the key sets differ");
    for (name, t) in original {
        let view = st.tensor(name).unwrap();
        assert_eq!(view.shape(), t.shape.to_vec().as_slice(), "{name}");
        if name.ends_with("num_batches_tracked") || name.contains(".classifier.") {
            // PyTorch counts batches and keeps torchvision's ImageNet classifier; DenseDepth
            // uses neither, the import drops them and the export writes zeros of their shapes.
            continue;
        }
        let data = burn::store::bridge::into_data(t.clone()).unwrap();
        let want: Vec<u8> = data.try_into_vec::<f32>().unwrap().iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(view.data() == want.as_slice(), "{name}: values differ");
    }
}

#[test]
fn a_bundle_exported_with_torch_names_says_so_and_still_loads() {
    use model::bundle::{BundleFile, SafetensorsKeys, WEIGHTS_SAFETENSORS, load_bundle, write_bundle};
    let tmp = tempfile::tempdir().unwrap();
    let device = model::backend::default_device();
    device.seed(2);
    let config = DenseDepthConfig::new(DenseNetConfig::tiny());
    let net = config.init(&device);
    let file = BundleFile {
        safetensors_keys: SafetensorsKeys::Pytorch,
        ..BundleFile::new(config.clone(), [64, 64], sensor::Sensor::default(), model::DepthScale::paper(9.4))
    };
    let dir = tmp.path().join("bundle");
    write_bundle(&dir, &net, &file, None, &[]).unwrap();
    let (loaded, read) = load_bundle(&dir, &device).unwrap();
    assert_eq!(read.safetensors_keys, SafetensorsKeys::Pytorch);
    assert!(read.sha256.contains_key(WEIGHTS_SAFETENSORS));
    assert_eq!(tensors(&loaded), tensors(&net));
    let st = std::fs::read(dir.join(WEIGHTS_SAFETENSORS)).unwrap();
    let st = safetensors::SafeTensors::deserialize(&st).unwrap();
    assert!(st.names().iter().any(|n| n.starts_with("encoder.original_model.features.denseblock1.denselayer1.")));
    let back = load_pytorch(&dir.join(WEIGHTS_SAFETENSORS), &device).unwrap();
    assert_eq!(tensors(&back.model), tensors(&net));
    // A bundle written before the field reads as Burn's names.
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("bundle.json")).unwrap()).unwrap();
    assert_eq!(json["safetensors_keys"], "pytorch");
    json.as_object_mut().unwrap().remove("safetensors_keys");
    let old: BundleFile = serde_json::from_value(json).unwrap();
    assert_eq!(old.safetensors_keys, SafetensorsKeys::Burn);
}
