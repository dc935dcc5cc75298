//! Point clouds in the sensor frame (millimetres) and their PLY files.

use std::path::Path;

use sensor::{DepthMap, PixelRay, Sensor};

/// Points of the pressed surface, sensor frame, millimetres.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub points_mm: Vec<[f32; 3]>,
}

impl PointCloud {
    /// The surface at `(R - depth)` along every useful pixel's ray; with `min_depth_mm`, only
    /// the pixels pressed deeper than it (the contact patch).
    pub fn from_depth(depth: &DepthMap, sensor: &Sensor, min_depth_mm: Option<f32>) -> Self {
        Self::from_rays(depth, &sensor.pixel_rays(), sensor.radius_mm, min_depth_mm)
    }

    /// Like [`from_depth`](Self::from_depth) with the sensor's rays computed once beforehand
    /// (what a frame loop should do: the rays cost more than the cloud).
    pub fn from_rays(depth: &DepthMap, rays: &[PixelRay], radius_mm: f64, min_depth_mm: Option<f32>) -> Self {
        let radius = radius_mm as f32;
        let points_mm = rays
            .iter()
            .filter_map(|ray| {
                let d = depth.depth_mm[ray.index as usize];
                if min_depth_mm.is_some_and(|t| d <= t) {
                    return None;
                }
                Some((ray.dir * (radius - d)).to_array())
            })
            .collect();
        PointCloud { points_mm }
    }
}

/// A binary little-endian PLY of the points (Open3D and MeshLab read it).
pub fn ply_bytes(cloud: &PointCloud) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment DenseTact surface, sensor frame, millimetres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        cloud.points_mm.len()
    )
    .into_bytes();
    out.reserve(cloud.points_mm.len() * 12);
    for p in &cloud.points_mm {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Writes [`ply_bytes`] atomically.
pub fn write_ply(path: &Path, cloud: &PointCloud) -> Result<(), formats::FsError> {
    formats::fs::write_atomic(path, &ply_bytes(cloud))
}

/// Reads a PLY that [`write_ply`] wrote (binary little-endian, float x, y, z per vertex),
/// checking that the file's size matches its header.
pub fn read_ply(path: &Path) -> Result<PointCloud, sensor::SensorError> {
    let bytes = std::fs::read(path).map_err(|e| sensor::SensorError::io(path, e))?;
    parse_ply(path, &bytes)
}

/// Parses [`ply_bytes`]' format; `path` names the file in errors. Points must be finite.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<PointCloud, sensor::SensorError> {
    let bad = |message: &str| sensor::SensorError::InFile { path: path.to_path_buf(), message: message.into() };
    const END: &[u8] = b"end_header\n";
    let header_end = bytes.windows(END.len()).position(|w| w == END).ok_or_else(|| bad("no PLY header"))? + END.len();
    let header = std::str::from_utf8(&bytes[..header_end]).map_err(|_| bad("PLY header is not text"))?;
    if !header.starts_with("ply\nformat binary_little_endian 1.0\n") {
        return Err(bad("not a binary little-endian PLY"));
    }
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|v| v.trim().parse().ok())
        .ok_or_else(|| bad("PLY header has no vertex count"))?;
    let body = &bytes[header_end..];
    if n.checked_mul(12) != Some(body.len()) {
        return Err(bad(&format!("{} bytes of vertices, the header says {n} vertices of 12 bytes", body.len())));
    }
    let points_mm = body
        .chunks_exact(12)
        .map(|v| std::array::from_fn(|k| f32::from_le_bytes(v[4 * k..4 * k + 4].try_into().expect("4 bytes"))))
        .collect::<Vec<[f32; 3]>>();
    if let Some(k) = points_mm.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad(&format!("vertex {k} is not finite: {:?}", points_mm[k])));
    }
    Ok(PointCloud { points_mm })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_analytic_press_lands_on_its_surface_and_the_ply_parses() {
        // A plate pressed 2 mm down along the axis: the surface it leaves is the plane z = R - 2
        // where the plate touches, the sphere elsewhere.
        let sensor = Sensor::default();
        let r = sensor.radius_mm;
        let mut depth = DepthMap::zeros(sensor.crop_size_px);
        for ray in sensor.pixel_rays() {
            let cos_t = ray.dir.z as f64;
            let to_plane = (r - 2.0) / cos_t.max(1e-9);
            depth.depth_mm[ray.index as usize] = (r - to_plane).max(0.0) as f32;
        }
        let all = PointCloud::from_depth(&depth, &sensor, None);
        assert_eq!(all.points_mm.len(), sensor.valid_count());
        let contact = PointCloud::from_depth(&depth, &sensor, Some(0.02));
        assert!(contact.points_mm.len() > 1000 && contact.points_mm.len() < all.points_mm.len());
        for p in &contact.points_mm {
            assert!((p[2] as f64 - (r - 2.0)).abs() < 1e-3, "contact point off the plate: {p:?}");
        }
        for p in &all.points_mm {
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() as f64;
            assert!(len <= r + 1e-3 && p[2] as f64 <= r - 2.0 + 1e-3, "{p:?}");
        }

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ply");
        write_ply(&path, &contact).unwrap();
        assert_eq!(read_ply(&path).unwrap(), contact);
        // A cut file is named as such.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
        let err = read_ply(&path).unwrap_err().to_string();
        assert!(err.contains("c.ply") && err.contains("the header says"), "{err}");
    }
}
