//! What a log's z column measures, and where an assembly first touches the sensor.
//!
//! The project's z is the CNC's travel from the kit's seated pose (`RigPose`). A lab's log may
//! count it from first touch (the CNC zeroed where the indicator meets the skin) or in a fixed
//! machine coordinate; `dataset label --z-from` reads each, and says which it assumed.

use anyhow::{Result, bail};
use formats::dataset::RigPose;
use sensor::Sensor;
use serde::{Deserialize, Serialize};

use crate::generate::build_scene_in;
use crate::kit::{Kit, Trial};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::rig::RigOffsets;

/// What the log's z column measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum ZFrom {
    /// Travel from the kit's seated pose (the project's convention, and a simulated session's).
    #[default]
    Seated,
    /// Travel from first touch: the pose, for the row's trial, tilts and B, where the assembly
    /// first meets the undeformed dome (a CNC zeroed at first touch).
    FirstTouch,
    /// A machine coordinate: the travel is z less the machine's z at the seated pose (the row's
    /// `z_zero_mm` column, else `--z-zero-mm`).
    Machine,
}

/// How a log's z is read: its convention and, for a machine coordinate, the seated pose's z.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ZReading {
    pub from: ZFrom,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zero_mm: Option<f32>,
}

/// The column of a log that gives a row's machine zero (mm).
pub const Z_ZERO_COLUMN: &str = "z_zero_mm";

impl ZReading {
    pub fn is_seated(&self) -> bool {
        *self == ZReading::default()
    }

    /// What the report says it assumed.
    pub fn describe(&self) -> String {
        match (self.from, self.zero_mm) {
            (ZFrom::Seated, _) => "z read as travel from the kit's seated pose (--z-from seated, the default)".into(),
            (ZFrom::FirstTouch, _) => {
                "z read as travel from first touch, found per row by ray casting its trial, tilts and B (--z-from \
                 first-touch)"
                    .into()
            }
            (ZFrom::Machine, Some(z)) => format!(
                "z read as a machine coordinate: travel = z - {z} mm, or less the row's {Z_ZERO_COLUMN} where it has one \
                 (--z-from machine)"
            ),
            (ZFrom::Machine, None) => {
                format!("z read as a machine coordinate: travel = z - the row's {Z_ZERO_COLUMN} (--z-from machine)")
            }
        }
    }
}

/// Raised further than this (mm), nothing of any kit reaches a fingertip sensor: a log's z (as
/// travel) is refused below it, and the search for first touch starts there.
pub const MIN_Z_TRAVEL_MM: f32 = -50.0;

/// Bisection stops when the first touch is known this closely (mm).
pub const TOUCH_TOLERANCE_MM: f32 = 0.002;

/// The travel (mm, from the seated pose) at which `trial`'s assembly, tilted and turned as
/// `pose` says (its z ignored), first touches the undeformed dome: the least travel at which
/// one of `sensor`'s rays meets the assembly inside the dome, to [`TOUCH_TOLERANCE_MM`].
pub fn first_touch_mm(kit: &Kit, trial: &Trial, pose: RigPose, sensor: &Sensor, rays: &RayBundle) -> Result<f32> {
    let bracket = (MIN_Z_TRAVEL_MM, sensor.max_depth_mm as f32);
    first_touch_in(kit, trial, pose, &RigOffsets::default(), sensor, rays, bracket, Seen::default())
}

/// What counts as a touch: by default anything of the assembly on any pixel of the crop.
#[derive(Clone, Copy, Default)]
pub(crate) struct Seen<'a> {
    /// Only the crop's pixels this marks (what a camera sees of the skin).
    pub within: Option<&'a [bool]>,
    /// Only the indenters (where the trial has any), not the indicator's shell: a broad shell
    /// pressed on the dome it is concentric with hardly changes the image.
    pub indenters_only: bool,
}

impl Seen<'_> {
    /// The parts of `scene` that count: all, or its indenters alone (the indicator's shell is
    /// its first part).
    pub(crate) fn parts<'s>(&self, scene: &'s crate::scene::Scene) -> Vec<&'s crate::mesh::Mesh> {
        let mut parts = scene.part_refs();
        if self.indenters_only && parts.len() > 1 {
            parts.remove(0);
        }
        parts
    }
}

/// [`first_touch_mm`] on a rig with errors `rig` (its B zero and mount; z zeros are left out:
/// the travel returned is the rig's true one), searched within `bracket_mm` (an error if the
/// assembly touches at its low end or never at its high end), counting what `seen` counts.
#[allow(clippy::too_many_arguments)] // The rig, the bracket and what counts are each needed by one caller.
pub(crate) fn first_touch_in(
    kit: &Kit,
    trial: &Trial,
    pose: RigPose,
    rig: &RigOffsets,
    sensor: &Sensor,
    rays: &RayBundle,
    bracket_mm: (f32, f32),
    seen: Seen,
) -> Result<f32> {
    let mount = rig.mount();
    let touches = |z: f32| -> Result<bool> {
        let pose = RigPose { z_travel_mm: z, b_axis_deg: pose.b_axis_deg + rig.b_zero_deg, ..pose };
        let scene = build_scene_in(kit, trial, pose, mount)?;
        let caster = RayCaster::new(&seen.parts(&scene), sensor.radius_mm, Skipping::On);
        let (depth, _) = caster.depth_map(sensor, rays);
        Ok(match seen.within {
            None => depth.depth_mm.iter().any(|&d| d > 0.0),
            Some(mask) => depth.depth_mm.iter().zip(mask).any(|(&d, &m)| m && d > 0.0),
        })
    };
    let (mut lo, mut hi) = bracket_mm;
    if touches(lo)? {
        bail!("the assembly touches the sensor even at {lo} mm of travel: no first touch to count from");
    }
    if !touches(hi)? {
        bail!("the assembly never touches the sensor within {hi} mm of travel: no first touch to count from");
    }
    while hi - lo > TOUCH_TOLERANCE_MM {
        let mid = 0.5 * (lo + hi);
        if touches(mid)? {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_touch_is_where_depth_begins() {
        let kit = Kit::procedural(25.0);
        let sensor = Sensor::with_radius(25.0);
        let rays = RayBundle::new(&sensor);
        for (k, trial) in kit.trials.iter().take(3).enumerate() {
            let pose = RigPose { b_axis_deg: 40.0 * k as f32, ..RigPose::default() };
            let z = first_touch_mm(&kit, trial, pose, &sensor, &rays).unwrap();
            let depth = |z: f32| {
                let scene = crate::generate::build_scene(&kit, trial, RigPose { z_travel_mm: z, ..pose }).unwrap();
                let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
                caster.depth_map(&sensor, &rays).0.max_mm()
            };
            assert_eq!(depth(z - 0.01), 0.0, "trial {}: touching before its first touch", trial.number);
            // Past it, the deepest pixel goes in about as far as the assembly moved.
            let past = depth(z + 0.2);
            assert!(past > 0.05 && past < 0.3, "trial {}: {past} mm 0.2 mm past first touch", trial.number);
        }
    }
}
