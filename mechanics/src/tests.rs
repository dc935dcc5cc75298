//! The contact model against the closed forms it must reproduce in their own limits.

use glam::DVec3;

use super::*;

const R: f64 = 25.0;

/// How far a sphere of radius `r` centred at `centre` reaches inside the dome along `u`.
fn sphere_interference(centre: DVec3, r: f64) -> impl Fn(DVec3) -> f64 + Sync {
    move |u: DVec3| {
        let b = u.dot(centre);
        let disc = b * b - centre.length_squared() + r * r;
        if disc < 0.0 { f64::NEG_INFINITY } else { R - (b - disc.sqrt()) }
    }
}

/// The directions where `interference` is positive, sampled on a 0.05 mm grid of the pole's
/// tangent plane (what a depth map's contact pixels give, finer): one region.
fn region(interference: &impl Fn(DVec3) -> f64, reach_mm: f64) -> Vec<DVec3> {
    let steps = (reach_mm / 0.05) as i64;
    let mut dirs = Vec::new();
    for j in -steps..=steps {
        for i in -steps..=steps {
            let d = DVec3::new(i as f64 * 0.05, j as f64 * 0.05, R).normalize();
            if interference(d) > 0.0 {
                dirs.push(d);
            }
        }
    }
    dirs
}

/// A sphere pressed `depth` into the dome's top, solved on `grid`.
fn hertz_case(r: f64, depth: f64, grid: &GridConfig) -> Contact {
    let f = sphere_interference(DVec3::new(0.0, 0.0, R + r - depth), r);
    let dirs = region(&f, 6.0);
    solve(R, &Material::PAPER, grid, &[dirs], f).unwrap()
}

/// What a unit's stiffness is fitted on: the contact's pressure scales with E* alone (Poisson's
/// ratio enters only through it) and its contact set stays where it is.
#[test]
fn pressure_scales_with_the_effective_modulus_alone() {
    let f = sphere_interference(DVec3::new(0.0, 0.0, R + 8.0 - 0.6), 8.0);
    let dirs = region(&f, 6.0);
    let paper = solve(R, &Material::PAPER, &GridConfig::default(), std::slice::from_ref(&dirs), &f).unwrap();
    let e_star = Material::PAPER.effective_modulus_mpa();
    for scale in [1.0, 0.37, 2.9] {
        let m = Material::with_effective_modulus(scale * e_star);
        assert!((m.effective_modulus_mpa() / (scale * e_star) - 1.0).abs() < 1e-12);
        let c = solve(R, &m, &GridConfig::default(), std::slice::from_ref(&dirs), &f).unwrap();
        assert_eq!(c.patches.len(), paper.patches.len());
        for (a, b) in c.patches.iter().zip(&paper.patches) {
            for (&pa, &pb) in a.pressure_kpa.iter().zip(&b.pressure_kpa) {
                assert_eq!(pa > 0.0, pb > 0.0, "the contact set moved");
                assert!((pa - scale * pb).abs() <= 1e-9 * pb.abs().max(1.0), "{pa} against {scale} x {pb}");
            }
        }
    }
}

fn hertz_force_n(r: f64, depth: f64) -> (f64, f64) {
    let e_star = Material::PAPER.effective_modulus_mpa();
    let r_eff = r * R / (r + R);
    (4.0 / 3.0 * e_star * r_eff.sqrt() * depth.powf(1.5), (r_eff * depth).sqrt())
}

#[test]
fn a_sphere_at_the_top_gives_hertz_force_and_contact_radius() {
    for (r, depth) in [(4.0, 0.1), (6.0, 0.3), (10.0, 0.5)] {
        let contact = hertz_case(r, depth, &GridConfig::default());
        let (force, radius) = hertz_force_n(r, depth);
        let got = contact.total_normal_force_n();
        let area = contact.contact_area_mm2();
        let got_radius = (area / std::f64::consts::PI).sqrt();
        eprintln!(
            "hertz r {r} d {depth}: force {got:.5} N against {force:.5}, radius {got_radius:.4} against {radius:.4}"
        );
        assert!((got / force - 1.0).abs() <= 0.05, "force {got} N against Hertz's {force}");
        // The area counts whole nodes: its edge is known to a node's spacing.
        let spacing = contact.patches[0].spacing_mm;
        assert!(spacing <= radius / 5.0, "{spacing} mm is too coarse for a contact of radius {radius} mm");
        assert!(
            (got_radius - radius).abs() <= spacing,
            "contact radius {got_radius} against {radius} (spacing {spacing} mm)"
        );
        // Straight down (each node pushes along its own normal, at most a few degrees off the
        // axis), and through the dome's centre: no torque about it.
        let w = contact.wrench();
        assert!((w.force_n[2] + got).abs() <= 1e-2 * got && w.force_n[0].abs() <= 1e-9 * got, "{w:?}");
        assert!(w.torque_nmm.iter().all(|t| t.abs() <= 1e-9 * got * R), "{w:?}");
        // Hertz's pressure peaks at 3F / (2 pi a^2) in the middle.
        let peak = contact.patches[0].pressure_kpa.iter().fold(0f64, |m, &p| m.max(p));
        let hertz_peak = 3.0 * force / (2.0 * std::f64::consts::PI * radius * radius) * 1e3;
        assert!((peak / hertz_peak - 1.0).abs() <= 0.1, "peak {peak} kPa against {hertz_peak}");
    }
}

/// A punch whose face follows the dome (a cap concentric with it), so that it presses `depth`
/// uniformly over the disc of radius `a` (along the dome): Boussinesq's flat punch.
fn punch_interference(a: f64, depth: f64) -> impl Fn(DVec3) -> f64 + Sync {
    move |u: DVec3| if R * u.z.clamp(-1.0, 1.0).acos() <= a { depth } else { -1.0 }
}

#[test]
fn a_flat_punch_gives_boussinesq_force_and_the_grid_converges() {
    let e_star = Material::PAPER.effective_modulus_mpa();
    for (a, depth) in [(2.0, 0.2), (4.0, 0.5)] {
        let f = punch_interference(a, depth);
        let dirs = region(&f, a + 1.0);
        let coarse = solve(R, &Material::PAPER, &GridConfig::default(), std::slice::from_ref(&dirs), &f).unwrap();
        let fine = solve(R, &Material::PAPER, &GridConfig::default().halved(), &[dirs], &f).unwrap();
        let known = 2.0 * a * e_star * depth;
        let (c, g) = (coarse.total_normal_force_n(), fine.total_normal_force_n());
        eprintln!(
            "punch a {a} d {depth}: {c:.5} / {g:.5} N against {known:.5} (steps {} / {})",
            coarse.steps, fine.steps
        );
        assert!(
            (c / known - 1.0).abs() <= 0.1 && (g / known - 1.0).abs() <= 0.1,
            "{c}, {g} N against Boussinesq's {known}"
        );
        assert!((g / c - 1.0).abs() <= 0.03, "halving the grid moved the force from {c} to {g} N");
    }
}

#[test]
fn halving_the_grid_moves_hertz_force_by_under_three_percent() {
    for (r, depth) in [(5.0, 0.2), (10.0, 0.6)] {
        let coarse = hertz_case(r, depth, &GridConfig::default()).total_normal_force_n();
        let fine = hertz_case(r, depth, &GridConfig::default().halved()).total_normal_force_n();
        assert!((fine / coarse - 1.0).abs() <= 0.03, "r {r} d {depth}: {coarse} -> {fine} N");
    }
}

#[test]
fn two_mirrored_contacts_carry_equal_loads_and_their_sideways_forces_cancel() {
    // Two spheres tilted 20 degrees either side of the pole in the x-z plane, pressed alike.
    let (r, depth) = (5.0, 0.3);
    let tilt = 20f64.to_radians();
    let centre = |sign: f64| DVec3::new(sign * tilt.sin(), 0.0, tilt.cos()) * (R + r - depth);
    let (left, right) = (sphere_interference(centre(-1.0), r), sphere_interference(centre(1.0), r));
    let both = |u: DVec3| left(u).max(right(u));
    let cone = |sign: f64| -> Vec<DVec3> {
        let axis = centre(sign).normalize();
        let e1 = DVec3::Y.cross(axis).normalize();
        let e2 = axis.cross(e1);
        let mut dirs = Vec::new();
        for j in -60..=60 {
            for i in -60..=60 {
                let d = (axis * R + e1 * (i as f64 * 0.05) + e2 * (j as f64 * 0.05)).normalize();
                if both(d) > 0.0 {
                    dirs.push(d);
                }
            }
        }
        dirs
    };
    let contact = solve(R, &Material::PAPER, &GridConfig::default(), &[cone(-1.0), cone(1.0)], both).unwrap();
    assert_eq!(contact.patches.len(), 2);
    let loads: Vec<f64> = contact
        .patches
        .iter()
        .map(|p| p.pressure_kpa.iter().sum::<f64>() * p.spacing_mm * p.spacing_mm * 1e-3)
        .collect();
    assert!((loads[0] / loads[1] - 1.0).abs() <= 0.01, "{loads:?}");
    let w = contact.wrench();
    let total = contact.total_normal_force_n();
    assert!(w.force_n[0].abs() <= 0.01 * total, "{w:?}");
    // Each pushes towards the centre: the sum points down by cos(20 degrees) of the total.
    assert!((-w.force_n[2] / (total * tilt.cos()) - 1.0).abs() <= 0.01, "{w:?} against {total}");
    // They interact through the elastomer: each sinks the other's surface a little, so each
    // carries less than it would alone (a point force's sink at 17 mm is about 5 % of the depth).
    let alone = hertz_case(r, depth, &GridConfig::default()).total_normal_force_n();
    assert!(loads[0] < alone && loads[0] > 0.85 * alone, "{} against {alone} alone", loads[0]);
}

#[test]
fn nothing_pressed_means_no_force_and_bad_materials_are_refused() {
    let contact = solve(R, &Material::PAPER, &GridConfig::default(), &[], |_| -1.0).unwrap();
    assert_eq!(contact.total_normal_force_n(), 0.0);
    assert!(contact.patches.is_empty());
    for bad in
        [Material { youngs_modulus_mpa: 0.0, ..Material::PAPER }, Material { poisson_ratio: 0.5, ..Material::PAPER }]
    {
        let err = solve(R, &bad, &GridConfig::default(), &[], |_| -1.0).unwrap_err().to_string();
        assert!(err.contains("elastomer"), "{err}");
    }
}

#[test]
fn a_sphere_seen_through_the_depth_map_gives_hertz_force() {
    let sensor = sensor::Sensor::default();
    assert_eq!(sensor.radius_mm, R);
    let dome = Dome::new(&sensor);
    for (r, depth) in [(6.0f32, 0.3f32), (10.0, 0.6)] {
        // The depth map a ray cast of the sphere gives: its overlap with the dome per pixel
        // (the dataset's tests cast a meshed sphere through the same path).
        let reach = sphere_interference(DVec3::new(0.0, 0.0, R + r as f64 - depth as f64), r as f64);
        let n = sensor.crop_size_px as usize;
        let mut map = sensor::DepthMap { size_px: n as u32, depth_mm: vec![0.0; n * n] };
        for ray in sensor.pixel_rays() {
            map.depth_mm[ray.index as usize] = reach(ray.dir.as_dvec3()).max(0.0) as f32;
        }
        let label = force_label(&dome, &map, &Material::PAPER, &GridConfig::default()).unwrap();
        let (force, radius) = hertz_force_n(r as f64, depth as f64);
        let got = label.contact.total_normal_force_n();
        eprintln!("meshed sphere r {r} d {depth}: {got:.5} N against Hertz's {force:.5}");
        assert!((got / force - 1.0).abs() <= 0.05, "{got} N against Hertz's {force}");
        assert!((label.wrench.force_n[2] + got).abs() <= 0.01 * got);
        // The map: pressure only where the depth map shows contact, peaking near Hertz's peak.
        let peak = label.pressure_kpa.iter().fold(0f32, |m, &p| m.max(p)) as f64;
        let hertz_peak = 3.0 * force / (2.0 * std::f64::consts::PI * radius * radius) * 1e3;
        assert!((peak / hertz_peak - 1.0).abs() <= 0.1, "peak {peak} kPa against {hertz_peak}");
        assert!(label.pressure_kpa.iter().zip(&map.depth_mm).all(|(&p, &d)| d > 0.0 || p == 0.0));
        // The map's coordinates come from a lattice every few pixels: against each pixel's own
        // exact mapping, within 1e-4 of the peak (measured: 2e-6).
        let worst = (0..map.depth_mm.len())
            .filter(|&i| map.depth_mm[i] > 0.0005)
            .map(|i| (label.pressure_kpa[i] as f64 - label.contact.pressure_along(dome.dir(i))).abs())
            .fold(0f64, f64::max);
        assert!(worst <= 1e-4 * peak, "interpolated map off by {worst} kPa (peak {peak})");
        let pressed = label.pressure_kpa.iter().filter(|&&p| p > 0.0).count();
        let touching = map.depth_mm.iter().filter(|&&d| d > 0.0).count();
        // Hertz's contact is half the overlap's area (radius sqrt(R d) against sqrt(2 R d)); the
        // bilinear map reaches up to one node spacing beyond the last loaded node.
        let share = pressed as f64 / touching as f64;
        let h = label.contact.patches[0].spacing_mm;
        let most = 0.5 * ((radius + h) / radius).powi(2) + 0.02;
        assert!((0.45..most).contains(&share), "{pressed} pressed pixels of {touching} overlapping (spacing {h} mm)");
        // What a network's pressure output is read back through: the map summed over the dome
        // area each pixel sees gives the solved contact's force (pixel sums against node sums).
        let summed = sensor::DomeAreas::new(&sensor).wrench(&label.pressure_kpa);
        let off = summed.force_distance_n(&label.wrench) / got;
        eprintln!("  pressure map summed over pixels: {:?} N, {:.2} % off the nodes'", summed.force_n, 100.0 * off);
        assert!(off <= 0.03, "{:?} against {:?}", summed.force_n, label.wrench.force_n);
    }
}

#[test]
fn the_fast_angle_agrees_with_libm_everywhere() {
    for k in 0..=20_000 {
        let t = k as f64 / 20_000.0 * std::f64::consts::PI;
        let (side, along) = (t.sin().abs() * 3.7, t.cos() * 3.7);
        let got = super::angle_from(side, along);
        assert!((got - side.atan2(along)).abs() <= 1e-8, "{t}: {got} against {}", side.atan2(along));
    }
    assert_eq!(super::angle_from(0.0, 0.0), 0.0);
}

/// Hertz's surface beyond the contact (Johnson, Contact Mechanics, eq. 3.42b): for `r > a`,
/// `u = p0 / (2 a E*) [(2 a^2 - r^2) asin(a / r) + r a sqrt(1 - a^2 / r^2)]`, and inside
/// `u = d - r^2 / (2 R_eff)`; far away Boussinesq's `F / (pi E* r)`.
fn hertz_surface_mm(r_sphere: f64, depth: f64, r: f64) -> f64 {
    let e_star = Material::PAPER.effective_modulus_mpa();
    let (force, a) = hertz_force_n(r_sphere, depth);
    let r_eff = r_sphere * R / (r_sphere + R);
    if r <= a {
        return depth - r * r / (2.0 * r_eff);
    }
    let p0 = 3.0 * force / (2.0 * std::f64::consts::PI * a * a);
    p0 / (2.0 * a * e_star) * ((2.0 * a * a - r * r) * (a / r).asin() + r * a * (1.0 - a * a / (r * r)).sqrt())
}

/// The membrane the renderer shades: the solved surface around a sphere pressed at the top
/// follows Hertz's closed form inside and beyond the contact, through the crop's pixels; the
/// far field falls as Boussinesq's point force; without contact nothing sinks.
#[test]
fn the_solved_surface_around_a_sphere_is_hertzs() {
    let sensor = sensor::Sensor::default();
    let dome = Dome::new(&sensor);
    let (r_sphere, depth) = (6.0, 0.3);
    let contact = hertz_case(r_sphere, depth, &GridConfig::default());
    let sink = contact.sink_mm(&dome);
    let (_, a) = hertz_force_n(r_sphere, depth);
    let n = sensor.crop_size_px as usize;
    let mut worst = [0f64; 3];
    let mut compared = [0usize; 3];
    for (i, &sunk) in sink.iter().enumerate().take(n * n) {
        let dir = dome.dir(i);
        if dir == DVec3::ZERO {
            continue;
        }
        // Distance along the dome from the pole (the half-space's r).
        let r = R * dir.z.clamp(-1.0, 1.0).acos();
        let want = hertz_surface_mm(r_sphere, depth, r);
        let got = sunk as f64;
        // Inside the contact, beyond it out to 4 radii (where the surface is shaded most),
        // and far out against the point force.
        let band = if r < 0.8 * a {
            0
        } else if (1.2 * a..4.0 * a).contains(&r) {
            1
        } else if (8.0 * a..12.0 * a).contains(&r) {
            2
        } else {
            continue;
        };
        worst[band] = worst[band].max((got - want).abs() / want);
        compared[band] += 1;
    }
    eprintln!("solved surface against Hertz: worst relative error {worst:?} over {compared:?} pixels");
    assert!(compared.iter().all(|&c| c > 20), "{compared:?}");
    assert!(worst[0] <= 0.02 && worst[1] <= 0.05 && worst[2] <= 0.06, "{worst:?}");
    let none = solve(R, &Material::PAPER, &GridConfig::default(), &[], |_| -1.0).unwrap();
    assert!(none.sink_mm(&dome).iter().all(|&s| s == 0.0));
}

/// The merge without its shortcuts: every footprint again on every round, every direction of a
/// group projected onto every patch it is checked against.
fn plain_patches_over(radius_mm: f64, grid: &GridConfig, regions: &[Vec<DVec3>]) -> (Vec<Patch>, Vec<Option<usize>>) {
    let mut groups: Vec<(Vec<DVec3>, Vec<usize>)> =
        regions.iter().enumerate().filter(|(_, r)| !r.is_empty()).map(|(k, r)| (r.clone(), vec![k])).collect();
    loop {
        let footprints: Vec<Footprint> = groups.iter().map(|g| Footprint::of(radius_mm, &g.0)).collect();
        let total: f64 = footprints.iter().map(|f| f.area_mm2()).sum();
        let coarsest = (total / grid.max_nodes as f64).sqrt();
        let patches: Vec<Patch> = footprints
            .iter()
            .map(|f| {
                let own = (f.area_mm2() / grid.nodes_per_region as f64).sqrt();
                f.grid(own.max(coarsest).clamp(grid.min_spacing_mm, grid.max_spacing_mm))
            })
            .collect();
        let lands = |p: &Patch, d: DVec3| p.project(radius_mm, d).is_some_and(|st| p.holds(st));
        let corners = |p: &Patch| {
            let [i1, j1] = [p.size[0] - 1, p.size[1] - 1];
            [(0, 0), (i1, 0), (0, j1), (i1, j1), (i1 / 2, j1 / 2)].map(|(i, j)| p.direction(radius_mm, i, j))
        };
        let mut merged = false;
        'pairs: for a in 0..patches.len() {
            for b in a + 1..patches.len() {
                let (pa, pb) = (&patches[a], &patches[b]);
                if corners(pa).iter().any(|&d| lands(pb, d))
                    || corners(pb).iter().any(|&d| lands(pa, d))
                    || groups[b].0.iter().any(|&d| lands(pa, d))
                {
                    let (dirs, members) = groups.remove(b);
                    groups[a].0.extend(dirs);
                    groups[a].1.extend(members);
                    merged = true;
                    break 'pairs;
                }
            }
        }
        if !merged {
            let mut group_of = vec![None; regions.len()];
            for (g, (_, members)) in groups.iter().enumerate() {
                for &k in members {
                    group_of[k] = Some(g);
                }
            }
            return (patches, group_of);
        }
    }
}

/// A scene's worth of small regions scattered over the dome's upper part, some close enough to
/// merge, each the outline of a disk (what `Dome::solve` hands over), from `seed`.
fn scattered_regions(seed: u64) -> Vec<Vec<DVec3>> {
    let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut uniform = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let count = 3 + (uniform() * 25.0) as usize;
    let (cluster_theta, cluster_phi) = (uniform() * 0.9, uniform() * std::f64::consts::TAU);
    (0..count)
        .map(|k| {
            if k == count / 2 {
                return Vec::new();
            }
            // Most near one spot (a contact seen as a score of regions), the rest anywhere.
            let (theta, phi) = if uniform() < 0.7 {
                (cluster_theta + 0.15 * (uniform() - 0.5), cluster_phi + 0.3 * (uniform() - 0.5))
            } else {
                (uniform() * 1.2, uniform() * std::f64::consts::TAU)
            };
            let centre = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
            let (e1, e2) = tangent_axes(centre);
            let radius_mm = 0.05 + 2.0 * uniform() * uniform();
            let points = 1 + (radius_mm * 40.0) as usize;
            if uniform() < 0.3 {
                // A thin streak, whose middle may cross another's grid while its corners do not.
                let (angle, length_mm) = (uniform() * std::f64::consts::PI, 1.0 + 6.0 * uniform());
                return (0..=4 * points)
                    .map(|i| {
                        let along = length_mm * (i as f64 / (4 * points) as f64 - 0.5);
                        from_map(centre, e1, e2, R, [along * angle.cos(), along * angle.sin()])
                    })
                    .collect();
            }
            (0..points)
                .map(|i| {
                    let a = i as f64 * std::f64::consts::TAU / points as f64;
                    from_map(centre, e1, e2, R, [radius_mm * a.cos(), radius_mm * a.sin()])
                })
                .collect()
        })
        .collect()
}

#[test]
fn patches_are_those_of_the_plain_merge() {
    let mut merges = 0;
    for seed in 0..60 {
        let regions = scattered_regions(seed);
        for grid in [GridConfig::default(), GridConfig { max_nodes: 40, ..GridConfig::default() }] {
            let (patches, group_of) = patches_over(R, &grid, &regions);
            let (plain, plain_group_of) = plain_patches_over(R, &grid, &regions);
            assert_eq!(group_of, plain_group_of, "seed {seed}");
            assert_eq!(patches.len(), plain.len(), "seed {seed}");
            for (p, q) in patches.iter().zip(&plain) {
                assert_eq!(
                    (p.normal, p.e1, p.e2, p.spacing_mm, p.origin_mm, p.size),
                    (q.normal, q.e1, q.e2, q.spacing_mm, q.origin_mm, q.size),
                    "seed {seed}"
                );
            }
            merges += regions.iter().filter(|r| !r.is_empty()).count() - patches.len();
        }
    }
    // The cases merge, or the shortcut would have nothing to keep equal.
    assert!(merges > 100, "only {merges} merges");
    // Two thin streaks crossing away from both their middles: no corner or centre of either grid
    // lies in the other, only the directions of one show the overlap.
    let (e1, e2) = tangent_axes(DVec3::Z);
    let streak = |from: [f64; 2], to: [f64; 2]| -> Vec<DVec3> {
        (0..=120)
            .map(|i| {
                let f = i as f64 / 120.0;
                from_map(DVec3::Z, e1, e2, R, [from[0] + f * (to[0] - from[0]), from[1] + f * (to[1] - from[1])])
            })
            .collect()
    };
    let crossing = [streak([-3.0, 0.0], [3.0, 0.0]), streak([2.0, -1.0], [2.0, 5.0])];
    let (patches, group_of) = patches_over(R, &GridConfig::default(), &crossing);
    assert_eq!((patches.len(), group_of), (1, vec![Some(0), Some(0)]));
}
