//! Ray-cast ground truth: depth of the pressed surface along every useful pixel's ray.
//!
//! All rays start at the sphere's centre (the sensor frame's origin). That lets each triangle
//! precompute its three edge-plane normals through the origin: a ray hits the triangle when its
//! direction lies on the same side of all three planes, and the distance follows from one more
//! dot product. Each edge test's sign is exact: vertices are snapped to a power-of-two grid
//! (a few nanometres) and ray directions to multiples of 2^-24, so that where the fast f32 test
//! is within its rounding bound of zero the sign is recomputed in integers. Exact signs are
//! consistent between neighbouring triangles, so no ray leaks through a shared edge or vertex.
//!
//! Rays are cast a tile at a time, tiles a block at a time: a SIMD scan of every triangle's
//! bounding ball against the block's cone, then of the survivors against all 64 tile cones at
//! once, gathers the triangles any of a tile's rays can reach; sorted by their distance from the
//! centre, each ray tests them in that order and stops once the next one lies beyond its nearest
//! hit. No BVH is built (the scan costs less than building one); the single-ray reference path
//! builds one on first use.
//!
//! Skipping (on by default) changes nothing in the result and is tested for that:
//! - a triangle whose nearest point to the centre lies beyond the radius can never be the first
//!   hit inside the sphere, so it is dropped;
//! - a ray (or a whole tile) outside the bounding cone of every part's remaining triangles
//!   cannot hit any of them, so it is not traversed;
//! - rays stop at the radius (`tmax = R`): anything farther gives depth 0 anyway.

/// Whether to skip what cannot change the depth map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Skipping {
    /// Drop unreachable triangles, bound rays by cones, stop rays at the radius.
    On,
    /// Cast every ray against every triangle to infinity: the reference, and the fair peer
    /// comparison with a general-purpose ray caster.
    Off,
}

#[allow(unsafe_code)] // the AVX2 block kernel
mod cast;
#[allow(unsafe_code)] // eight rays per SIMD lane group
mod lanes;
#[allow(unsafe_code)] // AVX2 cone and ball scans
mod rays;
mod reference;
mod triangle;

pub use cast::RayCaster;
pub use rays::{BallView, BallViews, BlockCones, Cone, RayBundle};
pub use triangle::{origin_distance, snap_direction};
