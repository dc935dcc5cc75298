//! The dataset folder format, written by `dataset` and read by `train`, `infer` and `xtask`.
//!
//! ```text
//! DIR/generator.json        generator parameters and sensor (a resumed run must match them)
//! DIR/samples/NNNNNN.json   one record per finished sample: its scene, split and statistics
//! DIR/depth/NNNNNN.png      depth, 16-bit grey PNG in micrometres, on the sensor's crop
//! DIR/depth_u8/NNNNNN.png   optional: the paper's 8-bit encoding (0..255 = 0..max depth)
//! DIR/pressure/NNNNNN.png   with force labels: contact pressure, 16-bit grey PNG in 0.1 kPa,
//!                           on the crop (the record holds the wrench)
//! DIR/images/NNNNNN.png     with a simulated unit: its 8-bit RGB camera image of the crop (.jpg,
//!                           the stream as sent, for a unit that streams JPEG)
//! DIR/unit/unit.json        the unit's optics and lighting (`SensorUnit`)
//! DIR/unit/truth.json       the unit's true sensor description (for evaluating a calibration)
//! DIR/unit/reference.png    the unit's no-contact image of the crop, without noise
//! DIR/manifest.json         written last: sensor, parameters, every sample record, summary
//! ```
//!
//! A sample's record is written after its images, each atomically (temporary file, rename), so
//! after a killed run a record on disk means a complete sample: that is what makes generation
//! resumable. Sample files are not synced one by one; after a power cut a resumed run checks
//! that each record parses and each PNG ends whole, and makes a sample again where not.

use std::collections::BTreeMap;
use std::path::Path;

use sensor::{CONTACT_THRESHOLD_MM, DepthMap, Sensor};
use serde::{Deserialize, Serialize};

use crate::json::FormatError;

pub const DATASET_FORMAT_VERSION: u32 = 1;

/// Which part of a kit's index a trial (and so a sample) belongs to. The paper's train and test
/// trials share no indicator-indenter combination.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    Test,
}

impl Split {
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
        }
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Split {
    type Err = crate::UnknownName;

    /// `train` or `test`, in any case, spaces around ignored.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::find_by_name("split", &s.trim().to_ascii_lowercase(), &[Split::Train, Split::Test], Split::name)
            .map_err(|e| crate::UnknownName { name: s.to_string(), ..e })
    }
}

/// Where an indenter goes: which hole, turned by how much about the hole's axis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    pub indenter: String,
    pub hole: usize,
    /// Turn about the hole's axis (degrees, the index CSV's angle). Zero is the indenter's own
    /// `x` axis carried by the shortest rotation from its `+z` to the inward hole axis.
    pub angle_deg: f32,
}

/// The rig's pose of the indicator assembly, as the paper's CNC rig sets it.
///
/// In the sensor frame (origin at the hemisphere's centre, `x` along image `u`, `y` along image
/// `v`, `z` along the optical axis towards the dome's top), the seated assembly is moved by
/// `T(-z travel along z) * Rz(B) * Ry(C) * Rx(A)`: first tilted by A about the `x` axis, then by
/// C about the `y` axis (the two hand-set axes, horizontal and through the sphere's centre, so
/// a tilt keeps the shell concentric with the sensor and moves its holes over the dome), then
/// turned by B about the sensor axis (the motorised axis), then pressed down by the z travel.
/// Rotations are right-handed (counter-clockwise looking down the axis), in degrees.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RigPose {
    /// Tilt about the sensor frame's `x` axis (degrees), applied first.
    #[serde(default)]
    pub a_axis_deg: f32,
    /// Rotation about the sensor axis (degrees), applied after the tilts.
    pub b_axis_deg: f32,
    /// Tilt about the sensor frame's `y` axis (degrees), applied after A.
    #[serde(default)]
    pub c_axis_deg: f32,
    /// How far the assembly is pressed down along the sensor axis from its seated pose (mm).
    pub z_travel_mm: f32,
}

/// Angles a generator draws from (degrees): a list (each equally likely) or a range (uniform).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Angles {
    List(Vec<f32>),
    Range([f32; 2]),
}

impl Default for Angles {
    /// Always 0: no tilt.
    fn default() -> Self {
        Angles::List(vec![0.0])
    }
}

impl Angles {
    /// Whether every draw is 0 (then nothing is drawn, and datasets made before the A and C
    /// axes existed keep their samples).
    pub fn is_zero(&self) -> bool {
        match self {
            Angles::List(v) => v.iter().all(|&a| a == 0.0),
            Angles::Range([lo, hi]) => *lo == 0.0 && *hi == 0.0,
        }
    }

    /// One draw, given a uniform number in [0, 1).
    pub fn pick(&self, unit: f64) -> f32 {
        match self {
            Angles::List(v) => v[((unit * v.len() as f64) as usize).min(v.len() - 1)],
            Angles::Range([lo, hi]) => (*lo as f64 + (*hi - *lo) as f64 * unit) as f32,
        }
    }

    /// The largest magnitude it can draw.
    pub fn max_abs(&self) -> f32 {
        match self {
            Angles::List(v) => v.iter().fold(0.0, |m, a| m.max(a.abs())),
            Angles::Range([lo, hi]) => lo.abs().max(hi.abs()),
        }
    }
}

/// Why a text is not [`Angles`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AnglesError {
    #[error("{0:?} is not a number of degrees")]
    NotANumber(String),
    #[error("{0:?} is not finite")]
    NotFinite(String),
    #[error("the range {0:?} runs backwards")]
    Backwards(String),
}

impl std::str::FromStr for Angles {
    type Err = AnglesError;

    /// `45` (one value), `0,45,90` (a list) or `-30..30` (a range).
    fn from_str(s: &str) -> Result<Self, AnglesError> {
        let number = |t: &str| -> Result<f32, AnglesError> {
            let v: f32 = t.trim().parse().map_err(|_| AnglesError::NotANumber(t.to_string()))?;
            if v.is_finite() { Ok(v) } else { Err(AnglesError::NotFinite(t.to_string())) }
        };
        if let Some((lo, hi)) = s.split_once("..") {
            let (lo, hi) = (number(lo)?, number(hi)?);
            if lo > hi {
                return Err(AnglesError::Backwards(s.to_string()));
            }
            return Ok(Angles::Range([lo, hi]));
        }
        // `split` yields at least one piece, so a list is never empty.
        let list = s.split(',').map(number).collect::<Result<Vec<_>, _>>()?;
        Ok(Angles::List(list))
    }
}

/// What a scene is made of: enough to rebuild it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneDescription {
    pub indicator: String,
    pub placements: Vec<Placement>,
    pub pose: RigPose,
}

/// Counts that show what the ray caster's skipping saved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CastStats {
    pub triangles_total: usize,
    pub triangles_kept: usize,
    pub rays_total: usize,
    pub rays_cast: usize,
    pub rays_hit: usize,
}

/// Per-sample depth statistics over the useful pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthStats {
    pub contact_fraction: f32,
    pub mean_contact_depth_mm: f32,
    pub max_depth_mm: f32,
}

impl DepthStats {
    pub fn of(depth: &DepthMap, mask: &[bool]) -> Self {
        let (mut useful, mut contact, mut sum, mut max) = (0usize, 0usize, 0f64, 0f32);
        for (&d, &m) in depth.depth_mm.iter().zip(mask) {
            if !m {
                continue;
            }
            useful += 1;
            if d > CONTACT_THRESHOLD_MM {
                contact += 1;
                sum += d as f64;
            }
            max = max.max(d);
        }
        DepthStats {
            contact_fraction: contact as f32 / useful.max(1) as f32,
            mean_contact_depth_mm: (sum / contact.max(1) as f64) as f32,
            max_depth_mm: max,
        }
    }
}

/// What the generator was asked to make.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeneratorParams {
    pub seed: u64,
    pub count: u32,
    /// "procedural" or the kit folder.
    pub kit: String,
    pub z_travel_mm: [f32; 2],
    pub b_axis_deg: [f32; 2],
    /// Chance that a sample's rig is lifted clear of the sensor ([`LIFTED_Z_TRAVEL_MM`]): a
    /// frame without contact, so that a network learns to answer zero where nothing touches.
    #[serde(default)]
    pub lifted_fraction: f32,
    /// Chance that a sample is drawn from the test trials.
    pub test_fraction: f32,
    pub depth_u8: bool,
    /// Seed of the simulated unit whose images are rendered; `None`: depth only.
    #[serde(default)]
    pub unit: Option<u64>,
    /// A-axis tilts to draw from (default: none).
    #[serde(default, skip_serializing_if = "Angles::is_zero")]
    pub a_axis_deg: Angles,
    /// C-axis tilts to draw from (default: none).
    #[serde(default, skip_serializing_if = "Angles::is_zero")]
    pub c_axis_deg: Angles,
    /// The renderer's image model the images were made with ([`IMAGE_MODEL`]), so that a
    /// resume never mixes two: 1 shaded the rigid surface through a sharp, linear camera; 2
    /// shaded the membrane's drape and added lens blur, a tone curve and the unit's JPEG; 3
    /// shades the contact model's solved surface instead of the drape.
    #[serde(default = "first_image_model")]
    pub image_model: u32,
    /// Whether each sample is rendered under its own random look (lights, coating, gel,
    /// camera; `dataset::looks`), with its own reference frame beside it: data for a network
    /// that must read units it never saw rather than one renderer's shading.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub random_looks: bool,
    /// Whether each sample gets force labels: its pressure map and wrench from the elastomer's
    /// contact model (the unit's material, or the paper's without a unit). Absent in older
    /// `generator.json`: none.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub force_labels: bool,
    /// The share of the samples this folder holds (`--shard K/N`; absent: all of them). A
    /// merge of every share (`dataset merge`) is the dataset without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<crate::Shard>,
}

/// The image model this version renders (see [`GeneratorParams::image_model`]).
pub const IMAGE_MODEL: u32 = 3;

fn first_image_model() -> u32 {
    1
}

impl GeneratorParams {
    /// The generator's defaults: z travel 0..2.5 mm, any B-axis angle, 10% test samples,
    /// 16-bit depth and force labels, no images.
    pub fn new(seed: u64, count: u32, kit: &str) -> Self {
        GeneratorParams {
            seed,
            count,
            kit: kit.to_string(),
            z_travel_mm: [0.0, 2.5],
            b_axis_deg: [0.0, 360.0],
            lifted_fraction: 0.0,
            test_fraction: 0.1,
            depth_u8: false,
            unit: None,
            a_axis_deg: Angles::default(),
            c_axis_deg: Angles::default(),
            image_model: IMAGE_MODEL,
            random_looks: false,
            force_labels: true,
            shard: None,
        }
    }
}

/// The z travel of a lifted sample (mm): well above any kit's reach of a 25 mm hemisphere.
pub const LIFTED_Z_TRAVEL_MM: f32 = -40.0;

/// `generator.json`: parameters and the sensor, fixed for the life of a dataset folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeneratorFile {
    pub format_version: u32,
    pub sensor: Sensor,
    pub params: GeneratorParams,
}

/// One sample's record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleRecord {
    pub id: u32,
    pub split: Split,
    /// The kit index's trial number within the split.
    pub trial: u32,
    pub scene: SceneDescription,
    /// Paths relative to the dataset folder.
    pub depth: String,
    /// The camera image, when the dataset has a unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    /// The untouched frame under this sample's own look, when it has one (random looks); else
    /// the unit's `unit/reference.png` is its reference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
    pub stats: DepthStats,
    pub cast: CastStats,
    /// The contact pressure map, when the dataset has force labels (`dataset::mechanics`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pressure: Option<String>,
    /// The force and torque the contact applies to the sensor, when the dataset has force labels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrench: Option<Wrench>,
    /// For a labelled capture session: the row of `captures.csv` the sample came from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capture: Option<CaptureInfo>,
}

pub use sensor::Wrench;

impl SampleRecord {
    /// The files the record names (relative to the dataset folder).
    pub fn files(&self) -> impl Iterator<Item = &String> {
        std::iter::once(&self.depth).chain(&self.image).chain(&self.reference).chain(&self.pressure)
    }

    /// The wrench a force output is trained and scored against: the one a force-torque sensor
    /// measured where the capture has one, else the labelled one (from the depth map's contact).
    pub fn force_label(&self) -> Option<&Wrench> {
        self.measured_wrench().or(self.wrench.as_ref())
    }

    /// The wrench measured for this sample's capture, if any (`captures.csv`'s force-torque columns).
    pub fn measured_wrench(&self) -> Option<&Wrench> {
        self.capture.as_ref().and_then(|c| c.measured_wrench.as_ref())
    }
}

/// Where a labelled sample came from in its session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaptureInfo {
    /// The frame's path relative to the session folder.
    pub frame: String,
    /// Its row's line in `captures.csv`.
    pub line: usize,
    /// The row's other columns.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub extra: BTreeMap<String, String>,
    /// The wrench a force-torque sensor measured for the frame (`captures.csv`'s `fx_n`, ...,
    /// `tz_nmm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_wrench: Option<Wrench>,
    /// SHA-256 of what the sample was made from: the row (all but its line) and the frame
    /// file's bytes. A resumed labelling makes the sample again when they changed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
}

/// What a labelled dataset was made from (`dataset label`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LabelParams {
    /// The session folder.
    pub session: String,
    /// "procedural" or the kit folder.
    pub kit: String,
    /// Rows of the session's log.
    pub rows: u32,
}

/// Summary of one split.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SplitSummary {
    pub samples: usize,
    pub mean_contact_fraction: f32,
    pub mean_contact_depth_mm: f32,
    pub max_depth_mm: f32,
}

impl SplitSummary {
    pub fn of<'a>(records: impl Iterator<Item = &'a SampleRecord>) -> Self {
        let mut s = SplitSummary::default();
        let (mut frac, mut depth, mut with_contact) = (0f64, 0f64, 0usize);
        for r in records {
            s.samples += 1;
            frac += r.stats.contact_fraction as f64;
            if r.stats.contact_fraction > 0.0 {
                depth += r.stats.mean_contact_depth_mm as f64;
                with_contact += 1;
            }
            s.max_depth_mm = s.max_depth_mm.max(r.stats.max_depth_mm);
        }
        s.mean_contact_fraction = (frac / s.samples.max(1) as f64) as f32;
        s.mean_contact_depth_mm = (depth / with_contact.max(1) as f64) as f32;
        s
    }
}

/// `manifest.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format_version: u32,
    pub sensor: Sensor,
    /// What the generator was asked for, for a generated dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<GeneratorParams>,
    /// Where the frames came from, for a labelled capture session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labelled: Option<LabelParams>,
    pub samples: Vec<SampleRecord>,
    pub summary: BTreeMap<Split, SplitSummary>,
}

impl Manifest {
    /// Loads `DIR/manifest.json`, checking its version and its sensor. Sample files are not
    /// checked here: a reader meets a missing one as that sample's error, which `--on-bad-data
    /// skip` can leave out ([`Manifest::missing_files`] lists them beforehand).
    pub fn load(dir: &Path) -> Result<Manifest, FormatError> {
        let path = dir.join("manifest.json");
        let bytes = std::fs::read(&path).map_err(|source| FormatError::Io { path: path.clone(), source })?;
        Self::parse(&path, &bytes)
    }

    /// Parses and checks a `manifest.json`'s bytes (`path` names it in errors): its version, its
    /// sensor, and that every file a record names lies inside the dataset folder.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Manifest, FormatError> {
        let manifest: Manifest = serde_json::from_slice(bytes).map_err(|e| FormatError::invalid(path, e))?;
        if manifest.format_version > DATASET_FORMAT_VERSION {
            return Err(FormatError::invalid(
                path,
                format!(
                    "dataset format {} is newer than this program understands ({DATASET_FORMAT_VERSION})",
                    manifest.format_version
                ),
            ));
        }
        manifest.sensor.validate().map_err(|e| FormatError::invalid(path, e))?;
        for record in &manifest.samples {
            for file in record.files() {
                if !is_inside(file) {
                    return Err(FormatError::invalid(
                        path,
                        format!(
                            "sample {} names the file {file:?}, which is not a path inside the dataset folder",
                            record.id
                        ),
                    ));
                }
            }
        }
        Ok(manifest)
    }

    /// The files the records list that are not in `dir`.
    pub fn missing_files(&self, dir: &Path) -> Vec<std::path::PathBuf> {
        self.samples.iter().flat_map(|s| s.files()).map(|f| dir.join(f)).filter(|f| !f.is_file()).collect()
    }

    /// The records of one split, or of all of them.
    pub fn split(&self, split: Option<Split>) -> impl Iterator<Item = &SampleRecord> {
        self.samples.iter().filter(move |s| split.is_none_or(|want| s.split == want))
    }
}

/// Whether `name` is a relative path that stays inside its folder (no root, no `..`, not empty):
/// a dataset is a self-contained folder that can be moved as a whole.
pub fn is_inside(name: &str) -> bool {
    use std::path::Component;
    let path = Path::new(name);
    !name.is_empty() && path.components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
}

/// A sample's file name stem: its id, six digits.
pub fn sample_name(id: u32) -> String {
    format!("{id:06}")
}

/// Where sample `id`'s 8-bit depth (`--depth-u8`) lies in a dataset folder: a file its record
/// does not name.
pub fn depth_u8_file(id: u32) -> String {
    format!("depth_u8/{}.png", sample_name(id))
}

impl GeneratorParams {
    /// Sample `id`'s files beside those its record names ([`SampleRecord::files`]), relative to
    /// the dataset folder.
    pub fn unrecorded_files(&self, id: u32) -> Vec<String> {
        if self.depth_u8 { vec![depth_u8_file(id)] } else { Vec::new() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_files_must_stay_inside_the_dataset() {
        for good in ["000001.png", "depth/000001.png", "./a.png"] {
            assert!(is_inside(good), "{good}");
        }
        for bad in ["", "/etc/passwd", "../x.png", "depth/../../x.png"] {
            assert!(!is_inside(bad), "{bad}");
        }
    }

    #[test]
    fn poses_round_trip_and_old_records_read_as_untilted() {
        let pose = RigPose { a_axis_deg: 45.0, b_axis_deg: 12.25, c_axis_deg: -30.0, z_travel_mm: 1.125 };
        let text = serde_json::to_string(&pose).unwrap();
        assert_eq!(serde_json::from_str::<RigPose>(&text).unwrap(), pose);
        let old: RigPose = serde_json::from_str(r#"{"b_axis_deg": 10.0, "z_travel_mm": 2.0}"#).unwrap();
        assert_eq!(old, RigPose { b_axis_deg: 10.0, z_travel_mm: 2.0, ..RigPose::default() });
    }

    #[test]
    fn angles_parse_as_values_lists_and_ranges() {
        assert_eq!("45".parse::<Angles>().unwrap(), Angles::List(vec![45.0]));
        assert_eq!("0, 45,90".parse::<Angles>().unwrap(), Angles::List(vec![0.0, 45.0, 90.0]));
        assert_eq!("-30..30".parse::<Angles>().unwrap(), Angles::Range([-30.0, 30.0]));
        assert!("30..-30".parse::<Angles>().is_err() && "a".parse::<Angles>().is_err());
        assert!(Angles::default().is_zero() && !Angles::List(vec![0.0, 45.0]).is_zero());
        let list = Angles::List(vec![0.0, 45.0]);
        assert_eq!((list.pick(0.2), list.pick(0.7), list.pick(0.999_999)), (0.0, 45.0, 45.0));
        assert_eq!(Angles::Range([-10.0, 10.0]).pick(0.75), 5.0);
    }

    #[test]
    fn splits_parse_and_print() {
        for split in [Split::Train, Split::Test] {
            assert_eq!(split.to_string().parse::<Split>().unwrap(), split);
        }
        assert_eq!(" TEST ".parse::<Split>().unwrap(), Split::Test);
        assert_eq!("validation".parse::<Split>().unwrap_err().to_string(), "unknown split \"validation\": train, test");
    }
}
