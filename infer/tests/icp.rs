//! ICP: a known rigid motion recovered from noisy partial clouds, Open3D's fitness and RMSE on
//! a hand-made case, clear errors for degenerate clouds.

use infer::icp::{IcpError, IcpSettings, evaluate, icp, kabsch, pose_error};
use infer::kdtree::KdTree;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// Points on an ellipsoid with three different semi-axes (mm): no rotational symmetry.
fn ellipsoid(rng: &mut Rng, n: usize) -> Vec<Point3<f64>> {
    (0..n)
        .map(|_| {
            let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            Point3::new(20.0 * v.x, 14.0 * v.y, 9.0 * v.z)
        })
        .collect()
}

#[test]
fn recovers_a_known_motion_from_noisy_partial_clouds() {
    let mut rng = Rng(11);
    let object = ellipsoid(&mut rng, 100_000);
    // A partial view (one end and the top) in the frame where the object sits at `truth`, with
    // 0.05 mm noise.
    let truth = Isometry3::from_parts(
        Translation3::new(1.0, -0.6, 0.4),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.3, 1.0, -0.5).normalize() * 4f64.to_radians()),
    );
    let seen: Vec<Point3<f64>> = ellipsoid(&mut rng, 20_000)
        .into_iter()
        .filter(|p| p.x > 8.0 || p.z > 6.0)
        .map(|p| truth * p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.05)
        .collect();
    assert!(seen.len() > 2000 && seen.len() < 12_000, "{}", seen.len());
    // ICP maps the seen points onto the object: the answer is the inverse of the pose.
    // Point-to-point ICP slides slowly along a smooth surface: Open3D's default stopping rule
    // (changes below 1e-6) ends it early, so this runs a fixed 400 iterations.
    let settings =
        IcpSettings { max_iterations: 400, relative_fitness: 0.0, relative_rmse: 0.0, ..IcpSettings::new(5.0) };
    let result = icp(&seen, &object, &Isometry3::identity(), &settings).unwrap();
    let (angle_deg, shift_mm) = pose_error(&result.transform, &truth.inverse());
    assert!(angle_deg < 0.3 && shift_mm < 0.05, "pose error {angle_deg} deg, {shift_mm} mm");
    assert!(result.fitness > 0.99, "fitness {}", result.fitness);
    assert!(result.inlier_rmse_mm < 0.12, "rmse {}", result.inlier_rmse_mm);
    assert_eq!(result.iterations, 400);
}

#[test]
fn fitness_and_rmse_are_open3d_s() {
    let target = [Point3::new(0.0, 0.0, 0.0), Point3::new(10.0, 0.0, 0.0), Point3::new(0.0, 10.0, 0.0)];
    let source = [
        Point3::new(0.0, 0.0, 0.5),
        Point3::new(10.0, 0.0, 0.2),
        Point3::new(0.0, 10.0, 3.0),
        Point3::new(50.0, 50.0, 50.0),
    ];
    let r = evaluate(&source, &KdTree::new(&target), &Isometry3::identity(), 1.0);
    assert_eq!(r.correspondences, vec![(0, 0), (1, 1)]);
    assert_eq!(r.fitness, 0.5);
    assert!((r.inlier_rmse_mm - ((0.25f64 + 0.04) / 2.0).sqrt()).abs() < 1e-12);
    // No correspondence at all: fitness and RMSE are zero, as in Open3D.
    let none = evaluate(&source[3..], &KdTree::new(&target), &Isometry3::identity(), 1.0);
    assert_eq!((none.fitness, none.inlier_rmse_mm), (0.0, 0.0));
}

#[test]
fn kabsch_is_exact_on_noise_free_pairs() {
    let mut rng = Rng(5);
    let motion =
        Isometry3::from_parts(Translation3::new(-4.0, 7.0, 0.5), UnitQuaternion::from_euler_angles(0.4, -1.1, 2.0));
    let points: Vec<Point3<f64>> =
        (0..50).map(|_| Point3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0).collect();
    let got = kabsch(points.iter().map(|&p| (p, motion * p))).unwrap();
    let (angle, shift) = pose_error(&got, &motion);
    assert!(angle < 1e-9 && shift < 1e-9, "{angle} {shift}");
    // A reflection is never returned: mirrored pairs still give a proper rotation.
    let mirrored = kabsch(points.iter().map(|&p| (p, Point3::new(-p.x, p.y, p.z)))).unwrap();
    assert!((mirrored.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-9);
}

#[test]
fn degenerate_clouds_are_clear_errors() {
    let good = ellipsoid(&mut Rng(1), 500);
    let settings = IcpSettings::new(2.0);
    let id = Isometry3::identity();
    assert_eq!(icp(&[], &good, &id, &settings).unwrap_err(), IcpError::Empty("source"));
    assert_eq!(icp(&good, &[], &id, &settings).unwrap_err(), IcpError::Empty("target"));
    let same = vec![Point3::new(1.0, 2.0, 3.0); 50];
    assert_eq!(icp(&same, &good, &id, &settings).unwrap_err(), IcpError::Degenerate("source", "all points are equal"));
    let line: Vec<Point3<f64>> = (0..50).map(|i| Point3::new(i as f64, 2.0 * i as f64, -(i as f64))).collect();
    assert_eq!(
        icp(&good, &line, &id, &settings).unwrap_err(),
        IcpError::Degenerate("target", "all points lie on one line")
    );
    let mut nan = good.clone();
    nan[7].y = f64::NAN;
    assert_eq!(icp(&nan, &good, &id, &settings).unwrap_err(), IcpError::NonFinite("source", 7));
    assert!(matches!(icp(&good, &good, &id, &IcpSettings::new(0.0)), Err(IcpError::Settings(_))));
    // Far apart clouds: no correspondences, the initial pose back, finite numbers.
    let far: Vec<Point3<f64>> = good.iter().map(|p| p + Vector3::new(1000.0, 0.0, 0.0)).collect();
    let r = icp(&far, &good, &id, &settings).unwrap();
    assert_eq!((r.fitness, r.inlier_rmse_mm, r.transform), (0.0, 0.0, id));
}
