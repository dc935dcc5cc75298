//! ONNX export: the graph run by tract (pure Rust) gives Burn's output within 1e-4 relative, at
//! sizes that are not multiples of 32, for batches of any size from one file, for our variants
//! and for the PyTorch fixture; the metadata carries the input encoding and depth scale.

use crate::common;

use burn::tensor::Distribution;
use common::{SafeFile, errors, fixtures, to_vec};
use model::bundle::BundleFile;
use model::{DenseDepth, DenseDepthConfig, DenseNetConfig, DepthScale, InputChannels};
use tract_onnx::prelude::*;

fn bundle_file(config: &DenseDepthConfig) -> BundleFile {
    BundleFile::new(config.clone(), [64, 64], sensor::Sensor::default(), DepthScale::paper(9.4))
}

/// The exported `bytes` run by tract on `input` ([n, c, h, w] values).
fn tract_run(bytes: &[u8], shape: [usize; 4], input: Vec<f32>) -> (Vec<usize>, Vec<f32>) {
    let model = tract_onnx::onnx().model_for_read(&mut &bytes[..]).unwrap();
    let plan =
        model.with_input_fact(0, f32::fact(shape).into()).unwrap().into_optimized().unwrap().into_runnable().unwrap();
    let input = tract_ndarray::Array4::from_shape_vec(shape, input).unwrap();
    let out = plan.run(tvec!(Tensor::from(input).into_tvalue())).unwrap();
    let view = out[0].to_plain_array_view::<f32>().unwrap();
    (view.shape().to_vec(), view.iter().copied().collect())
}

fn check(net: &DenseDepth, bytes: &[u8], shape: [usize; 4], what: &str) {
    let device = model::backend::default_device();
    let x = burn::tensor::Tensor::<4>::random(shape, Distribution::Uniform(0.0, 1.0), &device);
    let input = x.to_data().try_to_vec::<f32>().unwrap();
    let want = net.forward(x);
    let want_shape = want.dims().to_vec();
    let (got_shape, got) = tract_run(bytes, shape, input);
    assert_eq!(got_shape, want_shape, "{what} {shape:?}");
    let (abs, rel) = errors(&got, &to_vec(want));
    assert!(rel <= 1e-4, "{what} {shape:?}: max_abs_err={abs} max_rel_err={rel}");
}

#[test]
fn tract_runs_the_export_as_burn_does_at_any_size_and_batch() {
    let device = model::backend::default_device();
    for (input, full) in [(InputChannels::Rgb, false), (InputChannels::RgbDifference, true)] {
        device.seed(11);
        let config = DenseDepthConfig::new(DenseNetConfig::tiny()).with_input(input).with_full_resolution(full);
        let net = config.init(&device);
        let bytes = model::onnx::export(&net, &bundle_file(&config)).unwrap();
        let c = input.count();
        // One file: batch, height and width are free.
        for shape in [[1, c, 64, 64], [2, c, 45, 71], [3, c, 33, 96]] {
            check(&net, &bytes, shape, &format!("{input:?}, full {full}"));
        }
    }
}

/// Large 3x3 convolutions run through Winograd's F(4x4, 3x3) in flex's kernels (the image
/// holding 64 of its tiles or more, the weight 1,024 channel pairs or more): the `small` preset
/// at 128x128 takes it in dense block 1 (64 -> 16 channels at 32x32) and decoder block 3's first
/// convolution (80 -> 16 at 32x32), and F(2x2, 3x3) everywhere else; at 144x132 too, whose
/// sides no tile divides. tract, which has no Winograd path of ours, is the reference.
#[test]
fn the_larger_winograd_tile_gives_tracts_output() {
    let device = model::backend::default_device();
    device.seed(12);
    let config = DenseDepthConfig::new(DenseNetConfig::small());
    let net = config.init(&device);
    let bytes = model::onnx::export(&net, &bundle_file(&config)).unwrap();
    for shape in [[1, 3, 128, 128], [2, 3, 144, 132]] {
        check(&net, &bytes, shape, "small");
    }
}

#[test]
fn the_metadata_says_how_to_feed_and_read_the_model() {
    let device = model::backend::default_device();
    let config = DenseDepthConfig::new(DenseNetConfig::tiny());
    let file = bundle_file(&config);
    let bytes = model::onnx::export(&config.init(&device), &file).unwrap();
    let model = tract_onnx::onnx().model_for_read(&mut &bytes[..]).unwrap();
    let prop = |key: &str| {
        let t =
            model.properties.get(&format!("onnx.metadata_props.densetact.{key}")).unwrap_or_else(|| panic!("{key}"));
        t.to_plain_array_view::<String>().unwrap().iter().next().unwrap().clone()
    };
    assert_eq!(prop("input_encoding"), file.input_encoding);
    let scale: DepthScale = serde_json::from_str(&prop("depth_scale")).unwrap();
    assert_eq!(scale, file.depth_scale);
    let read: DenseDepthConfig = serde_json::from_str(&prop("model")).unwrap();
    assert_eq!(read, config);
    assert_eq!(prop("input_hw"), "64x64");
    assert_eq!(model.input_outlets().unwrap().len(), 1);
    assert_eq!(model.node(model.input_outlets().unwrap()[0].node).name, model::onnx::INPUT);
}

#[test]
#[ignore = "needs ../shared"]
fn the_pytorch_fixture_exported_gives_pytorchs_output() {
    let dir = fixtures();
    let device = model::backend::default_device();
    let imported = model::import::load_pytorch(&dir.join("densedepth_tiny.pth"), &device).unwrap();
    let bytes = model::onnx::export(&imported.model, &bundle_file(&imported.config)).unwrap();
    let io = SafeFile::open(&dir.join("densedepth_tiny_io.safetensors"));
    let (input, shape) = io.get("input");
    let (want, want_shape) = io.get("output");
    let (got_shape, got) = tract_run(&bytes, shape.clone().try_into().unwrap(), input);
    assert_eq!(got_shape, want_shape);
    let (abs, rel) = errors(&got, &want);
    assert!(rel <= 1e-4, "max_abs_err={abs} max_rel_err={rel}");
}

/// A network with the pressure output exports it as the graph's second output, named and
/// scaled in the metadata; one with the force head too exports the head's force (N,
/// `[batch, 3]`) as the third; tract gives Burn's values for all.
#[test]
fn the_pressure_output_is_the_graphs_second_and_the_force_head_its_third() {
    let device = model::backend::default_device();
    for (head, skip) in [(None, false), (Some(8), false), (Some(8), true)] {
        device.seed(5);
        let config = DenseDepthConfig::new(DenseNetConfig::tiny())
            .with_pressure(true)
            .with_force_head(head)
            .with_force_head_skip(skip.then_some(true));
        let net = config.init(&device);
        let bytes = model::onnx::export(&net, &bundle_file(&config)).unwrap();
        let shape = [2, 3, 40, 52];
        let x = burn::tensor::Tensor::<4>::random(shape, Distribution::Uniform(0.0, 1.0), &device);
        let input = x.to_data().try_to_vec::<f32>().unwrap();
        let heads = net.forward_heads(x);
        let model = tract_onnx::onnx().model_for_read(&mut &bytes[..]).unwrap();
        let names: Vec<&str> =
            model.output_outlets().unwrap().iter().map(|o| model.node(o.node).name.as_str()).collect();
        // (tract names outputs by the nodes that make them.)
        let mut want_names = vec!["decoder.conv3", "decoder.pressure"];
        want_names.extend(head.map(|_| "decoder.force.n"));
        assert_eq!(names, want_names);
        let scale =
            model.properties.get("onnx.metadata_props.densetact.pressure_kpa_per_unit").expect("pressure scale");
        let scale = scale.to_plain_array_view::<String>().unwrap().iter().next().unwrap().clone();
        assert_eq!(scale.parse::<f32>().unwrap(), model::PRESSURE_KPA_PER_UNIT);
        let plan = model
            .with_input_fact(0, f32::fact(shape).into())
            .unwrap()
            .into_optimized()
            .unwrap()
            .into_runnable()
            .unwrap();
        let out =
            plan.run(tvec!(Tensor::from(tract_ndarray::Array4::from_shape_vec(shape, input).unwrap()).into_tvalue()));
        let out = out.unwrap();
        let map = |t: burn::tensor::Tensor<4>| (t.dims().to_vec(), to_vec(t));
        let mut want = vec![map(heads.depth), map(heads.pressure.expect("the pressure output"))];
        assert_ne!(want[0].1, want[1].1, "two heads, two maps");
        if let Some(f) = heads.force {
            want.push((f.dims().to_vec(), to_vec(f.mul_scalar(model::FORCE_N_PER_LOSS_UNIT))));
        }
        assert_eq!(out.len(), want.len());
        for (got, (dims, want)) in out.iter().zip(want) {
            let view = got.to_plain_array_view::<f32>().unwrap();
            assert_eq!(view.shape(), dims.as_slice());
            let (abs, rel) = errors(&view.iter().copied().collect::<Vec<_>>(), &want);
            assert!(rel <= 1e-4, "head {head:?}, skip {skip}: max_abs_err={abs} max_rel_err={rel}");
        }
    }
}
