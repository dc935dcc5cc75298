//! The sensor description: hemisphere, camera frame, crop and correspondence.

use std::path::Path;

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use crate::{Correspondence, RadialMap, SensorError};

/// Format version of the JSON sensor description.
pub const SENSOR_FORMAT_VERSION: u32 = 1;

/// Focal length of the default equidistant fisheye: puts the hemisphere's equator (90 degrees)
/// 283.9 px from the centre, so the useful disk of the 570 px crop holds the paper's 253,213 pixels.
pub const DEFAULT_FOCAL_PX_PER_RAD: f64 = 180.74;

/// A DenseTact sensor: geometry of the elastomer and of the camera that films it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sensor {
    /// Format version; readers refuse newer ones.
    pub format_version: u32,
    /// Radius of the undeformed hemisphere's outer surface (25 mm; a 15 mm variant exists).
    pub radius_mm: f64,
    /// Largest depth the ground truth records; deeper presses are clipped (9.4 mm in the paper).
    pub max_depth_mm: f64,
    /// Largest polar angle of the elastomer that is useful (90 degrees: the hemisphere's base).
    pub max_theta_rad: f64,
    pub frame_width_px: u32,
    pub frame_height_px: u32,
    /// Side of the square crop around the optical centre that networks see (570 px).
    pub crop_size_px: u32,
    pub correspondence: Correspondence,
}

/// Largest frame side a sensor description may give: a bound that keeps every per-pixel table
/// (masks, rays, images) of a mistyped or corrupted file within memory.
pub const MAX_FRAME_SIDE_PX: u32 = 16_384;

impl Default for Sensor {
    fn default() -> Self {
        Self::with_radius(25.0)
    }
}

/// One useful pixel of the crop and the ray it sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelRay {
    /// Row-major index into the crop (`y * crop_size + x`).
    pub index: u32,
    /// Unit direction from the sphere's centre, sensor frame.
    pub dir: Vec3,
}

impl Sensor {
    /// The paper's sensor with another hemisphere radius; depth range scaled with it.
    pub fn with_radius(radius_mm: f64) -> Self {
        Sensor {
            format_version: SENSOR_FORMAT_VERSION,
            radius_mm,
            max_depth_mm: 9.4 * radius_mm / 25.0,
            max_theta_rad: std::f64::consts::FRAC_PI_2,
            frame_width_px: 800,
            frame_height_px: 600,
            crop_size_px: 570,
            correspondence: Correspondence {
                centre_u_px: 399.5,
                centre_v_px: 299.5,
                radial: RadialMap::Equidistant { focal_px_per_rad: DEFAULT_FOCAL_PX_PER_RAD },
            },
        }
    }

    /// Frame pixel of the crop's top-left pixel: the crop is centred on the optical centre.
    pub fn crop_origin_px(&self) -> (i64, i64) {
        let half = self.crop_size_px as f64 / 2.0;
        // Pixel centres sit at integers, so a centre of 399.5 with a 570 crop starts at 115.
        let x0 = (self.correspondence.centre_u_px - half + 0.5).round() as i64;
        let y0 = (self.correspondence.centre_v_px - half + 0.5).round() as i64;
        (x0, y0)
    }

    /// Frame coordinates of crop pixel `(x, y)`.
    pub fn crop_to_frame(&self, x: u32, y: u32) -> (f64, f64) {
        let (x0, y0) = self.crop_origin_px();
        ((x0 + x as i64) as f64, (y0 + y as i64) as f64)
    }

    /// Number of pixels in the crop.
    pub fn crop_len(&self) -> usize {
        (self.crop_size_px as usize).pow(2)
    }

    /// Checks every field; the error names the problem.
    pub fn validate(&self) -> Result<(), SensorError> {
        let bad = |why: String| Err(SensorError::Invalid(why));
        if self.format_version > SENSOR_FORMAT_VERSION {
            return bad(format!(
                "sensor format version {} is newer than this program understands ({SENSOR_FORMAT_VERSION})",
                self.format_version
            ));
        }
        if !(self.radius_mm.is_finite() && self.radius_mm > 0.0 && self.radius_mm < 1000.0) {
            return bad(format!("radius_mm must be in (0, 1000) mm, got {}", self.radius_mm));
        }
        if !(self.max_depth_mm > 0.0 && self.max_depth_mm < self.radius_mm) {
            return bad(format!(
                "max_depth_mm must be in (0, radius_mm = {}), got {}",
                self.radius_mm, self.max_depth_mm
            ));
        }
        if !(self.max_theta_rad > 0.0 && self.max_theta_rad < std::f64::consts::PI) {
            return bad(format!("max_theta_rad must be in (0, pi), got {}", self.max_theta_rad));
        }
        if self.frame_width_px > MAX_FRAME_SIDE_PX || self.frame_height_px > MAX_FRAME_SIDE_PX {
            return bad(format!(
                "a {}x{} frame is larger than any camera this reads ({MAX_FRAME_SIDE_PX} px a side at most)",
                self.frame_width_px, self.frame_height_px
            ));
        }
        let (u, v) = (self.correspondence.centre_u_px, self.correspondence.centre_v_px);
        if !(u.is_finite() && v.is_finite()) {
            return bad(format!("the optical centre must be finite, got ({u}, {v}) px"));
        }
        if self.crop_size_px == 0 || self.crop_size_px > self.frame_width_px || self.crop_size_px > self.frame_height_px
        {
            return bad(format!(
                "crop of {} px does not fit the {}x{} frame",
                self.crop_size_px, self.frame_width_px, self.frame_height_px
            ));
        }
        let (x0, y0) = self.crop_origin_px();
        let n = self.crop_size_px as i64;
        if x0 < 0 || y0 < 0 || x0 + n > self.frame_width_px as i64 || y0 + n > self.frame_height_px as i64 {
            return bad(format!(
                "crop at ({x0}, {y0}) of {n} px around the optical centre ({:.1}, {:.1}) leaves the {}x{} frame",
                self.correspondence.centre_u_px,
                self.correspondence.centre_v_px,
                self.frame_width_px,
                self.frame_height_px
            ));
        }
        // The crop's corner is the farthest any pixel of interest lies from the centre.
        let r_corner = std::f64::consts::SQRT_2 * (n as f64 / 2.0 + 1.0);
        self.correspondence.radial.validate(r_corner)
    }

    /// Polar angle seen by crop pixel `(x, y)`, if the correspondence covers it.
    pub fn crop_theta(&self, x: u32, y: u32) -> Option<f64> {
        let (u, v) = self.crop_to_frame(x, y);
        self.correspondence.angles(u, v).map(|(theta, _)| theta)
    }

    /// Mask of useful crop pixels (row-major): those that see the elastomer (`theta <= max`).
    pub fn valid_mask(&self) -> Vec<bool> {
        let n = self.crop_size_px;
        (0..n * n).map(|i| self.crop_theta(i % n, i / n).is_some_and(|t| t <= self.max_theta_rad)).collect()
    }

    /// Number of useful pixels (the paper's sensor has 253,213).
    pub fn valid_count(&self) -> usize {
        self.valid_mask().iter().filter(|&&v| v).count()
    }

    /// One ray per useful pixel, in row-major order.
    pub fn pixel_rays(&self) -> Vec<PixelRay> {
        let n = self.crop_size_px;
        let mut rays = Vec::with_capacity(self.crop_len());
        for y in 0..n {
            for x in 0..n {
                let (u, v) = self.crop_to_frame(x, y);
                if let Some((dir, theta)) = self.correspondence.direction(u, v)
                    && theta <= self.max_theta_rad
                {
                    rays.push(PixelRay { index: y * n + x, dir: dir.as_vec3() });
                }
            }
        }
        rays
    }

    /// The paper's form of the correspondence: image radius (px) -> `R * sin(theta)` (mm).
    pub fn r_sin_theta_mm(&self, r_px: f64) -> Option<f64> {
        self.correspondence.radial.theta_of_radius(r_px).map(|t| self.radius_mm * t.sin())
    }

    /// Point on the undeformed surface pressed in by `depth_mm` along `dir` (sensor frame, mm).
    pub fn surface_point_mm(&self, dir: DVec3, depth_mm: f64) -> DVec3 {
        dir.normalize() * (self.radius_mm - depth_mm)
    }

    /// Reads and validates a JSON sensor description.
    pub fn load_json(path: &Path) -> Result<Self, SensorError> {
        let bytes = std::fs::read(path).map_err(|e| SensorError::io(path, e))?;
        Self::from_json(path, &bytes)
    }

    /// Parses and validates a JSON sensor description's bytes; `path` names it in errors.
    pub fn from_json(path: &Path, bytes: &[u8]) -> Result<Self, SensorError> {
        let sensor: Sensor =
            serde_json::from_slice(bytes).map_err(|e| SensorError::Json { path: path.to_path_buf(), source: e })?;
        sensor.validate().map_err(|e| e.in_file(path))?;
        Ok(sensor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_sensor_matches_the_paper() {
        let s = Sensor::default();
        s.validate().unwrap();
        assert_eq!((s.frame_width_px, s.frame_height_px, s.crop_size_px), (800, 600, 570));
        assert_eq!(s.crop_origin_px(), (115, 15));
        let count = s.valid_count();
        // The paper counts 253,213 useful pixels; our default fisheye is tuned to it.
        assert!((count as i64 - 253_213).abs() < 300, "useful pixels: {count}");
        assert_eq!(s.pixel_rays().len(), count);
        // The useful disk ends at the equator: R sin(theta) reaches R there.
        let r_edge = s.correspondence.radial.radius_of_theta(s.max_theta_rad).unwrap();
        assert!((s.r_sin_theta_mm(r_edge).unwrap() - 25.0).abs() < 1e-9);
        assert!((s.r_sin_theta_mm(0.0).unwrap()).abs() < 1e-12);
    }

    #[test]
    fn mask_is_a_centred_disk() {
        let s = Sensor::default();
        let mask = s.valid_mask();
        let n = s.crop_size_px as usize;
        assert!(mask[(n / 2) * n + n / 2]);
        assert!(!mask[0] && !mask[n - 1] && !mask[n * n - 1]);
        // Symmetric under mirroring, since the centre sits between pixels 284 and 285.
        for y in 0..n {
            for x in 0..n {
                assert_eq!(mask[y * n + x], mask[y * n + (n - 1 - x)]);
                assert_eq!(mask[y * n + x], mask[(n - 1 - y) * n + x]);
            }
        }
    }

    #[test]
    fn json_round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sensor.json");
        let mut s = Sensor::with_radius(15.0);
        s.correspondence.radial = RadialMap::KannalaBrandt { focal_px_per_rad: 178.0, k: [0.01, -0.002, 0.0, 0.0] };
        std::fs::write(&path, serde_json::to_string_pretty(&s).unwrap()).unwrap();
        assert_eq!(Sensor::load_json(&path).unwrap(), s);

        std::fs::write(&path, "{ not json").unwrap();
        let err = Sensor::load_json(&path).unwrap_err().to_string();
        assert!(err.contains("sensor.json"), "{err}");

        let newer = Sensor { format_version: 99, ..Sensor::default() };
        std::fs::write(&path, serde_json::to_string(&newer).unwrap()).unwrap();
        let err = Sensor::load_json(&path).unwrap_err().to_string();
        assert!(err.contains("sensor.json") && err.contains("newer"), "{err}");

        let mut off = Sensor::default();
        off.correspondence.centre_u_px = 30.0;
        assert!(off.validate().unwrap_err().to_string().contains("leaves the 800x600 frame"));
    }
}
