//! Calibration of simulated units from their saw-tooth images, against their known truth.

use dataset::calibration::{Calibration, CalibrationOptions, GpTarget, calibrate, compare};
use dataset::{SawTooth, SawToothShot, SensorUnit};

/// The goals: RMS over the useful disk.
const MAX_RMS_PX: f64 = 0.5;
const MAX_RMS_DEG: f64 = 0.1;

fn shot(seed: u64, noise_scale: f64) -> SawToothShot {
    SawToothShot { seed, noise_scale, ..Default::default() }
}

fn check(unit: &SensorUnit, cal: &Calibration, what: &str) {
    let (px, deg) = compare(&cal.sensor, &unit.sensor);
    eprintln!(
        "{what}: rms_px {px:.3} (stated +-{:.3}) rms_deg {deg:.4}, {} edges, missing {:?}",
        cal.uncertainty_px,
        cal.edges.len(),
        cal.missing
    );
    assert!(px <= MAX_RMS_PX && deg <= MAX_RMS_DEG, "{what}: rms {px:.3} px, {deg:.4} deg");
    assert!(px <= cal.uncertainty_px, "{what}: off by {px:.3} px, more than the stated {:.3}", cal.uncertainty_px);
    let t = &unit.sensor.correspondence;
    let c = &cal.sensor.correspondence;
    assert!((c.centre_u_px - t.centre_u_px).hypot(c.centre_v_px - t.centre_v_px) < 0.2, "{what}: centre");
    assert!(cal.max_sd_deg.is_finite() && cal.max_sd_deg < 0.5, "{what}: predictive sd {}", cal.max_sd_deg);
}

#[test]
fn several_units_and_noise_levels_calibrate_within_goals() {
    for (seed, noise) in [(1, 0.0), (2, 0.5), (3, 1.0), (4, 2.0), (5, 3.0)] {
        let unit = SensorUnit::from_seed(seed, 25.0);
        let img = shot(seed, noise).render(&unit);
        let cal = calibrate(&img, &CalibrationOptions::default()).unwrap();
        check(&unit, &cal, &format!("unit {seed}, noise x{noise}"));
    }
}

/// The same frame as a camera's MJPEG stream delivers it: JPEG with 4:2:0 chroma.
fn jpeg_420(img: &image::RgbImage, quality: u8) -> image::RgbImage {
    let mut out = Vec::new();
    let mut enc = jpeg_encoder::Encoder::new(&mut out, quality);
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_0);
    enc.encode(img.as_raw(), img.width() as u16, img.height() as u16, jpeg_encoder::ColorType::Rgb).unwrap();
    sensor::frame::decode(std::path::Path::new("sawtooth.jpg"), &out).unwrap()
}

#[test]
fn draped_teeth_through_subsampled_jpeg_calibrate() {
    // Units whose gel drapes 0.25 to 1 mm over each tooth's foot, as every frame they take.
    for (seed, quality) in [(21, 75), (22, 90), (23, 95)] {
        let unit = SensorUnit::from_seed(seed, 25.0);
        assert!(unit.elastomer.drape_mm > 0.2, "unit {seed} drapes");
        let img = jpeg_420(&shot(seed, 1.0).render(&unit), quality);
        let cal = calibrate(&img, &CalibrationOptions::default()).unwrap();
        check(&unit, &cal, &format!("unit {seed}, drape {:.2} mm, JPEG q{quality} 4:2:0", unit.elastomer.drape_mm));
    }
}

#[test]
fn hidden_teeth_and_speckle_still_calibrate() {
    let unit = SensorUnit::from_seed(11, 25.0);
    let hidden =
        SawToothShot { indicator: SawTooth { missing_teeth: vec![4, -9], ..Default::default() }, ..shot(11, 1.0) };
    let cal = calibrate(&hidden.render(&unit), &CalibrationOptions::default()).unwrap();
    assert!(
        cal.missing.contains(&(1, 4)) && cal.missing.contains(&(-1, 9)),
        "hidden teeth are reported: {:?}",
        cal.missing
    );
    check(&unit, &cal, "teeth 4 and -9 hidden");

    let speckled = SawToothShot { speckle_fraction: 0.01, ..shot(12, 1.0) };
    let unit = SensorUnit::from_seed(12, 25.0);
    let cal = calibrate(&speckled.render(&unit), &CalibrationOptions::default()).unwrap();
    check(&unit, &cal, "1% speckle");
}

#[test]
fn the_papers_r_sin_theta_target_also_works() {
    let unit = SensorUnit::from_seed(6, 25.0);
    let img = shot(6, 1.0).render(&unit);
    let opts = CalibrationOptions { target: GpTarget::RSinTheta, ..Default::default() };
    let cal = calibrate(&img, &opts).unwrap();
    let (px, deg) = compare(&cal.sensor, &unit.sensor);
    eprintln!("R sin(theta) target: rms_px {px:.3} rms_deg {deg:.4}, {} px interpolated below the rim", cal.patched_px);
    // Flat at the rim, so less precise there than the theta target; still sub-pixel.
    assert!(px < 1.0 && deg < 0.3, "rms {px} px, {deg} deg");
}

#[test]
fn images_without_the_indicator_fail_with_a_message() {
    let unit = SensorUnit::from_seed(7, 25.0);
    let opts = CalibrationOptions::default();
    // The sensor without anything pressed.
    let bare = SawToothShot { indicator: SawTooth { teeth: 0, ..Default::default() }, ..shot(7, 1.0) }.render(&unit);
    let e = calibrate(&bare, &opts).unwrap_err().to_string();
    assert!(e.contains("saw-tooth indicator"), "{e}");
    // The indicator pressed along the image's y axis instead of x.
    let turned = image::imageops::rotate90(&shot(7, 1.0).render(&unit));
    let e = calibrate(&turned, &opts).unwrap_err().to_string();
    assert!(e.contains("saw-tooth") || e.contains("teeth"), "{e}");
    // A black frame (LEDs off).
    let e = calibrate(&image::RgbImage::new(800, 600), &opts).unwrap_err().to_string();
    assert!(e.contains("no bright disk"), "{e}");
    // Another pitch than the indicator's.
    let wrong = CalibrationOptions { indicator: SawTooth { pitch_deg: 7.0, teeth: 12, ..Default::default() }, ..opts };
    assert!(calibrate(&shot(7, 1.0).render(&unit), &wrong).is_err(), "a wrong pitch must not calibrate");
}
