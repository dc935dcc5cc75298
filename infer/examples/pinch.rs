//! Two DenseTact sensors pinch a ball; ICP recovers the ball's pose from their point clouds.
//!
//! The sensors face each other along z, 2 x 38.5 mm apart; a 15 mm ball sits between them, off
//! centre by a known offset, pressing about 1.5 mm into each. Each sensor's depth map is cast
//! analytically through its fisheye rays, disturbed by Gaussian noise (standing in for the
//! network's error), turned into a contact point cloud and placed in the common frame by the
//! sensor's pose. ICP then registers the merged cloud to the ball's model cloud from a guess a
//! few millimetres off. A ball has no orientation, so the pose error is its position error.
//!
//! ```sh
//! cargo run --release -p infer --example pinch -- [--noise-mm 0.05] [--out DIR]
//! ```
//! With `--out`, `source.ply`, `target.ply` and `icp.json` are written for
//! `python3 scripts/icp_open3d.py DIR`, which runs Open3D's `registration_icp` on the same inputs.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Parser;
use infer::icp::{IcpSettings, icp, merge, pose_error};
use infer::{PointCloud, write_ply};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use sensor::{CONTACT_THRESHOLD_MM, DepthMap, Sensor};

#[derive(Parser)]
struct Args {
    /// Standard deviation of the depth noise on contact pixels (mm).
    #[arg(long, default_value_t = 0.05)]
    noise_mm: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// ICP's correspondence distance (mm).
    #[arg(long, default_value_t = 2.0)]
    max_distance_mm: f64,
    /// ICP's iteration limit (Open3D's default is 30; point-to-point converges slowly).
    #[arg(long, default_value_t = 200)]
    iterations: usize,
    /// Folder for the Open3D comparison's inputs.
    #[arg(long)]
    out: Option<PathBuf>,
}

const BALL_RADIUS_MM: f64 = 15.0;
const SENSOR_OFFSET_MM: f64 = 38.5;

struct Normal(u64);

impl Normal {
    fn sample(&mut self) -> f64 {
        let mut uniform = || {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u, v) = (uniform(), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The depth map a sensor at `pose` (sensor -> common frame) records with the ball at `centre`.
fn press(sensor: &Sensor, pose: &Isometry3<f64>, centre: &Point3<f64>, noise: &mut Normal, sd_mm: f64) -> DepthMap {
    let c = pose.inverse() * centre;
    let mut depth = DepthMap::zeros(sensor.crop_size_px);
    for ray in sensor.pixel_rays() {
        let u = Vector3::new(ray.dir.x as f64, ray.dir.y as f64, ray.dir.z as f64);
        let along = u.dot(&c.coords);
        let disc = along * along - c.coords.norm_squared() + BALL_RADIUS_MM * BALL_RADIUS_MM;
        if disc < 0.0 {
            continue;
        }
        let hit = along - disc.sqrt();
        let d = (sensor.radius_mm - hit).clamp(0.0, sensor.max_depth_mm);
        if d > 0.0 {
            depth.depth_mm[ray.index as usize] = (d + sd_mm * noise.sample()).max(0.0) as f32;
        }
    }
    depth
}

/// Points spread evenly over the ball (a Fibonacci lattice), object frame.
fn ball_model(n: usize) -> Vec<Point3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            Point3::new(r * phi.cos(), r * phi.sin(), z) * BALL_RADIUS_MM
        })
        .collect()
}

fn main() -> Result<()> {
    let args = Args::parse();
    let sensor = Sensor::default();
    let mut noise = Normal(args.seed);
    // Sensor A looks up +z from below, sensor B down -z from above.
    let poses = [
        Isometry3::from_parts(Translation3::new(0.0, 0.0, -SENSOR_OFFSET_MM), UnitQuaternion::identity()),
        Isometry3::from_parts(
            Translation3::new(0.0, 0.0, SENSOR_OFFSET_MM),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        ),
    ];
    let truth = Isometry3::from_parts(Translation3::new(1.2, -0.8, 0.3), UnitQuaternion::identity());
    let centre = truth * Point3::origin();
    let clouds: Vec<PointCloud> = poses
        .iter()
        .map(|pose| {
            let depth = press(&sensor, pose, &centre, &mut noise, args.noise_mm);
            PointCloud::from_depth(&depth, &sensor, Some(CONTACT_THRESHOLD_MM))
        })
        .collect();
    for (name, cloud) in ["A", "B"].iter().zip(&clouds) {
        println!("sensor {name}: {} contact points", cloud.points_mm.len());
    }
    // The common-frame cloud, rounded to f32 as a PLY stores it, so Open3D sees the same input.
    let merged = PointCloud {
        points_mm: merge(&[(&clouds[0], poses[0]), (&clouds[1], poses[1])])
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect(),
    };
    let source = merge(&[(&merged, Isometry3::identity())]);
    let target_cloud =
        PointCloud { points_mm: ball_model(100_000).iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect() };
    let target = merge(&[(&target_cloud, Isometry3::identity())]);

    // ICP maps the seen points into the ball's frame: the inverse of the ball's pose. The guess
    // is the ball at the pinch's centre line, 1.5 mm off.
    let guess = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity());
    let settings = IcpSettings { max_iterations: args.iterations, ..IcpSettings::new(args.max_distance_mm) };
    let start = Instant::now();
    let result = icp(&source, &target, &guess.inverse(), &settings)?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let found = result.transform.inverse();
    let (_, start_error_mm) = pose_error(&guess, &truth);
    let (_, error_mm) = pose_error(&found, &truth);
    println!(
        "ICP: {} iterations, {ms:.1} ms, fitness {:.4}, inlier RMSE {:.4} mm",
        result.iterations, result.fitness, result.inlier_rmse_mm
    );
    println!(
        "ball centre: true ({:.3}, {:.3}, {:.3}) mm, found ({:.3}, {:.3}, {:.3}) mm",
        centre.x, centre.y, centre.z, found.translation.x, found.translation.y, found.translation.z
    );
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)?;
        write_ply(&dir.join("source.ply"), &merged)?;
        write_ply(&dir.join("target.ply"), &target_cloud)?;
        let json = serde_json::json!({
            "max_correspondence_distance_mm": settings.max_correspondence_distance_mm,
            "max_iterations": settings.max_iterations,
            "relative_fitness": settings.relative_fitness,
            "relative_rmse": settings.relative_rmse,
            "init": guess.inverse().to_homogeneous().transpose().as_slice().chunks(4).map(|r| r.to_vec()).collect::<Vec<_>>(),
            "transform": result.transform.to_homogeneous().transpose().as_slice().chunks(4).map(|r| r.to_vec()).collect::<Vec<_>>(),
            "fitness": result.fitness,
            "inlier_rmse_mm": result.inlier_rmse_mm,
            "iterations": result.iterations,
            "ms": ms,
        });
        formats::fs::write_atomic(&dir.join("icp.json"), serde_json::to_string_pretty(&json)?.as_bytes())?;
        println!("wrote {}/source.ply, target.ply, icp.json", dir.display());
    }
    println!("pose error: {start_error_mm:.3} mm before ICP, {error_mm:.4} mm after");
    Ok(())
}
