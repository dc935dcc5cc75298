//! Depth in millimetres <-> network units: the one place the mapping lives (and the pressure's,
//! a fixed number of kPa per unit).
//!
//! The paper rescales its 8-bit depth (0..255 over 0..max depth) to 10..1000 for training;
//! here the same linear map goes straight from millimetres.

use serde::{Deserialize, Serialize};

/// The paper's network units of zero and maximum depth.
pub const PAPER_NET_RANGE: [f32; 2] = [10.0, 1000.0];

/// The same map shrunk a thousandfold: a network trained from scratch on a short budget
/// reaches these outputs in far fewer steps.
pub const UNIT_NET_RANGE: [f32; 2] = [0.01, 1.0];

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthScale {
    /// Depth (mm) that maps to `net_max`.
    pub max_depth_mm: f32,
    /// Network value of zero depth.
    pub net_min: f32,
    /// Network value of the maximum depth.
    pub net_max: f32,
}

impl DepthScale {
    /// The paper's mapping: 0..`max_depth_mm` to 10..1000.
    pub fn paper(max_depth_mm: f32) -> Self {
        DepthScale { max_depth_mm, net_min: PAPER_NET_RANGE[0], net_max: PAPER_NET_RANGE[1] }
    }

    /// Width of the network's value range (990 for the paper's); SSIM's dynamic range `L`.
    pub fn range(&self) -> f32 {
        self.net_max - self.net_min
    }

    pub fn to_net(&self, depth_mm: f32) -> f32 {
        self.net_min + self.range() * depth_mm / self.max_depth_mm
    }

    pub fn to_mm(&self, net: f32) -> f32 {
        (net - self.net_min) * self.max_depth_mm / self.range()
    }

    /// Checks a scale read from a file: finite, a positive depth, a non-empty range.
    pub fn check(&self) -> Result<(), ScaleError> {
        let finite = [self.max_depth_mm, self.net_min, self.net_max].iter().all(|v| v.is_finite());
        if !finite || self.max_depth_mm <= 0.0 || self.range() <= 0.0 || !self.range().is_finite() {
            return Err(ScaleError(*self));
        }
        Ok(())
    }

    pub fn tensor_to_net<const D: usize>(&self, depth_mm: burn::tensor::Tensor<D>) -> burn::tensor::Tensor<D> {
        depth_mm.mul_scalar(self.range() / self.max_depth_mm).add_scalar(self.net_min)
    }

    pub fn tensor_to_mm<const D: usize>(&self, net: burn::tensor::Tensor<D>) -> burn::tensor::Tensor<D> {
        net.sub_scalar(self.net_min).mul_scalar(self.max_depth_mm / self.range())
    }
}

/// Contact pressure in network units: one unit is this many kPa. Contacts of the kit on the
/// paper's silicone peak at tens to a few hundred kPa, so the pressure channel's targets span
/// about the depth's `UNIT_NET_RANGE` and one loss weight serves both.
pub const PRESSURE_KPA_PER_UNIT: f32 = 100.0;

/// A scale that maps no depth range: not finite, no positive depth, or an empty range.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("needs a finite max_depth_mm > 0 and net_min < net_max, got {} mm, {}..{}", .0.max_depth_mm, .0.net_min, .0.net_max)]
pub struct ScaleError(pub DepthScale);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_the_paper_range_and_inverts() {
        let s = DepthScale::paper(9.4);
        assert_eq!(s.to_net(0.0), 10.0);
        assert!((s.to_net(9.4) - 1000.0).abs() < 1e-4);
        for d in [0.0f32, 0.013, 1.0, 4.7, 9.4] {
            assert!((s.to_mm(s.to_net(d)) - d).abs() < 1e-5);
        }
        s.check().unwrap();
        assert!(DepthScale { net_max: 10.0, ..s }.check().is_err());
        assert!(DepthScale { max_depth_mm: 0.0, ..s }.check().is_err());
    }
}
