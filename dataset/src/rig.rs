//! A real rig's errors: how its true pose differs from what its log says. A CNC's z zero is set
//! by eye at first touch (again at every indenter change), the sensor sits in its mount a little
//! off the CAD and tilted, and the B axis has its own zero. The frames obey the truth; the log
//! does not. Simulated sessions take these offsets (`dataset generate --session --rig-errors`)
//! so that whatever reads a session can be tested against known truth.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use rayon::prelude::*;
use sensor::{CONTACT_THRESHOLD_MM, DepthMap};

use formats::SplitMix64;
use formats::dataset::{RigPose, Split};
use glam::{Affine3A, Vec3};
use serde::{Deserialize, Serialize};

use crate::generate::build_scene_in;
use crate::kit::Kit;
use crate::raycast::{RayBundle, RayCaster, Skipping};

/// How far a rig's truth is from its log. All zero: the log is the truth.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RigOffsets {
    /// Added to every logged z (mm): the log's zero is this far above the true one (a log
    /// short in z has it positive).
    pub z_zero_mm: f32,
    /// Added on top of `z_zero_mm` for one trial (`"train/3"`): the zero set again at that
    /// indenter change (mm).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub z_zero_by_trial_mm: BTreeMap<String, f32>,
    /// Where the rig's axis meets the sensor's base plane, in the sensor frame (mm): the
    /// sensor sits this far off the CAD in its mount.
    pub x_mm: f32,
    pub y_mm: f32,
    /// The rig's axis tilted against the sensor's, about the sensor's `x` and `y` (degrees).
    pub tilt_x_deg: f32,
    pub tilt_y_deg: f32,
    /// Added to every logged B (degrees): the B axis' true zero.
    pub b_zero_deg: f32,
}

/// The key of a trial in [`RigOffsets::z_zero_by_trial_mm`].
pub fn trial_key(split: Split, trial: u32) -> String {
    format!("{}/{trial}", split.name())
}

impl RigOffsets {
    /// Offsets drawn within what a lab's rig shows (the limits registration must recover
    /// from): z zeros within +-0.3 mm, one per trial of `kit`; x and y within +-0.5 mm; tilts
    /// within +-1 degree; B's zero within +-2 degrees.
    pub fn draw(seed: u64, kit: &Kit) -> Self {
        let mut rng = SplitMix64::for_item(seed, 0x416);
        let mut pick = |limit: f64| rng.range(-limit, limit) as f32;
        let (x_mm, y_mm, tilt_x_deg, tilt_y_deg, b_zero_deg) = (pick(0.5), pick(0.5), pick(1.0), pick(1.0), pick(2.0));
        let z_zero_by_trial_mm = kit.trials.iter().map(|t| (trial_key(t.split, t.number), pick(0.3))).collect();
        RigOffsets { z_zero_mm: 0.0, z_zero_by_trial_mm, x_mm, y_mm, tilt_x_deg, tilt_y_deg, b_zero_deg }
    }

    /// Whether the log is the truth.
    pub fn is_zero(&self) -> bool {
        *self == RigOffsets::default()
    }

    /// The pose the rig truly had for a row that logged `logged` in trial `trial` of `split`.
    pub fn true_pose(&self, split: Split, trial: u32, logged: RigPose) -> RigPose {
        let zero = self.z_zero_mm + self.z_zero_by_trial_mm.get(&trial_key(split, trial)).copied().unwrap_or(0.0);
        RigPose { z_travel_mm: logged.z_travel_mm + zero, b_axis_deg: logged.b_axis_deg + self.b_zero_deg, ..logged }
    }

    /// The rig's frame in the sensor's: tilted about `x`, then `y`, then shifted in the base
    /// plane. Applied to the whole pressed assembly.
    pub fn mount(&self) -> Affine3A {
        Affine3A::from_translation(Vec3::new(self.x_mm, self.y_mm, 0.0))
            * Affine3A::from_rotation_y(self.tilt_y_deg.to_radians())
            * Affine3A::from_rotation_x(self.tilt_x_deg.to_radians())
    }
}

/// Labels to measure against the truth: a `dataset label` folder's depth maps, or the depth
/// maps an offset set casts (what those offsets would label).
#[derive(Clone, Copy)]
pub enum Labels<'a> {
    Written(&'a Path),
    Cast(&'a RigOffsets),
}

/// How far a labelled session's depth maps (`labelled`, a `dataset label` folder of `session`)
/// are from the depth its frames were truly pressed to, the rig's errors being `truth` (a
/// simulated session's `.simulation/rig.json`): the mean absolute difference (mm) over the
/// pixels either calls contact, and their count. What registration is measured by.
pub fn label_error_mm(session: &Path, labelled: &Path, kit: &Kit, truth: &RigOffsets) -> Result<(f64, usize)> {
    Ok(label_errors_mm(session, labelled, kit, truth, &[Labels::Written(labelled)])?[0])
}

/// As [`label_error_mm`], for several sets of labels of the samples `labelled` lists (each
/// sample's true depth cast once for all of them): for example what each of a registration's
/// offsets costs the labels, the others set to the truth.
pub fn label_errors_mm(
    session: &Path,
    labelled: &Path,
    kit: &Kit,
    truth: &RigOffsets,
    labels: &[Labels],
) -> Result<Vec<(f64, usize)>> {
    let manifest = formats::dataset::Manifest::load(labelled)?;
    let log = formats::session::CaptureLog::read(session)?;
    let by_line: BTreeMap<usize, RigPose> = log.rows.iter().map(|r| (r.line, r.pose)).collect();
    let sensor = &manifest.sensor;
    let rays = RayBundle::new(sensor);
    let per_sample: Vec<Vec<(f64, usize)>> = manifest
        .samples
        .par_iter()
        .map(|sample| -> Result<Vec<(f64, usize)>> {
            let trial = kit.trial(sample.split, sample.trial).with_context(|| {
                format!("sample {}: trial {} {} not in the kit", sample.id, sample.split, sample.trial)
            })?;
            let row = sample.capture.as_ref().with_context(|| format!("sample {} has no capture row", sample.id))?;
            let logged =
                *by_line.get(&row.line).with_context(|| format!("{}: no line {}", log.path.display(), row.line))?;
            let cast = |offsets: &RigOffsets| -> Result<DepthMap> {
                let scene =
                    build_scene_in(kit, trial, offsets.true_pose(sample.split, sample.trial, logged), offsets.mount())?;
                Ok(RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On).depth_map(sensor, &rays).0)
            };
            let true_depth = cast(truth)?;
            labels
                .iter()
                .map(|set| {
                    let label = match set {
                        Labels::Written(folder) => {
                            let path = folder.join(&sample.depth);
                            let bytes = std::fs::read(&path).with_context(|| path.display().to_string())?;
                            DepthMap::decode_png_um(&path, &bytes)?
                        }
                        Labels::Cast(offsets) => cast(offsets)?,
                    };
                    let (mut sum, mut pixels) = (0f64, 0usize);
                    for (t, l) in true_depth.depth_mm.iter().zip(&label.depth_mm) {
                        if *t > CONTACT_THRESHOLD_MM || *l > CONTACT_THRESHOLD_MM {
                            sum += (t - l).abs() as f64;
                            pixels += 1;
                        }
                    }
                    Ok((sum, pixels))
                })
                .collect()
        })
        .collect::<Result<_>>()?;
    Ok((0..labels.len())
        .map(|k| {
            let (sum, pixels) = per_sample.iter().fold((0.0, 0), |a, s| (a.0 + s[k].0, a.1 + s[k].1));
            (sum / pixels.max(1) as f64, pixels)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drawn_offsets_stay_in_their_limits_and_apply_as_documented() {
        let kit = Kit::procedural(25.0);
        let o = RigOffsets::draw(3, &kit);
        assert_eq!(o, RigOffsets::draw(3, &kit), "seeded");
        assert_ne!(o, RigOffsets::draw(4, &kit));
        assert_eq!(o.z_zero_by_trial_mm.len(), kit.trials.len());
        assert!(o.z_zero_by_trial_mm.values().all(|z| z.abs() <= 0.3));
        assert!(o.x_mm.abs() <= 0.5 && o.y_mm.abs() <= 0.5 && o.tilt_x_deg.abs() <= 1.0 && o.tilt_y_deg.abs() <= 1.0);
        assert!(o.b_zero_deg.abs() <= 2.0 && !o.is_zero() && RigOffsets::default().is_zero());
        let t = &kit.trials[0];
        let logged = RigPose { a_axis_deg: 5.0, b_axis_deg: 10.0, c_axis_deg: -3.0, z_travel_mm: 1.0 };
        let truth = o.true_pose(t.split, t.number, logged);
        let zero = o.z_zero_by_trial_mm[&trial_key(t.split, t.number)];
        assert_eq!((truth.z_travel_mm, truth.b_axis_deg), (1.0 + zero, 10.0 + o.b_zero_deg));
        assert_eq!((truth.a_axis_deg, truth.c_axis_deg), (5.0, -3.0));
        // The mount moves the sphere's centre in the base plane and turns the axis by the tilts.
        let m = o.mount();
        assert!((m.transform_point3(Vec3::ZERO) - Vec3::new(o.x_mm, o.y_mm, 0.0)).length() < 1e-6);
        let axis = m.transform_vector3(Vec3::Z);
        assert!((axis.angle_between(Vec3::Z).to_degrees() - o.tilt_x_deg.hypot(o.tilt_y_deg)).abs() < 0.01);
    }
}
