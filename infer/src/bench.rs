//! `infer bench`: milliseconds per frame on a device, beside the bundle's recorded test error.

use std::time::Instant;

use formats::stats::Summary;
use image::RgbImage;
use sensor::CONTACT_THRESHOLD_MM;

use crate::{InferError, Predictor};

/// Times (ms: median, quartiles, range) of one frame's stages.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameTimes {
    /// Input tensor to output tensor, synchronised (the network alone).
    pub network_ms: Summary,
    /// PNG bytes to depth map and contact point cloud, the network always running.
    pub end_to_end_ms: Summary,
    /// What `infer predict` (and the Python package's `predict(path, always=True)`) does with a
    /// frame: decode, the crop and its colour and channel-order checks, the network, the contact
    /// mask and the point cloud.
    pub as_predict_ms: Summary,
    /// The same for a frame without contact, which the gate answers without the network.
    pub gated_no_contact_ms: Summary,
    pub repeats: usize,
}

fn timed_ms(repeats: usize, mut f: impl FnMut() -> Result<(), InferError>) -> Result<Summary, InferError> {
    f()?; // warm-up: first-use allocations, kernel compilation on GPUs
    let mut times = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let start = Instant::now();
        f()?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Summary::of(times))
}

/// Times `frame_png` (an encoded crop) through `predictor`; `no_contact_png` is a frame the
/// gate should pass over (the unit's reference image).
pub fn time_frames(
    predictor: &Predictor,
    frame_png: &[u8],
    no_contact_png: &[u8],
    repeats: usize,
) -> Result<FrameTimes, InferError> {
    let repeats = repeats.max(1);
    let decode = |bytes: &[u8]| -> Result<RgbImage, InferError> {
        let path = std::path::Path::new("<frame>");
        Ok(sensor::frame::crop(path, sensor::frame::decode(path, bytes)?, &predictor.file.sensor)?)
    };
    let frame = decode(frame_png)?;
    let input = predictor.input(std::slice::from_ref(&frame))?;
    let network_ms = timed_ms(repeats, || {
        // Reading the output back waits for the device: the time includes the whole forward.
        let out = predictor.forward(input.clone());
        let _ = out.into_data();
        Ok(())
    })?;
    let end_to_end_ms = timed_ms(repeats, || {
        let depth = predictor.predict_network(&[decode(frame_png)?])?.remove(0);
        let cloud = predictor.point_cloud(&depth, CONTACT_THRESHOLD_MM);
        std::hint::black_box(cloud);
        Ok(())
    })?;
    let as_predict_ms = timed_ms(repeats, || {
        let path = std::path::Path::new("<frame>");
        let frame = predictor.accept_frame(path, sensor::frame::decode(path, frame_png)?, true)?;
        let p = predictor.predict_network_all(std::slice::from_ref(&frame))?.remove(0);
        std::hint::black_box(Predictor::contact_mask(&p.depth, CONTACT_THRESHOLD_MM));
        std::hint::black_box(predictor.point_cloud(&p.depth, CONTACT_THRESHOLD_MM));
        Ok(())
    })?;
    let gated_no_contact_ms = timed_ms(repeats, || {
        let (depth, _) = predictor.predict_gated(&decode(no_contact_png)?)?;
        std::hint::black_box(predictor.point_cloud(&depth, CONTACT_THRESHOLD_MM));
        Ok(())
    })?;
    Ok(FrameTimes { network_ms, end_to_end_ms, as_predict_ms, gated_no_contact_ms, repeats })
}

/// The test error the bundle's training recorded (mean per-image L1 over useful pixels, mm).
pub fn recorded_test_l1_mm(predictor: &Predictor) -> Option<f64> {
    predictor.file.training.as_ref().and_then(|t| t.test_l1_mm())
}
