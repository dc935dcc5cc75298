//! Pose tracking by point-to-point ICP, as the paper's evaluation does it with Open3D.
//!
//! The source is what the sensors see (one or several clouds, each placed in a common frame by
//! its sensor's pose); the target is the known object's cloud. Fitness and inlier RMSE are
//! Open3D's: fitness = correspondences within the distance / source points, RMSE = the root mean
//! square distance of those correspondences. The loop, the stopping rule and the transform
//! estimate (Kabsch/Umeyama without scale) follow `o3d.pipelines.registration.registration_icp`
//! with `TransformationEstimationPointToPoint`, so results can be compared one to one
//! (`scripts/icp_open3d.py`).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, SymmetricEigen, Translation3, UnitQuaternion, Vector3};

use crate::PointCloud;
use crate::kdtree::KdTree;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IcpError {
    #[error("the {0} point cloud is empty")]
    Empty(&'static str),
    #[error("the {0} point cloud has a non-finite coordinate (point {1})")]
    NonFinite(&'static str, usize),
    #[error("the {0} point cloud is degenerate ({1}): a rigid pose cannot be fitted to it")]
    Degenerate(&'static str, &'static str),
    #[error("invalid ICP settings: {0}")]
    Settings(String),
}

/// Settings with Open3D's defaults (`ICPConvergenceCriteria`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpSettings {
    /// Pairs farther apart than this (mm) are not correspondences.
    pub max_correspondence_distance_mm: f64,
    pub max_iterations: usize,
    /// Stop when fitness changes by less than this between iterations...
    pub relative_fitness: f64,
    /// ...and the inlier RMSE by less than this (mm).
    pub relative_rmse: f64,
}

impl IcpSettings {
    pub fn new(max_correspondence_distance_mm: f64) -> Self {
        IcpSettings { max_correspondence_distance_mm, max_iterations: 30, relative_fitness: 1e-6, relative_rmse: 1e-6 }
    }
}

/// The outcome of a registration.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpResult {
    /// Maps source points onto the target.
    pub transform: Isometry3<f64>,
    pub fitness: f64,
    pub inlier_rmse_mm: f64,
    /// (source index, target index) pairs at `transform`.
    pub correspondences: Vec<(usize, usize)>,
    pub iterations: usize,
}

/// Fitness, RMSE and correspondences of `source` moved by `transform`, against `target`.
pub fn evaluate(
    source: &[Point3<f64>],
    target: &KdTree,
    transform: &Isometry3<f64>,
    max_distance_mm: f64,
) -> IcpResult {
    let mut correspondences = Vec::new();
    let mut sum_d2 = 0.0;
    for (i, p) in source.iter().enumerate() {
        if let Some((j, d2)) = target.nearest_within(&(transform * p), max_distance_mm) {
            correspondences.push((i, j));
            sum_d2 += d2;
        }
    }
    let n = correspondences.len();
    IcpResult {
        transform: *transform,
        fitness: if source.is_empty() { 0.0 } else { n as f64 / source.len() as f64 },
        inlier_rmse_mm: if n == 0 { 0.0 } else { (sum_d2 / n as f64).sqrt() },
        correspondences,
        iterations: 0,
    }
}

/// Point-to-point ICP from `init`. Degenerate clouds (empty, non-finite, all points equal,
/// collinear) are refused with an error rather than giving NaN or an arbitrary rotation.
pub fn icp(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: &Isometry3<f64>,
    settings: &IcpSettings,
) -> Result<IcpResult, IcpError> {
    if !(settings.max_correspondence_distance_mm > 0.0 && settings.max_correspondence_distance_mm.is_finite()) {
        return Err(IcpError::Settings(format!(
            "the correspondence distance must be positive, got {} mm",
            settings.max_correspondence_distance_mm
        )));
    }
    check_cloud("source", source)?;
    check_cloud("target", target)?;
    let tree = KdTree::new(target);
    let dist = settings.max_correspondence_distance_mm;
    let mut result = evaluate(source, &tree, init, dist);
    for iteration in 1..=settings.max_iterations {
        let Some(update) =
            kabsch(result.correspondences.iter().map(|&(i, j)| (result.transform * source[i], target[j])))
        else {
            // Fewer than three pairs, or pairs on a line: no unique update from here.
            break;
        };
        let transform = update * result.transform;
        let previous = std::mem::replace(&mut result, evaluate(source, &tree, &transform, dist));
        result.iterations = iteration;
        if (previous.fitness - result.fitness).abs() < settings.relative_fitness
            && (previous.inlier_rmse_mm - result.inlier_rmse_mm).abs() < settings.relative_rmse
        {
            break;
        }
    }
    Ok(result)
}

fn check_cloud(which: &'static str, points: &[Point3<f64>]) -> Result<(), IcpError> {
    if points.is_empty() {
        return Err(IcpError::Empty(which));
    }
    if let Some(i) = points.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
        return Err(IcpError::NonFinite(which, i));
    }
    let spread = principal_spreads(points.iter().copied());
    let scale = spread[2].max(f64::MIN_POSITIVE);
    if spread[2] <= 1e-18 {
        return Err(IcpError::Degenerate(which, "all points are equal"));
    }
    if spread[1] <= 1e-12 * scale {
        return Err(IcpError::Degenerate(which, "all points lie on one line"));
    }
    Ok(())
}

/// Eigenvalues of the points' covariance, ascending.
fn principal_spreads(points: impl Iterator<Item = Point3<f64>> + Clone) -> [f64; 3] {
    let n = points.clone().count().max(1) as f64;
    let mean = points.clone().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let cov = points.fold(Matrix3::zeros(), |c, p| {
        let d = p.coords - mean;
        c + d * d.transpose()
    }) / n;
    let mut e: Vec<f64> = SymmetricEigen::new(cov).eigenvalues.iter().copied().collect();
    e.sort_by(f64::total_cmp);
    [e[0].max(0.0), e[1].max(0.0), e[2].max(0.0)]
}

/// The rigid motion that best maps the first point of each pair onto the second (least squares,
/// no scale), or `None` when the pairs do not fix one.
pub fn kabsch(pairs: impl Iterator<Item = (Point3<f64>, Point3<f64>)> + Clone) -> Option<Isometry3<f64>> {
    let n = pairs.clone().count();
    if n < 3 {
        return None;
    }
    let (sum_s, sum_t) =
        pairs.clone().fold((Vector3::zeros(), Vector3::zeros()), |(a, b), (s, t)| (a + s.coords, b + t.coords));
    let (mean_s, mean_t) = (sum_s / n as f64, sum_t / n as f64);
    let spreads = principal_spreads(pairs.clone().map(|(s, _)| s));
    if spreads[1] <= 1e-12 * spreads[2].max(f64::MIN_POSITIVE) || spreads[2] <= 1e-18 {
        return None;
    }
    let h = pairs.fold(Matrix3::zeros(), |h, (s, t)| h + (s.coords - mean_s) * (t.coords - mean_t).transpose());
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = mean_t - rotation * mean_s;
    Some(Isometry3::from_parts(Translation3::from(translation), rotation))
}

/// The points of several sensors' clouds in one common frame, each moved by its sensor's pose
/// (sensor frame -> common frame, millimetres).
pub fn merge(clouds: &[(&PointCloud, Isometry3<f64>)]) -> Vec<Point3<f64>> {
    clouds
        .iter()
        .flat_map(|(cloud, pose)| {
            cloud.points_mm.iter().map(move |p| pose * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        })
        .collect()
}

/// Rotation angle (degrees) and translation distance (mm) between two poses.
pub fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let delta = a.inverse() * b;
    (delta.rotation.angle().to_degrees(), (a.translation.vector - b.translation.vector).norm())
}
