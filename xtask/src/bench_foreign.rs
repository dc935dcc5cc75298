//! `cargo xtask bench foreign`: the README's real-sensor commands on a capture session filmed by
//! a camera the project did not draw (`gelcam`), against the same scenes filmed through the
//! project's renderer: calibrate each from its own saw-tooth frame, label, train the default
//! recipe, export (the contact gate fitted), evaluate the test split. Labelled as `dataset label`
//! labels by default, with force labels (the paper's silicone), so the bundles solve each
//! predicted contact for force and the evaluation reports the force error on both sessions.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use dataset::calibration::{CalibrationOptions, calibrate, compare};
use dataset::label::{Labeller, OnBadRow};
use dataset::session::{RendererCamera, SessionCamera, SessionWriter};
use dataset::{Kit, SensorUnit};
use formats::dataset::{GeneratorParams, Split};
use infer::Predictor;
use infer::eval::SplitStats;
use train::{Recipe, Start, fit};

#[derive(clap::Args)]
pub struct Args {
    /// The independent image model's unit (`gelcam::GelUnit::from_seed`).
    #[arg(long, default_value_t = 44)]
    gelcam_unit: u64,
    /// The project's renderer's unit filming the same scenes.
    #[arg(long, default_value_t = 7)]
    own_unit: u64,
    /// Scenes per session (one in ten with the rig lifted clear).
    #[arg(long, default_value_t = 1000)]
    samples: u32,
    /// Work folder (resumable: every stage continues where it stopped).
    #[arg(long, default_value = "out/bench-foreign")]
    out: PathBuf,
    /// Calibration's bound (px), as `dataset calibrate --max-uncertainty-px`.
    #[arg(long, default_value_t = dataset::calibration::DEFAULT_MAX_UNCERTAINTY_PX)]
    max_uncertainty_px: f64,
}

/// What one session gave.
struct Outcome {
    calibration_px: f64,
    stated_px: f64,
    test: SplitStats,
    train_minutes: f64,
}

pub fn run(args: Args) -> Result<()> {
    let kit = Kit::procedural(25.0);
    let params = GeneratorParams { lifted_fraction: 0.1, ..GeneratorParams::new(0, args.samples, &kit.source) };
    let gel_unit = gelcam::GelUnit::from_seed(args.gelcam_unit, 25.0);
    let gel = gelcam::GelSession::new(&gel_unit);
    let own_unit = SensorUnit::from_seed(args.own_unit, 25.0);
    let own = RendererCamera::new(&own_unit, own_unit.camera.jpeg_quality);
    let opts = CalibrationOptions { max_uncertainty_px: args.max_uncertainty_px, ..Default::default() };
    let mut results = Vec::new();
    for (name, camera) in [("gelcam", &gel as &dyn SessionCamera), ("own", &own as &dyn SessionCamera)] {
        println!("[{name}] session of {} scenes", args.samples);
        results.push((name, one(&args.out.join(name), &kit, camera, params.clone(), &opts)?));
    }
    println!();
    for (name, o) in &results {
        let t = &o.test;
        println!(
            "{name:7} calibration {:.3} px (stated +-{:.3}); test contact L1 {:.4} mm (zeros {:.4}, {:.1}x better), L1 \
             {:.4} mm, {} of {} frames answered by the gate, {} with contact; trained in {:.1} min",
            o.calibration_px,
            o.stated_px,
            t.contact_l1_mm.mean,
            t.zero_contact_l1_mm.mean,
            t.zero_contact_l1_mm.mean / t.contact_l1_mm.mean,
            t.l1_mm.mean,
            t.skipped_frames,
            t.l1_mm.n,
            t.gated_contact_frames,
            o.train_minutes
        );
        if let Some(f) = &t.force {
            println!("        test force: {}", f.headline());
        }
    }
    let (gel, own) = (&results[0].1.test, &results[1].1.test);
    let ratio = gel.contact_l1_mm.mean / own.contact_l1_mm.mean;
    let verdict = |ok: bool| if ok { "met" } else { "NOT met" };
    println!(
        "goals: contact L1 {ratio:.2}x the same scenes from the renderer's images (at most 1.5x): {}; {:.1}x better than \
         zeros (at least 3x): {}; {} frames with contact gated (none): {}",
        verdict(ratio <= 1.5),
        gel.zero_contact_l1_mm.mean / gel.contact_l1_mm.mean,
        verdict(gel.zero_contact_l1_mm.mean >= 3.0 * gel.contact_l1_mm.mean),
        gel.gated_contact_frames,
        verdict(gel.gated_contact_frames == 0)
    );
    if let (Some(g), Some(o)) = (&gel.force, &own.force) {
        println!(
            "force from the predicted depth: total force error {:.2} % of the mean force on gelcam's frames against \
             {:.2} % on the renderer's ({:.2}x)",
            g.force_magnitude_error_pct,
            o.force_magnitude_error_pct,
            g.force_magnitude_error_pct / o.force_magnitude_error_pct
        );
    }
    Ok(())
}

/// A session filmed by `camera` in `dir`, through the README's commands.
fn one(
    dir: &Path,
    kit: &Kit,
    camera: &dyn SessionCamera,
    params: GeneratorParams,
    opts: &CalibrationOptions,
) -> Result<Outcome> {
    let session = dir.join("session");
    SessionWriter { out: session.clone(), kit, camera, params, rig: Default::default(), sweep: None }.run()?;
    let sawtooth = ["png", "jpg"]
        .iter()
        .map(|e| session.join(format!("sawtooth.{e}")))
        .find(|p| p.is_file())
        .context("the session has no saw-tooth frame")?;
    let frame = sensor::frame::read(&sawtooth)?;
    let cal = match calibrate(&frame, opts) {
        Ok(cal) => cal,
        Err(e) => bail!("{}: {e}", sawtooth.display()),
    };
    let (calibration_px, _) = compare(&cal.sensor, camera.sensor());
    println!("  calibrated: {calibration_px:.3} px off the truth (stated +-{:.3})", cal.uncertainty_px);
    let data = dir.join("data");
    Labeller {
        session: session.clone(),
        out: data.clone(),
        sensor: &cal.sensor,
        kit,
        on_bad_row: OnBadRow::Stop,
        z: Default::default(),
        force: Some(dataset::mechanics::Material::PAPER),
        shard: None,
        register: false,
    }
    .run()?;
    let device = model::backend::default_device();
    let run_dir = dir.join("run");
    let config = Recipe::Quickstart.fit_config(data.clone());
    let start = Start { model_config: Recipe::Quickstart.model_config()?, weights: None };
    let started = std::time::Instant::now();
    let fitted = fit(&run_dir, &config, start, &device, true).context("training (run again to resume)")?;
    let train_minutes = started.elapsed().as_secs_f64() / 60.0;
    let bundle = dir.join("bundle");
    train::export::export_net(&fitted.net, &fitted.state, &bundle, &[&run_dir])?;
    let predictor = Predictor::load(&bundle, &device)?;
    let stats = infer::eval::evaluate_dataset(&predictor, &data, &[Split::Test], &dir.join("eval"))?;
    let test = stats.get(&Split::Test).cloned().context("no test split")?;
    Ok(Outcome { calibration_px, stated_px: cal.uncertainty_px, test, train_minutes })
}
