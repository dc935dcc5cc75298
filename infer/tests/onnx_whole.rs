//! The whole predictor as one ONNX graph (`model::onnx::export_whole`), run by tract, gives
//! `Predictor::predict_all`'s depth within 1e-3 mm, its pressure and force, and its gate's
//! answer: on a pressed frame, on the same frame drifted (the balance at work; once until its
//! bright spots clip), and on an
//! untouched frame, as it is and drifted (the gate, on the balanced comparison, answers zeros
//! through its `If`); for RGB and reference-difference inputs, and with the force head.

use crate::common;

use burn::nn::conv::Conv2d;
use common::{bundle_with, pressed};
use image::RgbImage;
use infer::{Prediction, Predictor};
use model::onnx::{WholePredictor, export_whole};
use model::{DenseDepth, DenseDepthConfig, DenseNetConfig, InputChannels};
use tract_onnx::prelude::*;

/// What the graph gives for one frame: depth, and pressure and force where it has them, and
/// whether the network ran.
struct Whole {
    depth_mm: Vec<f32>,
    pressure_kpa: Option<Vec<f32>>,
    force_n: Option<Vec<f32>>,
    contact: bool,
}

fn run(bytes: &[u8], frame: &RgbImage) -> Whole {
    let model = tract_onnx::onnx().model_for_read(&mut &bytes[..]).unwrap();
    let plan = model.into_optimized().unwrap().into_runnable().unwrap();
    let n = frame.width() as usize;
    let input = tract_ndarray::Array3::from_shape_vec([n, n, 3], frame.as_raw().clone()).unwrap();
    let out = plan.run(tvec!(Tensor::from(input).into_tvalue())).unwrap();
    let floats = |i: usize| out[i].to_plain_array_view::<f32>().unwrap().iter().copied().collect::<Vec<f32>>();
    let contact = *out[out.len() - 1].to_plain_array_view::<bool>().unwrap().iter().next().unwrap();
    match out.len() {
        2 => Whole { depth_mm: floats(0), pressure_kpa: None, force_n: None, contact },
        4 => Whole { depth_mm: floats(0), pressure_kpa: Some(floats(1)), force_n: Some(floats(2)), contact },
        k => panic!("{k} outputs"),
    }
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// `frame` with every channel scaled (an LED warming, a camera's white balance moving).
fn drifted(frame: &RgbImage, gain: [f32; 3]) -> RgbImage {
    let mut out = frame.clone();
    for p in out.pixels_mut() {
        p.0 = [0, 1, 2].map(|c| (p.0[c] as f32 * gain[c]).round().clamp(0.0, 255.0) as u8);
    }
    out
}

fn check(config: DenseDepthConfig, edit: impl FnOnce(DenseDepth) -> DenseDepth, min_deepest_mm: f32) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bundle");
    let renderer = bundle_with(&dir, config, |net, _| edit(net));
    let device = model::backend::default_device();
    let predictor = Predictor::load(&dir, &device).unwrap();
    let (net, file) = model::bundle::load_bundle(&dir, &device).unwrap();
    let bytes =
        export_whole(&WholePredictor { net: &net, file: &file, reference: predictor.reference.as_ref() }).unwrap();
    let (_, frame) = pressed(&renderer);
    let untouched = renderer.render(&vec![0.0; frame.len() / 3], Some(77));
    let cases = [
        ("pressed", frame.clone()),
        ("drifted", drifted(&frame, [1.06, 0.97, 1.03])),
        // Bright enough that the LEDs' spots clip at 255 (the balance lifts them to the reference).
        ("drifted until it clips", drifted(&frame, [1.45, 1.4, 1.5])),
        ("untouched, drifted", drifted(&untouched, [0.95, 1.04, 1.02])),
        // A camera far darker: the gate compares in the reference's colours, its noise scaled up.
        ("pressed, darker", drifted(&frame, [0.72, 0.75, 0.7])),
        ("untouched, darker", drifted(&untouched, [0.72, 0.75, 0.7])),
        ("untouched", untouched.clone()),
        // Every level clipped: no channel keeps enough samples for a fit, so none is undone.
        ("saturated", RgbImage::from_pixel(untouched.width(), untouched.height(), image::Rgb([255; 3]))),
    ];
    let clipped = |f: &RgbImage| f.as_raw().iter().filter(|&&v| v == 255).count();
    assert!(clipped(&cases[2].1) > clipped(&frame) + 100, "the bright case clips");
    for (what, frame) in cases {
        let want: Prediction = predictor.predict_all(&frame).unwrap();
        let got = run(&bytes, &frame);
        assert_eq!(got.contact, want.network_ran, "{what}: the gate");
        let diff = max_diff(&got.depth_mm, &want.depth.depth_mm);
        let deepest = want.depth.depth_mm.iter().fold(0f32, |m, &d| m.max(d));
        eprintln!("{what}: deepest {deepest:.4} mm, largest difference {diff:e} mm");
        assert!(diff <= 1e-3, "{what}: {diff} mm from predict");
        if what.starts_with("untouched") {
            assert!(!got.contact && got.depth_mm.iter().all(|&d| d == 0.0), "an untouched frame reads zeros");
        } else if what != "saturated" {
            assert!(got.contact && deepest > min_deepest_mm, "{what}: the pressed frame reads a dent ({deepest} mm)");
        }
        if let Some(force) = want.force {
            let pressure = got.pressure_kpa.expect("the pressure output");
            let peak = force.pressure.pressure_kpa.iter().fold(0f32, |m, &p| m.max(p));
            let diff = max_diff(&pressure, &force.pressure.pressure_kpa);
            assert!(diff <= 1e-3 * peak.max(1.0), "{what}: pressure {diff} kPa from predict (peak {peak})");
            if file.model.force_head.is_some() && what.starts_with("untouched") {
                assert_eq!(force.wrench.force_magnitude_n(), 0.0, "{what}: an untouched frame pushes nothing");
            }
            let got_n = got.force_n.expect("the force output");
            for (g, w) in got_n.iter().zip(force.wrench.force_n) {
                assert!(
                    (*g as f64 - w).abs() <= 1e-4 * force.wrench.force_magnitude_n().max(1.0),
                    "{what}: {got_n:?} N against {:?}",
                    force.wrench.force_n
                );
            }
        }
    }
    // The metadata states the crop rule with the origin `infer` cuts at.
    let model = tract_onnx::onnx().model_for_read(&mut &bytes[..]).unwrap();
    let crop = model.properties.get("onnx.metadata_props.densetact.crop").expect("the crop rule");
    let crop = crop.to_plain_array_view::<String>().unwrap().iter().next().unwrap().clone();
    let crop: serde_json::Value = serde_json::from_str(&crop).unwrap();
    let (x0, y0) = file.sensor.crop_origin_px();
    assert_eq!(crop["origin_px"], serde_json::json!([x0, y0]));
    assert_eq!(crop["size_px"], file.sensor.crop_size_px);
}

/// `conv`'s weights on the input channels `channels` times `gain`. An untrained network's
/// answer to a dent is a ten-thousandth of a millimetre; scaled up, it is enough to compare.
/// Scaling the last convolution scales the untared depth too (and its rounding, which the tare
/// then leaves behind), so the RGB case scales less; the difference channels' weights (zero
/// input on the reference frame) scale the dent's answer alone.
fn scaled(mut conv: Conv2d, channels: std::ops::Range<usize>, gain: f32) -> Conv2d {
    let w = conv.weight.val();
    let [o, _, kh, kw] = w.dims();
    let part = w.clone().slice([0..o, channels.clone(), 0..kh, 0..kw]).mul_scalar(gain);
    conv.weight = burn::module::Param::from_tensor(w.slice_assign([0..o, channels, 0..kh, 0..kw], part));
    conv
}

/// Both inputs in one test, one after the other: each bundle's network is drawn from the seeded
/// device, which tests running side by side would share.
#[test]
fn the_whole_predictor_in_onnx_gives_predicts_depth_pressure_and_force() {
    let edit = |mut net: DenseDepth| {
        let n = net.decoder.conv3.weight.dims()[1];
        net.decoder.conv3 = scaled(net.decoder.conv3, 0..n, 5e4);
        net
    };
    check(DenseDepthConfig::new(DenseNetConfig::tiny()), edit, sensor::CONTACT_THRESHOLD_MM);
    let config = DenseDepthConfig::new(DenseNetConfig::tiny()).with_input(InputChannels::RgbDifference);
    let edit = |mut net: DenseDepth| {
        net.encoder.conv0 = scaled(net.encoder.conv0, 3..6, 2e4);
        net
    };
    check(config.clone().with_pressure(true), edit, 0.1);
    // The force head: its force, tared, and the pressure scaled to it.
    check(config.with_pressure(true).with_force_head(Some(8)), edit, 0.1);
}
