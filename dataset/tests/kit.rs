//! Tests on the authors' DenseTact kit (`../shared/densetact-kit` or `$DENSETACT_KIT`).

use std::path::PathBuf;

use dataset::generate::build_scene;
use dataset::{Kit, LoadOptions, Mesh, RayBundle, RayCaster, RigPose, Skipping, Split};
use glam::{Quat, Vec3};
use sensor::Sensor;

/// The kit folder (these tests are ignored unless asked for: `--include-ignored`).
fn kit_dir() -> PathBuf {
    sensor::shared::shared_dir("DENSETACT_KIT", "densetact-kit")
}

fn stl_files(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

#[test]
#[ignore = "needs ../shared"]
fn every_kit_stl_loads_and_every_shell_has_recoverable_holes() {
    let kit = kit_dir();
    let indenters = stl_files(&kit.join("stl/indenters"));
    let indicators = stl_files(&kit.join("stl/indicators"));
    assert_eq!((indenters.len(), indicators.len()), (25, 37));
    for path in &indenters {
        let mesh = Mesh::load(path, LoadOptions::default()).unwrap();
        let (lo, hi) = mesh.bounds();
        // Y-up in the file: the indenters' 25.4-30.8 mm width lies in x and y after loading.
        assert!((hi - lo).x > 25.0 && (hi - lo).y > 25.0 && (hi - lo).z < 18.0, "{}: {lo} {hi}", path.display());
    }
    for path in &indicators {
        let mesh = Mesh::load(path, LoadOptions::default()).unwrap();
        let ind = dataset::Indicator::new(path.display().to_string(), mesh).unwrap();
        assert!(
            (ind.radii.inner_mm - 25.75).abs() < 0.01 && (ind.radii.outer_mm - 26.75).abs() < 0.01,
            "{}: {:?}",
            path.display(),
            ind.radii
        );
        assert!((1..=2).contains(&ind.holes.len()), "{}: {} holes", path.display(), ind.holes.len());
        for h in &ind.holes {
            assert!((3.0..4.5).contains(&h.radius_mm), "{}: hole radius {}", path.display(), h.radius_mm);
            // Holes are drilled towards the centre: the rim's centre lies on the fitted axis.
            assert!(h.axis.z > 0.0 && (h.axis.length() - 1.0).abs() < 1e-5);
        }
    }
}

#[test]
#[ignore = "needs ../shared"]
fn hole_of_indicator_41_is_where_the_mesh_puts_it() {
    let kit = kit_dir();
    let mesh = Mesh::load(&kit.join("stl/indicators/3Dindicator_ver41.STL"), LoadOptions::default()).unwrap();
    let ind = dataset::Indicator::new("41", mesh).unwrap();
    // In the file (Y-up) the hole points along (0, 1, -1)/sqrt 2; in the sensor frame (0, 1, 1)/sqrt 2.
    let want = Vec3::new(0.0, 1.0, 1.0).normalize();
    let err = ind.holes[0].axis.angle_between(want).to_degrees();
    assert!(err < 0.2, "axis {} off by {err} degrees", ind.holes[0].axis);
}

#[test]
#[ignore = "needs ../shared"]
fn index_trials_are_disjoint_by_combination() {
    let dir = kit_dir();
    let kit = Kit::load_dir(&dir).unwrap();
    assert_eq!(kit.trials_in(Split::Train).len(), 74);
    assert_eq!(kit.trials_in(Split::Test).len(), 10);
    assert!(kit.shared_combinations().is_empty(), "{:?}", kit.shared_combinations());
    for t in &kit.trials {
        assert!(t.indenters.len() <= kit.indicators[t.indicator].holes.len(), "trial {:?}", t);
    }
}

#[test]
#[ignore = "needs ../shared"]
fn test_trial_2_presses_where_the_indenters_are() {
    let dir = kit_dir();
    let kit = Kit::load_dir(&dir).unwrap();
    let trial = kit.trials_in(Split::Test).into_iter().find(|t| t.number == 2).unwrap().clone();
    assert_eq!(kit.indicators[trial.indicator].name, "indicator-72");
    let names: Vec<&str> = trial.indenters.iter().map(|&(j, _)| kit.indenters[j].name.as_str()).collect();
    assert_eq!(names, ["indenter-37", "indenter-36"]);

    let sensor = Sensor::default();
    let rays = RayBundle::new(&sensor);
    let pose = RigPose { b_axis_deg: 30.0, z_travel_mm: 0.5, ..RigPose::default() };
    let scene = build_scene(&kit, &trial, pose).unwrap();
    let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On);
    let (depth, stats) = caster.depth_map(&sensor, &rays);
    assert!(stats.rays_cast < rays.len() / 2 && stats.triangles_kept < stats.triangles_total / 2, "{stats:?}");

    // Hole axes after the B-axis turn.
    let turn = Quat::from_rotation_z(pose.b_axis_deg.to_radians());
    let axes: Vec<Vec3> = kit.indicators[trial.indicator].holes.iter().map(|h| turn * h.axis).collect();
    let n = sensor.crop_size_px;
    let mut contact_near = vec![0usize; axes.len()];
    for y in 0..n {
        for x in 0..n {
            let d = depth.depth_mm[(y * n + x) as usize];
            if d <= 0.02 {
                continue;
            }
            let (u, v) = sensor.crop_to_frame(x, y);
            let (dir, _) = sensor.correspondence.direction(u, v).unwrap();
            let dir = dir.as_vec3();
            // Every contact lies under one of the two caps (12.7 mm wide at 25 mm: 31 degrees).
            let nearest = axes
                .iter()
                .map(|a| a.angle_between(dir).to_degrees())
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(nearest.1 < 33.0, "contact {d} mm at {} degrees from the nearest hole", nearest.1);
            contact_near[nearest.0] += 1;
        }
    }
    assert!(contact_near.iter().all(|&c| c > 1000), "contact pixels per indenter: {contact_near:?}");
}

#[test]
#[ignore = "needs ../shared"]
fn skipping_changes_nothing_on_kit_scenes() {
    let dir = kit_dir();
    let kit = Kit::load_dir(&dir).unwrap();
    let sensor = Sensor::default();
    let rays = RayBundle::new(&sensor);
    for (k, trial) in kit.trials.iter().step_by(9).enumerate() {
        // Shallow and deep presses, so that the shell itself comes into contact too.
        let pose = RigPose { b_axis_deg: 47.0 * k as f32, z_travel_mm: [0.0, 1.3, 3.0][k % 3], ..RigPose::default() };
        let scene = build_scene(&kit, trial, pose).unwrap();
        let on = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::On).depth_map(&sensor, &rays);
        let off = RayCaster::new(&scene.part_refs(), sensor.radius_mm, Skipping::Off).depth_map(&sensor, &rays);
        assert!(on.0 == off.0, "trial {:?} at {pose:?}: skipping changed the depth map", trial);
        assert!(on.0.max_mm() > 0.0);
    }
}

#[test]
#[ignore = "needs ../shared"]
fn tiled_casting_equals_single_rays_on_a_kit_scene() {
    let dir = kit_dir();
    let kit = Kit::load_dir(&dir).unwrap();
    let sensor = Sensor::default();
    let rays = RayBundle::new(&sensor);
    let trial = kit.trials_in(Split::Test).into_iter().find(|t| t.number == 2).unwrap().clone();
    let scene =
        build_scene(&kit, &trial, RigPose { b_axis_deg: 10.0, z_travel_mm: 2.0, ..RigPose::default() }).unwrap();
    for skipping in [Skipping::On, Skipping::Off] {
        let caster = RayCaster::new(&scene.part_refs(), sensor.radius_mm, skipping);
        let (tiled, _) = caster.first_hits(&rays);
        let differing = tiled.iter().zip(&rays.dirs).filter(|(t, d)| **t != caster.first_hit(**d)).count();
        assert_eq!(differing, 0, "{skipping:?}: {differing} rays differ between the tiled and the single-ray path");
    }
}
