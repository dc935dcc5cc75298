//! Ray-cast depth against closed forms.

use dataset::shapes;
use dataset::{Mesh, RayBundle, RayCaster, Skipping};
use glam::{Affine3A, DVec3, Vec3};
use sensor::Sensor;

/// Depth the sensor records along unit `d` for a surface first hit at `t`.
fn depth_of(sensor: &Sensor, t: f64) -> f64 {
    (sensor.radius_mm - t).clamp(0.0, sensor.max_depth_mm)
}

fn cast(sensor: &Sensor, mesh: &Mesh, skipping: Skipping) -> sensor::DepthMap {
    RayCaster::new(&[mesh], sensor.radius_mm, skipping).depth_map(sensor, &RayBundle::new(sensor)).0
}

/// Compares a cast depth map with `truth(direction)` over every useful pixel.
fn max_error_mm(sensor: &Sensor, depth: &sensor::DepthMap, truth: impl Fn(DVec3) -> f64) -> f64 {
    let n = sensor.crop_size_px;
    let mask = sensor.valid_mask();
    let mut worst = 0f64;
    for y in 0..n {
        for x in 0..n {
            let i = (y * n + x) as usize;
            if !mask[i] {
                assert_eq!(depth.depth_mm[i], 0.0, "pixel outside the useful disk has depth");
                continue;
            }
            let (u, v) = sensor.crop_to_frame(x, y);
            let (d, _) = sensor.correspondence.direction(u, v).unwrap();
            worst = worst.max((depth.depth_mm[i] as f64 - truth(d)).abs());
        }
    }
    worst
}

#[test]
fn pressed_sphere_matches_the_closed_form_within_a_micrometre() {
    let sensor = Sensor::default();
    let rho = 8.0f64;
    let pressed = 3.0f64;
    // On the axis and off it (tests the azimuth and the correspondence end to end).
    let dirs = [
        DVec3::Z,
        DVec3::new(
            40f64.to_radians().sin() * 120f64.to_radians().cos(),
            40f64.to_radians().sin() * 120f64.to_radians().sin(),
            40f64.to_radians().cos(),
        ),
    ];
    for axis in dirs {
        let centre = axis * (sensor.radius_mm - pressed + rho);
        let mesh = shapes::sphere(rho as f32, 720).transformed(&Affine3A::from_translation(centre.as_vec3()));
        let depth = cast(&sensor, &mesh, Skipping::On);
        let truth = |d: DVec3| {
            let b = d.dot(centre);
            let disc = b * b - centre.length_squared() + rho * rho;
            if disc < 0.0 { 0.0 } else { depth_of(&sensor, b - disc.sqrt()) }
        };
        let err = max_error_mm(&sensor, &depth, truth);
        assert!(err < 1e-3, "sphere along {axis}: max error {err} mm");
        // The deepest pixel is the one that looks at the sphere's centre.
        let n = sensor.crop_size_px as usize;
        let deepest = depth.depth_mm.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap().0;
        let (u, v) = sensor.correspondence.pixel(centre).unwrap();
        let (x0, y0) = sensor.crop_origin_px();
        let (dx, dy) = ((deepest % n) as f64 - (u - x0 as f64), (deepest / n) as f64 - (v - y0 as f64));
        assert!(dx.hypot(dy) < 1.5, "deepest pixel {dx},{dy} px from the centre's pixel");
        assert!((depth.max_mm() as f64 - pressed).abs() < 1e-3);
    }
}

#[test]
fn pressed_plate_gives_r_minus_r_minus_z_over_cos_theta() {
    let sensor = Sensor::default();
    for z in [0.5f64, 2.0, 6.0] {
        // A thick plate whose lower face sits at height R - z.
        let plate = shapes::box_mesh(Vec3::new(120.0, 120.0, 4.0)).transformed(&Affine3A::from_translation(Vec3::new(
            0.0,
            0.0,
            (sensor.radius_mm - z) as f32 + 2.0,
        )));
        let depth = cast(&sensor, &plate, Skipping::On);
        let truth = |d: DVec3| {
            if d.z > 0.0 { depth_of(&sensor, (sensor.radius_mm - z) / d.z) } else { 0.0 }
        };
        let err = max_error_mm(&sensor, &depth, truth);
        assert!(err < 1e-4, "plate pressed {z} mm: max error {err} mm");
    }
}

#[test]
fn deep_presses_clip_at_the_maximum_depth() {
    let sensor = Sensor::default();
    let plate = shapes::box_mesh(Vec3::new(120.0, 120.0, 4.0))
        .transformed(&Affine3A::from_translation(Vec3::new(0.0, 0.0, 12.0)));
    let depth = cast(&sensor, &plate, Skipping::On);
    assert_eq!(depth.max_mm(), sensor.max_depth_mm as f32);
    assert!(depth.depth_mm.iter().all(|&d| (0.0..=sensor.max_depth_mm as f32).contains(&d)));
}

#[test]
fn skipping_changes_nothing_on_analytic_scenes() {
    let sensor = Sensor::default();
    let sphere = shapes::sphere(6.0, 96).transformed(&Affine3A::from_translation(Vec3::new(5.0, -3.0, 28.0)));
    let plate = shapes::box_mesh(Vec3::new(120.0, 120.0, 4.0))
        .transformed(&Affine3A::from_translation(Vec3::new(0.0, 0.0, 25.0)));
    for mesh in [sphere, plate] {
        let (on, off) = (cast(&sensor, &mesh, Skipping::On), cast(&sensor, &mesh, Skipping::Off));
        let differing = on.depth_mm.iter().zip(&off.depth_mm).filter(|(a, b)| a != b).count();
        assert_eq!(differing, 0, "skipping changed {differing} pixels");
        assert!(on.max_mm() > 0.0);
    }
}
