//! The sensor's rays, ordered for coherent traversal.

use glam::Vec3A;
use sensor::Sensor;

/// One ray per useful pixel, ordered tile by tile so that neighbouring rays (which visit the
/// same BVH nodes and triangles) are traced together and chunks of work stay cache-friendly.
#[derive(Clone, Debug)]
pub struct RayBundle {
    pub dirs: Vec<Vec3A>,
    /// Row-major crop index of each ray's pixel.
    pub indices: Vec<u32>,
}

impl RayBundle {
    /// Side of a square tile, in pixels.
    pub const TILE_PX: u32 = 16;
    /// Rays handed to one worker at a time.
    pub const TILE_RAYS: usize = 1024;

    pub fn new(sensor: &Sensor) -> Self {
        let n = sensor.crop_size_px;
        let mut rays = sensor.pixel_rays();
        let tile = |i: u32| {
            let (x, y) = (i % n, i / n);
            (y / Self::TILE_PX, x / Self::TILE_PX, y, x)
        };
        rays.sort_by_key(|r| tile(r.index));
        RayBundle {
            dirs: rays.iter().map(|r| Vec3A::from(r.dir)).collect(),
            indices: rays.iter().map(|r| r.index).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.dirs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }
}
