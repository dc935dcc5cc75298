//! `cargo xtask bench register`: issue 41's first goal. Simulated capture sessions pressed in z
//! sweeps, with a rig's errors drawn within a lab's limits (z zeros +-0.3 mm per trial, x/y
//! +-0.5 mm, tilts +-1 degree, B +-2 degrees), filmed by the project's renderer and by the
//! independent image model (`gelcam`), each labelled with the unit's true sensor as `dataset
//! label` labels it and with `--register`: the offsets recovered against the truth, and both
//! labellings' depth against the depth the frames were truly pressed to, and what each kind of
//! offset costs those labels alone (its registered value, the others at the truth).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use dataset::label::{Labeller, OnBadRow};
use dataset::rig::{Labels, RigOffsets, label_errors_mm};
use dataset::session::{RendererCamera, SessionCamera, SessionWriter, Sweep};
use dataset::{Kit, SensorUnit};
use formats::dataset::GeneratorParams;

#[derive(clap::Args)]
pub struct Args {
    /// The kit: `procedural` (embedded) or its folder.
    #[arg(long, default_value = "procedural")]
    kit: String,
    /// The project's renderer's unit.
    #[arg(long, default_value_t = 7)]
    own_unit: u64,
    /// The independent image model's unit (`gelcam::GelUnit::from_seed`).
    #[arg(long, default_value_t = 44)]
    gelcam_unit: u64,
    /// Seeds of the rig's errors (`RigOffsets::draw`), one session each per camera.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    rig_errors: Vec<u64>,
    /// Sweeps per session.
    #[arg(long, default_value_t = 50)]
    sweeps: u32,
    /// Frames per sweep.
    #[arg(long, default_value_t = 40)]
    sweep_frames: u32,
    /// z step of a sweep (mm).
    #[arg(long, default_value_t = 0.05)]
    sweep_step_mm: f32,
    /// Work folder (sessions and labellings are resumed).
    #[arg(long, default_value = "out/bench-register")]
    out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let kit = Kit::open(&args.kit, 1.0, 25.0, "--kit")?;
    let own_unit = SensorUnit::from_seed(args.own_unit, 25.0);
    let own = RendererCamera::new(&own_unit, own_unit.camera.jpeg_quality);
    let gel_unit = gelcam::GelUnit::from_seed(args.gelcam_unit, 25.0);
    let gel = gelcam::GelSession::new(&gel_unit);
    let sweep = Sweep { frames: args.sweep_frames, step_mm: args.sweep_step_mm, lead_mm: Sweep::DEFAULT_LEAD_MM };
    let count = args.sweeps * args.sweep_frames;
    println!(
        "kit {}; {} sweeps of {} frames ({} mm steps) per session; true sensors",
        kit.source, args.sweeps, args.sweep_frames, args.sweep_step_mm
    );
    let mut all_met = true;
    for &seed in &args.rig_errors {
        let truth = RigOffsets::draw(seed, &kit);
        for (name, camera) in [("own", &own as &dyn SessionCamera), ("gelcam", &gel as &dyn SessionCamera)] {
            let dir = args.out.join(format!("{name}-rig{seed}"));
            let session = dir.join("session");
            let params = GeneratorParams::new(seed, count, &kit.source);
            let writer = SessionWriter {
                out: session.clone(),
                kit: &kit,
                camera,
                params,
                rig: truth.clone(),
                sweep: Some(sweep),
            };
            writer.run()?;
            let label = |register: bool| -> Result<(dataset::label::LabelReport, f64)> {
                let out = dir.join(if register { "registered" } else { "logged" });
                let start = Instant::now();
                let report = Labeller {
                    session: session.clone(),
                    out: out.clone(),
                    sensor: camera.sensor(),
                    kit: &kit,
                    on_bad_row: OnBadRow::Stop,
                    z: Default::default(),
                    force: None,
                    shard: None,
                    register,
                }
                .run()?;
                Ok((report, start.elapsed().as_secs_f64()))
            };
            let (plain, _) = label(false)?;
            let (registered, seconds) = label(true)?;
            let reg = registered.registration.context("a sweep session registers")?;
            let o = &reg.offsets;
            // What each kind of offset costs the labels: the registration's value of that kind
            // alone, the rest at the truth.
            let kinds = [
                (
                    "z zeros",
                    (|t: &mut RigOffsets, o: &RigOffsets| t.z_zero_by_trial_mm = o.z_zero_by_trial_mm.clone())
                        as fn(&mut RigOffsets, &RigOffsets),
                ),
                ("x/y", |t, o| (t.x_mm, t.y_mm) = (o.x_mm, o.y_mm)),
                ("tilts", |t, o| (t.tilt_x_deg, t.tilt_y_deg) = (o.tilt_x_deg, o.tilt_y_deg)),
                ("B", |t, o| t.b_zero_deg = o.b_zero_deg),
            ];
            let alone: Vec<RigOffsets> = kinds
                .iter()
                .map(|(_, pick)| {
                    let mut alone = truth.clone();
                    pick(&mut alone, o);
                    alone
                })
                .collect();
            let (logged_dir, registered_dir) = (dir.join("logged"), dir.join("registered"));
            let mut labels = vec![Labels::Written(&logged_dir), Labels::Written(&registered_dir)];
            labels.extend(alone.iter().map(Labels::Cast));
            let errors = label_errors_mm(&session, &registered_dir, &kit, &truth, &labels)?;
            let ((before, _), (after, pixels)) = (errors[0], errors[1]);
            let z_signed: Vec<f64> =
                o.z_zero_by_trial_mm.iter().map(|(t, z)| (z - truth.z_zero_by_trial_mm[t]) as f64).collect();
            let z_max = z_signed.iter().fold(0.0, |a: f64, e| a.max(e.abs()));
            let z_mean = z_signed.iter().map(|e| e.abs()).sum::<f64>() / z_signed.len().max(1) as f64;
            // Onsets found late or early all one way shift every zero alike.
            let z_bias = z_signed.iter().sum::<f64>() / z_signed.len().max(1) as f64;
            let xy = (o.x_mm - truth.x_mm).abs().max((o.y_mm - truth.y_mm).abs()) as f64;
            let tilt = (o.tilt_x_deg - truth.tilt_x_deg).abs().max((o.tilt_y_deg - truth.tilt_y_deg).abs()) as f64;
            let b = (o.b_zero_deg - truth.b_zero_deg).abs() as f64;
            let met = z_max <= 0.03 && xy <= 0.1 && tilt <= 0.2 && b <= 0.2 && after <= 0.02;
            all_met &= met;
            let unswept = plain.registration.as_ref().map_or(0, |r| r.unswept_trials.len());
            println!(
                "{name:6} rig {seed}: {} sweeps used ({} left out), {} trials' z zeros: max error {z_max:.3} mm, mean \
                 {z_mean:.3} mm, signed mean {z_bias:+.3} mm; x/y error {xy:.3} mm (x {:+.3} vs {:+.3}, y {:+.3} vs \
                 {:+.3}); tilts {tilt:.2} deg; B {b:.2} deg; label depth error against the truth {after:.4} mm \
                 registered, {before:.4} mm as logged ({pixels} px); registered labelling {seconds:.1} s; goals {}",
                reg.sweeps,
                reg.left_out.len(),
                z_signed.len(),
                o.x_mm,
                truth.x_mm,
                o.y_mm,
                truth.y_mm,
                if met { "met" } else { "NOT met" }
            );
            let costs: Vec<String> =
                kinds.iter().zip(&errors[2..]).map(|((kind, _), (mm, _))| format!("{kind} {mm:.4}")).collect();
            println!("        label error from each kind alone (mm): {}", costs.join(", "));
            if unswept > 0 {
                println!("        {unswept} trials of the log had no usable sweep");
            }
            for why in &reg.left_out {
                println!("        left out: {why}");
            }
        }
    }
    println!(
        "goals (z zeros within 0.03 mm, x/y 0.1 mm, tilts and B 0.2 degree, labels within 0.02 mm): {}",
        if all_met { "met" } else { "NOT met" }
    );
    Ok(())
}
