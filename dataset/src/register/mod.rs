//! Registration from the frames (`dataset label --register`): the rig's offsets (each trial's z
//! zero, the sensor's x, y and tilts in its mount, B's zero; [`RigOffsets`]) estimated from the
//! session itself, without a network, so that labels do not carry a rig's zeros set by eye.
//!
//! It reads the log's z sweeps: rows of one trial, tilts and B at several z. In each, the first
//! frame whose local change (a 9x9 box's, against the reference) rises out of the noise finds the
//! touch; each frame's change against the sweep's own untouched frames, projected on a frame 0.25
//! mm further, is then fitted as a power (1 to 2, the best) of the travel past an onset, which is
//! the logged z of first touch; where the change sits a little past it says where the skin was
//! touched. A camera that shows a touch's first tenths of a millimetre only faintly (a soft gel's
//! smoothing, JPEG blocks) shows that first frame late: where the change's growth, projected
//! through a spatial matched filter on the sweep's deepest change, extrapolates back to an onset
//! clearly earlier, that onset is used instead, with the distance it reaches back in its
//! uncertainty, and the contact is placed on the first frame that shows it. The ray cast says both
//! for any candidate offsets (the travel at which an indenter first meets the useful disk, and its
//! contact's centroid), and, linearised about the log and then about the first answer, the sweeps'
//! onsets and centroids give the offsets by weighted least squares. About the answer, a sweep whose
//! cast contact jumps within a step of the offsets (another part or blob taking the lead: the
//! slopes miss the centroid a step back by more than its deviation) has slopes that mean nothing:
//! its onset stays in the fit, its centroid does not, though it is still judged against the cast's.
//! Sweeps that start touched, never change, fit no growth law, that the ray cast cannot follow (no
//! first touch near the logged one under candidate offsets), or that disagree with what the others
//! predict (beyond five standard deviations of that prediction, the worst first, up to a quarter)
//! are named and left out.
//!
//! Measured against the truth on the renderer's sweeps of the authors' kit (`cargo xtask bench
//! register`, BENCHMARKS.md): onsets 0.003 mm late on average, scattering by 0.02 mm. On the
//! independent image model's JPEG frames the growth law finds 48 of 50 sweeps' onsets, but
//! 0.09 mm late on average and scattering by 0.11 mm: the goals are far there.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use formats::dataset::RigPose;
use formats::session::Capture;
use image::RgbImage;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use sensor::Sensor;
use sensor::frame::read_crop;
use serde::{Deserialize, Serialize};

use crate::generate::build_scene_in;
use crate::kit::{Kit, Trial};
use crate::raycast::{RayBundle, RayCaster, Skipping};
use crate::rig::{RigOffsets, trial_key};
use crate::touch::{MIN_Z_TRAVEL_MM, Seen, first_touch_in};

mod onset;
use onset::{Onset, blob_centroid, change_map, onset};

/// A sweep needs this many frames: a few untouched ones to learn the noise, and the onset.
pub const MIN_SWEEP_FRAMES: usize = 8;
/// The contact's centroid is compared this far (mm of travel) past first touch.
const PROBE_MM: f32 = 0.1;
/// A centroid's standard deviation (px) in the fit: the image's and the cast's contact
/// differ in shape as well as by noise. Measured against the cast under the true offsets: 4.1
/// px RMS over the 443 sweeps whose onsets set `onset::MIN_ONSET_SD_MM` (BENCHMARKS.md), 4.7
/// and 3.9 px per axis over the 50 of the renderer's rig-1 session; the onsets' and the
/// centroids' deviations keep the ratio they had at 0.02 mm and 3 px.
const CENTROID_SD_PX: f64 = 4.1;
/// Steps of the finite differences: x, y (mm), tilts, B (degrees).
const STEPS: [f32; 5] = [0.25, 0.25, 0.5, 0.5, 1.0];
/// Weak priors on the mount (one sd, mm and degrees): three times the limits a rig shows, so
/// that a session whose sweeps cannot tell an offset apart still solves, at zero.
const PRIOR_SD: [f64; 5] = [1.5, 1.5, 3.0, 3.0, 6.0];
/// A sweep this many standard deviations off what the other sweeps predict for it disagrees
/// with them and is left out.
const DISAGREE_SIGMAS: f64 = 5.0;

/// The offsets estimated from a session's frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Registration {
    /// The estimate: each swept trial's z zero in `z_zero_by_trial_mm`.
    pub offsets: RigOffsets,
    /// One standard deviation of each estimate, in the same fields.
    pub sd: RigOffsets,
    /// Sweeps the estimate is made from.
    pub sweeps: usize,
    /// Sweeps left out: too few frames, no onset found, or a residual that disagrees with the
    /// rest (`line N (frame): why`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub left_out: Vec<String>,
    /// Trials of the log with no sweep used: their z zero is taken as the log's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unswept_trials: Vec<String>,
}

/// Rows of one trial at one tilt and B, sorted by z.
struct SweepRows<'k> {
    trial: &'k Trial,
    pose: RigPose,
    rows: Vec<Capture>,
}

impl SweepRows<'_> {
    fn name(&self) -> String {
        format!("line {} ({})", self.rows[0].line, self.rows[0].frame)
    }
}

/// The log's sweeps: rows grouped by trial, tilts and B (in the order they first appear).
fn sweeps<'k>(kit: &'k Kit, rows: &[Capture]) -> (Vec<SweepRows<'k>>, Vec<String>) {
    let mut groups: Vec<SweepRows> = Vec::new();
    let mut index = BTreeMap::new();
    for r in rows {
        let Some(trial) = kit.trial(r.split, r.trial) else { continue };
        let p = r.pose;
        let key = (trial_key(r.split, r.trial), p.a_axis_deg.to_bits(), p.b_axis_deg.to_bits(), p.c_axis_deg.to_bits());
        let k = *index.entry(key).or_insert_with(|| {
            groups.push(SweepRows { trial, pose: RigPose { z_travel_mm: 0.0, ..p }, rows: Vec::new() });
            groups.len() - 1
        });
        groups[k].rows.push(r.clone());
    }
    let mut short = Vec::new();
    groups.retain_mut(|g| {
        g.rows.sort_by(|a, b| a.pose.z_travel_mm.total_cmp(&b.pose.z_travel_mm));
        g.rows.dedup_by(|a, b| a.pose.z_travel_mm == b.pose.z_travel_mm);
        let keep = g.rows.len() >= MIN_SWEEP_FRAMES;
        if !keep && g.rows.len() > 1 {
            short.push(format!("{}: {} frames, a sweep needs {MIN_SWEEP_FRAMES}", g.name(), g.rows.len()));
        }
        keep
    });
    (groups, short)
}

/// The touch a camera shows: an indenter's, on the useful disk.
fn seen(mask: &[bool]) -> Seen<'_> {
    Seen { within: Some(mask), indenters_only: true }
}

/// Where the cast looks for a sweep's first touch (mm of logged travel), and how far past it
/// (mm) it places the contact, as the image's was placed.
#[derive(Clone, Copy)]
struct Search {
    bracket: (f32, f32),
    probe_mm: f64,
}

/// What every cast of the session shares: the kit, the sensor with its rays, and the useful
/// disk.
struct Caster<'a> {
    kit: &'a Kit,
    sensor: &'a Sensor,
    rays: RayBundle,
    mask: Vec<bool>,
}

impl Caster<'_> {
    /// The logged travel (mm) within `bracket` at which an indenter of the sweep first meets the
    /// useful disk under candidate offsets.
    fn first_touch(&self, sweep: &SweepRows, rig: &RigOffsets, bracket: (f32, f32)) -> Result<f32> {
        let Caster { kit, sensor, rays, mask } = self;
        first_touch_in(kit, sweep.trial, sweep.pose, rig, sensor, rays, bracket, seen(mask))
    }

    /// The ray cast's account of a sweep under candidate offsets: its first touch (mm of logged
    /// travel) and the contact's depth-weighted centroid (px) `probe_mm` past it, where the
    /// image's was taken.
    fn predict(
        &self,
        sweep: &SweepRows,
        rig: &RigOffsets,
        Search { bracket, probe_mm }: Search,
    ) -> Result<(f64, [f64; 2])> {
        let Caster { kit, sensor, rays, mask } = self;
        let touch = self.first_touch(sweep, rig, bracket)?;
        let pose = RigPose {
            z_travel_mm: touch + probe_mm as f32,
            b_axis_deg: sweep.pose.b_axis_deg + rig.b_zero_deg,
            ..sweep.pose
        };
        let scene = build_scene_in(kit, sweep.trial, pose, rig.mount())?;
        // The contact of the parts whose touch was counted.
        let parts = seen(mask).parts(&scene);
        let (depth, _) = RayCaster::new(&parts, sensor.radius_mm, Skipping::On).depth_map(sensor, rays);
        let centroid =
            blob_centroid(sensor.crop_size_px as usize, |p| if mask[p] { depth.depth_mm[p] as f64 } else { 0.0 })
                .context("no contact past first touch")?;
        Ok((touch as f64, centroid))
    }

    /// The cast's touch and centroid for a sweep at offsets `theta`, and their derivatives (and,
    /// where `judge`, whether the centroid's slopes hold a step away).
    fn linearise(&self, g: &SweepRows, theta: &[f64; 5], search: Search, judge: bool) -> Result<Linearised> {
        let at = |theta: &[f64; 5]| self.predict(g, &offsets_of(theta), search);
        let (touch_mm, centroid_px) = at(theta)?;
        let (mut d_touch, mut d_centroid) = ([0.0; 5], [[0.0; 2]; 5]);
        for (k, &step) in STEPS.iter().enumerate() {
            let mut moved = *theta;
            moved[k] += step as f64;
            let (t, c) = at(&moved)?;
            d_touch[k] = (t - touch_mm) / step as f64;
            d_centroid[k] = [(c[0] - centroid_px[0]) / step as f64, (c[1] - centroid_px[1]) / step as f64];
        }
        // One step back along every offset at once, to see whether the slopes hold there (a
        // cast that cannot follow the sweep there does not).
        let bend_px = if judge {
            let back: [f64; 5] = std::array::from_fn(|k| theta[k] - STEPS[k] as f64);
            at(&back).map_or(f64::INFINITY, |(_, c)| {
                let slope = |a: usize| (0..5).map(|k| d_centroid[k][a] * STEPS[k] as f64).sum::<f64>();
                (0..2).map(|a| (c[a] - (centroid_px[a] - slope(a))).abs()).fold(0.0, f64::max)
            })
        } else {
            0.0
        };
        Ok(Linearised { touch_mm, centroid_px, d_touch, d_centroid, bend_px })
    }
}

/// The offsets in the order of [`STEPS`], as a rig's errors (no z zeros).
fn offsets_of(theta: &[f64]) -> RigOffsets {
    RigOffsets {
        x_mm: theta[0] as f32,
        y_mm: theta[1] as f32,
        tilt_x_deg: theta[2] as f32,
        tilt_y_deg: theta[3] as f32,
        b_zero_deg: theta[4] as f32,
        ..RigOffsets::default()
    }
}

/// One sweep linearised: the cast's touch and centroid at the current offsets, and their
/// derivatives along each offset.
struct Linearised {
    touch_mm: f64,
    centroid_px: [f64; 2],
    d_touch: [f64; 5],
    d_centroid: [[f64; 2]; 5],
    /// How far (px) the centroid one step back along every offset is from where the slopes
    /// put it: its second difference where the cast is smooth, a jump where it is not.
    bend_px: f64,
}

/// Linearisations: the second about the first's estimate.
const GAUSS_NEWTON_PASSES: usize = 2;

/// Estimates the rig's offsets from the session's sweeps (`None`: the log has no sweep). `rows`
/// are the log's parsed rows; frames are read as crops of `sensor` relative to `session`.
pub fn register(
    session: &Path,
    kit: &Kit,
    sensor: &Sensor,
    rows: &[Capture],
    reference: &RgbImage,
) -> Result<Option<Registration>> {
    let (groups, mut left_out) = sweeps(kit, rows);
    if groups.is_empty() {
        return Ok(None);
    }
    let caster = Caster { kit, sensor, rays: RayBundle::new(sensor), mask: sensor.valid_mask() };
    let mask = &caster.mask;
    let n = sensor.crop_size_px as usize;
    let onsets: Vec<Result<Onset, String>> = groups
        .par_iter()
        .map(|g| -> Result<Result<Onset, String>> {
            let (mut frames, mut maps) = (Vec::with_capacity(g.rows.len()), Vec::with_capacity(g.rows.len()));
            for r in &g.rows {
                let frame = read_crop(&session.join(&r.frame), sensor)?;
                // A camera's exposure and colour balance drift between frames: taken out
                // against the reference as the contact gate does.
                let frame = sensor::gate::Balance::fit(&frame, reference, mask).undo(&frame, reference);
                maps.push(change_map(&frame, reference, mask));
                frames.push(frame);
            }
            let z: Vec<f32> = g.rows.iter().map(|r| r.pose.z_travel_mm).collect();
            Ok(onset(&frames, &maps, &z, n, mask))
        })
        .collect::<Result<_>>()?;
    let mut used: Vec<(&SweepRows, Onset)> = Vec::new();
    for (g, o) in groups.iter().zip(onsets) {
        match o {
            Ok(o) => used.push((g, o)),
            Err(why) => left_out.push(format!("{}: {why}", g.name())),
        }
    }
    // The log's first touches, found over the whole travel once; later casts search near them.
    // A sweep the cast cannot follow (no first touch in its travel or near it under candidate
    // offsets) is left out, named, rather than stop the labels.
    let full = (MIN_Z_TRAVEL_MM, sensor.max_depth_mm as f32);
    let logged: Vec<Result<f32>> =
        used.par_iter().map(|(g, _)| caster.first_touch(g, &RigOffsets::default(), full)).collect();
    let mut cast = Vec::new();
    for ((g, o), t) in used.into_iter().zip(logged) {
        match t {
            Ok(t) => cast.push((g, o, t)),
            Err(e) => left_out.push(format!("{}: the ray cast finds no first touch for its log: {e:#}", g.name())),
        }
    }
    let mut theta = [0.0; 5];
    let mut solution = None;
    let mut kept = Vec::new();
    let mut disagree = Vec::new();
    let mut uncast = Vec::new();
    for pass in 0..GAUSS_NEWTON_PASSES {
        // Every measured sweep, linearised about the current estimate: one that disagreed about
        // the log's offsets may agree about better ones (which indenter touches first can change).
        let lin: Vec<Result<Linearised>> = cast
            .par_iter()
            .map(|(g, o, t)| {
                // About the log, far from the truth, a contact may jump where it would not near
                // it, and a short session needs every slope to get near: only the passes about
                // an estimate judge the slopes.
                caster.linearise(g, &theta, Search { bracket: (t - 1.5, t + 1.5), probe_mm: o.probe_mm }, pass > 0)
            })
            .collect();
        uncast = lin.iter().enumerate().filter_map(|(i, l)| Some((i, format!("{:#}", l.as_ref().err()?)))).collect();
        // Sweeps that disagree with the rest (a sweep whose touch the image shows late, whose
        // contact it places elsewhere, or a wrong line in the log) are left out one at a time,
        // the worst first, up to a quarter of them.
        let mut index: Vec<usize> = (0..cast.len()).filter(|&i| lin[i].is_ok()).collect();
        disagree.clear();
        // Each sweep beside its own linearisation, so the two lists cannot fall out of step.
        let pick = |index: &[usize]| -> (Vec<(&SweepRows, Onset)>, Vec<&Linearised>) {
            index.iter().filter_map(|&i| Some(((cast[i].0, cast[i].1), lin[i].as_ref().ok()?))).unzip()
        };
        let solve_over = |index: &[usize]| {
            let (sub, sub_lin) = pick(index);
            solve(&sub, &sub_lin, &theta)
        };
        let mut s = solve_over(&index);
        // Each sweep is judged against the fit of the others: a sweep far off pulls a fit that
        // holds it towards itself, so its residual there can look small while its good
        // neighbours show the misfit.
        while s.is_some() && 4 * (disagree.len() + 1) <= cast.len() {
            let worst = (0..index.len())
                .into_par_iter()
                .filter_map(|j| {
                    let rest: Vec<usize> = index.iter().enumerate().filter(|&(k, _)| k != j).map(|(_, &i)| i).collect();
                    let others = solve_over(&rest)?;
                    let i = index[j];
                    let off = misfit(cast[i].0, &cast[i].1, lin[i].as_ref().ok()?, &others);
                    Some((j, off, others))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1));
            let Some((j, off, others)) = worst else { break };
            if off <= DISAGREE_SIGMAS {
                break;
            }
            disagree.push((index.remove(j), off));
            s = Some(others);
        }
        if let Some(sol) = &s {
            theta = sol.theta;
        }
        solution = s;
        kept = index;
    }
    for &(i, residual) in &disagree {
        left_out.push(format!(
            "{}: disagrees with the other sweeps ({residual:.1} standard deviations off what they say)",
            cast[i].0.name()
        ));
    }
    for (i, why) in uncast {
        left_out.push(format!("{}: the ray cast cannot follow it near the estimated offsets: {why}", cast[i].0.name()));
    }
    let sweeps_used = kept.len();
    let trials: std::collections::BTreeSet<String> =
        rows.iter().filter(|r| kit.trial(r.split, r.trial).is_some()).map(|r| trial_key(r.split, r.trial)).collect();
    let (offsets, sd) = match solution {
        Some(s) => (s.offsets, s.sd),
        None => (RigOffsets::default(), RigOffsets::default()),
    };
    let unswept_trials = trials.into_iter().filter(|t| !offsets.z_zero_by_trial_mm.contains_key(t)).collect();
    Ok(Some(Registration { offsets, sd, sweeps: sweeps_used, left_out, unswept_trials }))
}

struct Solution {
    theta: [f64; 5],
    offsets: RigOffsets,
    sd: RigOffsets,
    /// The solved unknowns (the offsets' change from the linearisation's, then the zeros), their
    /// covariance, and each swept trial's place among them (after the five offsets).
    unknowns: DVector<f64>,
    covariance: DMatrix<f64>,
    trials: BTreeMap<String, usize>,
}

/// Weighted least squares over the mount's five offsets and each swept trial's z zero.
fn solve(used: &[(&SweepRows, Onset)], lin: &[&Linearised], theta0: &[f64; 5]) -> Option<Solution> {
    if used.is_empty() {
        return None;
    }
    let mut trials: BTreeMap<String, usize> = BTreeMap::new();
    for (g, _) in used {
        let next = trials.len();
        trials.entry(trial_key(g.trial.split, g.trial.number)).or_insert(next);
    }
    let unknowns = 5 + trials.len();
    let equations = 3 * used.len() + 5;
    let mut a = DMatrix::<f64>::zeros(equations, unknowns);
    let mut b = DVector::<f64>::zeros(equations);
    // Unknowns: the offsets' change from `theta0`, and the zeros.
    for (i, ((g, onset), m)) in used.iter().zip(lin).enumerate() {
        let t = 5 + trials[&trial_key(g.trial.split, g.trial.number)];
        for (r, (coefficients, zero, rhs)) in equations_of(onset, m, true).into_iter().enumerate() {
            for (k, c) in coefficients.into_iter().enumerate() {
                a[(3 * i + r, k)] = c;
            }
            a[(3 * i + r, t)] = zero;
            b[3 * i + r] = rhs;
        }
    }
    for k in 0..5 {
        a[(3 * used.len() + k, k)] = 1.0 / PRIOR_SD[k];
        b[3 * used.len() + k] = -theta0[k] / PRIOR_SD[k];
    }
    let normal = a.transpose() * &a;
    let chol = normal.cholesky()?;
    let u = chol.solve(&(a.transpose() * &b));
    let residual = &a * &u - &b;
    // Rows left empty (centroids not fitted) are no equations.
    let empty = (0..equations).filter(|&r| b[r] == 0.0 && a.row(r).iter().all(|&c| c == 0.0)).count();
    let dof = (equations as f64 - empty as f64 - unknowns as f64).max(1.0);
    let scale = (residual.norm_squared() / dof).max(1.0);
    let cov = chol.inverse() * scale;
    let sd_of = |k: usize| cov[(k, k)].max(0.0).sqrt();
    let theta: [f64; 5] = std::array::from_fn(|k| theta0[k] + u[k]);
    let sds: Vec<f64> = (0..5).map(sd_of).collect();
    let mut offsets = offsets_of(&theta);
    let mut sd = offsets_of(&sds);
    for (key, &t) in &trials {
        offsets.z_zero_by_trial_mm.insert(key.clone(), u[5 + t] as f32);
        sd.z_zero_by_trial_mm.insert(key.clone(), sd_of(5 + t) as f32);
    }
    Some(Solution { theta, offsets, sd, unknowns: u, covariance: cov, trials })
}

/// A sweep's three equations, in its a priori standard deviations: the coefficients on the
/// offsets' change from the linearisation's, the one on its trial's z zero, and the right side.
/// Onset: the logged first touch is the cast's touch under the offsets less the trial's zero;
/// centroids: the image's contact where the cast puts it.
fn equations_of(onset: &Onset, m: &Linearised, fit: bool) -> [([f64; 5], f64, f64); 3] {
    let w = 1.0 / onset.sd_mm;
    // A contact whose place jumps under a step of the offsets (another part or blob taking the
    // lead) has no slope to fit: its centroid adds nothing to the fit, its onset does. Judged
    // (`fit` false), its centroid must still sit where the cast puts it now.
    let smooth = m.bend_px <= CENTROID_SD_PX;
    let centroid = |axis: usize| {
        let rhs = (onset.centroid_px[axis] - m.centroid_px[axis]) / CENTROID_SD_PX;
        if !smooth {
            return ([0.0; 5], 0.0, if fit { 0.0 } else { rhs });
        }
        (std::array::from_fn(|k| m.d_centroid[k][axis] / CENTROID_SD_PX), 0.0, rhs)
    };
    [(m.d_touch.map(|d| w * d), -w, w * (onset.z_mm - m.touch_mm)), centroid(0), centroid(1)]
}

/// How far a sweep left out of `solution` is from what it predicts, in standard deviations of
/// that prediction (the worst of its equations): its own a priori one and the solution's
/// uncertainty along the equation, so that a sweep alone in pinning an offset is not called
/// off because the others cannot say where it should be. Its onset counts only where its
/// trial's zero was solved from other sweeps (otherwise that zero would take it up whole).
fn misfit(g: &SweepRows, onset: &Onset, m: &Linearised, solution: &Solution) -> f64 {
    let zero = solution.trials.get(&trial_key(g.trial.split, g.trial.number));
    let [onset_row, across, along] = equations_of(onset, m, false);
    let miss = |(coefficients, c_zero, rhs): ([f64; 5], f64, f64), zero: Option<usize>| {
        let mut row = DVector::<f64>::zeros(solution.unknowns.len());
        row.rows_mut(0, 5).copy_from_slice(&coefficients);
        if let Some(t) = zero {
            row[5 + t] = c_zero;
        }
        let variance = 1.0 + (row.transpose() * &solution.covariance * &row)[(0, 0)];
        (row.dot(&solution.unknowns) - rhs).abs() / variance.sqrt()
    };
    let lateral = miss(across, None).max(miss(along, None));
    match zero {
        Some(&t) => lateral.max(miss(onset_row, Some(t))),
        None => lateral,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sweep's equations: the onset always; the centroids in the fit only where the cast's
    /// contact moves smoothly, and judged against where the cast puts it either way.
    #[test]
    fn a_contact_that_jumps_under_the_offsets_is_judged_but_not_fitted() {
        let onset = Onset { z_mm: -3.0, sd_mm: 0.04, centroid_px: [110.0, 95.0], probe_mm: 0.1 };
        let mut m = Linearised {
            touch_mm: -3.1,
            centroid_px: [100.0, 100.0],
            d_touch: [0.5, -0.2, 0.01, 0.0, 0.0],
            d_centroid: [[8.0, 1.0], [-1.0, 7.0], [0.0, -2.8], [2.8, 0.0], [1.0, -2.0]],
            bend_px: 0.3,
        };
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        for fit in [true, false] {
            let [z, across, along] = equations_of(&onset, &m, fit);
            assert!(close(z.1, -25.0) && close(z.2, 25.0 * 0.1) && close(z.0[0], 12.5));
            assert!(close(across.0[0], 8.0 / CENTROID_SD_PX) && close(across.2, 10.0 / CENTROID_SD_PX));
            assert!(close(along.0[3], 0.0) && close(along.2, -5.0 / CENTROID_SD_PX));
        }
        m.bend_px = 2.0 * CENTROID_SD_PX;
        let [z, across, along] = equations_of(&onset, &m, true);
        assert!(close(z.0[0], 12.5) && close(z.2, 2.5), "the onset stays in the fit");
        assert!(across.0.iter().chain(&along.0).all(|&c| c == 0.0) && across.2 == 0.0 && along.2 == 0.0);
        let [_, across, along] = equations_of(&onset, &m, false);
        assert!(across.0.iter().chain(&along.0).all(|&c| c == 0.0));
        assert!(close(across.2, 10.0 / CENTROID_SD_PX) && close(along.2, -5.0 / CENTROID_SD_PX), "still judged");
    }
}
