//! Calibration on saw-tooth frames from an image model the calibration was not written against
//! (`gelcam`: other lights, a Gaussian-smoothed membrane, chromatic aberration, a Bayer sensor,
//! 4:2:0 JPEG, a soft rim). Whatever a unit looks like, calibration either returns a map within
//! the project's bound and within its own stated uncertainty, or refuses and says why.

use dataset::SawTooth;
use dataset::calibration::{CalibrationOptions, calibrate, compare};
use gelcam::{GelUnit, sawtooth_frame};

#[test]
fn every_unit_calibrates_within_its_stated_uncertainty_or_is_refused_with_a_reason() {
    let opts = CalibrationOptions::default();
    for seed in 100..106 {
        let unit = GelUnit::from_seed(seed, 25.0);
        let img = sawtooth_frame(&unit, &SawTooth::default(), Some(seed));
        match calibrate(&img, &opts) {
            Ok(cal) => {
                let (px, deg) = compare(&cal.sensor, &unit.sensor);
                eprintln!("unit {seed}: {px:.3} px ({deg:.4} deg), stated +-{:.3}", cal.uncertainty_px);
                assert!(px <= cal.uncertainty_px, "unit {seed}: off by {px:.3} px, stated {:.3}", cal.uncertainty_px);
                assert!(cal.uncertainty_px <= opts.max_uncertainty_px);
            }
            Err(e) => {
                let e = e.to_string();
                eprintln!("unit {seed}: refused: {e}");
                // A reason a lab can act on: which stage, and how far off.
                assert!(e.contains("calibration failed: ") && e.len() > 60, "unit {seed}: {e}");
            }
        }
    }
}

#[test]
fn a_frame_without_the_indicator_is_refused() {
    let unit = GelUnit::from_seed(7, 25.0);
    let bare = sawtooth_frame(&unit, &SawTooth { teeth: 0, ..SawTooth::default() }, Some(1));
    let e = calibrate(&bare, &CalibrationOptions::default()).unwrap_err().to_string();
    assert!(e.contains("saw-tooth") || e.contains("rim"), "{e}");
}
