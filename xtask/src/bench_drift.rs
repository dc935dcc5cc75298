//! `cargo xtask bench drift`: a camera that drifts for twenty minutes, read by a trained bundle.
//!
//! A timeline of frames at `--fps`: untouched frames of the dataset's unit (fresh noise each),
//! and every `--press-every-s` a press of `--press-s` made of the test split's frames (their
//! ground truth known). Every frame is drifted as a warming camera drifts: a global gain, a
//! colour cast per channel, and a slow drift per minute (over the whole frame, or on one side of
//! it). Arms, on the same frames: undrifted; drifted as read before the drift balance (the
//! gate's fixed comparison, drifted colours into the network); drifted with the balanced gate
//! and input and the bundle's reference (`--fixed-reference`); the same with a reference
//! that follows the untouched frames (`infer stream`'s default). Each gives the untouched frames gated, those
//! with a false contact pixel, the press frames the gate kept shut, and the contact L1 of the
//! press frames. `--per-minute` below zero drifts the camera darker.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use dataset::{Renderer, SensorUnit};
use formats::SplitMix64;
use formats::dataset::{Manifest, Split};
use image::RgbImage;
use infer::eval::ImageErrors;
use infer::{Predictor, ReferenceKeeper, RefreshConfig};
use sensor::CONTACT_THRESHOLD_MM;
use sensor::gate::Balance;

#[derive(clap::Args)]
pub struct Args {
    /// The bundle to read with (the quickstart's by default).
    #[arg(long, default_value = "out/quickstart/bundle")]
    bundle: PathBuf,
    /// Its dataset, with the unit (`unit/unit.json`) and a test split.
    #[arg(long, default_value = "out/quickstart/data")]
    data: PathBuf,
    /// Minutes of frames.
    #[arg(long, default_value_t = 20.0)]
    minutes: f64,
    /// Frames per second of the timeline.
    #[arg(long, default_value_t = 1.0)]
    fps: f64,
    /// A press begins this often (seconds) ...
    #[arg(long, default_value_t = 30.0)]
    press_every_s: f64,
    /// ... and lasts this long (seconds).
    #[arg(long, default_value_t = 5.0)]
    press_s: f64,
    /// Drifts to run: each a seeded global gain in 0.9..1.1 and a cast of +-5 % per channel.
    #[arg(long, default_value_t = 4)]
    drifts: u64,
    /// Slow drift, per minute (a fraction: 0.01 is 1 %); each drift is also run with it on one
    /// side of the frame only (0 at the left edge, this at the right).
    #[arg(long, default_value_t = 0.01)]
    per_minute: f64,
}

/// One frame of the timeline: when, the picture, and for a press its truth.
struct Frame {
    t_s: f64,
    image: RgbImage,
    truth_mm: Option<Vec<f32>>,
}

/// What an arm measured.
#[derive(Default)]
struct Tally {
    untouched: usize,
    gated: usize,
    false_contact_frames: usize,
    contact_l1_mm: Vec<f64>,
    /// Press frames the gate kept shut (their depth read as zero).
    presses_shut: usize,
    updates: u64,
}

#[derive(Clone, Copy, PartialEq)]
enum Arm {
    Undrifted,
    FixedComparison,
    Balanced,
    Following,
}

pub fn run(args: Args) -> Result<()> {
    let device = model::backend::default_device();
    let predictor = Predictor::load(&args.bundle, &device)?;
    let manifest = Manifest::load(&args.data)?;
    let unit_path = args.data.join("unit/unit.json");
    let unit: SensorUnit = formats::read_json(&unit_path).with_context(|| "the drift bench needs a unit's dataset")?;
    let renderer = Renderer::for_crop(&unit);
    let mask = predictor.mask.clone();
    let tests: Vec<_> =
        manifest.samples.iter().filter(|s| s.split == Split::Test && s.stats.contact_fraction > 0.0).collect();
    anyhow::ensure!(!tests.is_empty(), "{}: no test sample with contact", args.data.display());
    let n = (args.minutes * 60.0 * args.fps).round() as usize;
    let started = Instant::now();
    let mut next_test = 0;
    let mut frames = Vec::with_capacity(n);
    let quiet: Vec<RgbImage> =
        (0..40).map(|k| renderer.render(&vec![0.0; renderer.grid().len()], Some(1000 + k))).collect();
    for k in 0..n {
        let t_s = k as f64 / args.fps;
        let pressing = t_s % args.press_every_s >= args.press_every_s - args.press_s;
        if pressing {
            let s = tests[next_test % tests.len()];
            next_test += 1;
            let image = sensor::frame::read_reference(
                &args.data.join(s.image.as_ref().context("a unit's dataset has images")?),
                predictor.file.sensor.crop_size_px,
            )?;
            let depth_path = args.data.join(&s.depth);
            let truth = sensor::DepthMap::decode_png_um(&depth_path, &std::fs::read(&depth_path)?)?;
            frames.push(Frame { t_s, image, truth_mm: Some(truth.depth_mm) });
        } else {
            frames.push(Frame { t_s, image: quiet[k % quiet.len()].clone(), truth_mm: None });
        }
    }
    println!(
        "{} frames ({:.0} min at {} fps, {} pressed), bundle {}, made in {:.0} s",
        n,
        args.minutes,
        args.fps,
        frames.iter().filter(|f| f.truth_mm.is_some()).count(),
        args.bundle.display(),
        started.elapsed().as_secs_f64()
    );
    println!();
    // What the balance costs: the gate's comparison without it (before) and with it, on the
    // untouched frames (the gate's whole decision, as `has_contact` makes it).
    let gate = predictor.gate.context("the bundle has no contact gate")?;
    let reference = predictor.reference.clone().context("the bundle has no reference image")?;
    let quiet_frames: Vec<&RgbImage> =
        frames.iter().filter(|f| f.truth_mm.is_none()).map(|f| &f.image).take(200).collect();
    let timed = |f: &dyn Fn(&RgbImage) -> bool| {
        let start = Instant::now();
        let open = quiet_frames.iter().filter(|img| f(img)).count();
        (start.elapsed().as_secs_f64() * 1e3 / quiet_frames.len() as f64, open)
    };
    let (before_ms, before_open) = timed(&|img: &RgbImage| opens_unbalanced(img, &reference, &mask, &gate));
    let (after_ms, after_open) = timed(&|img: &RgbImage| predictor.has_contact(img));
    let (fit_ms, _) = timed(&|img: &RgbImage| Balance::fit(img, &reference, &mask).is_none());
    println!(
        "gate on {} untouched frames ({} px crop): {before_ms:.2} ms a frame without the balance ({before_open} opened), \
         {after_ms:.2} ms with it ({after_open} opened), of which the balance's fit {fit_ms:.2} ms",
        quiet_frames.len(),
        predictor.file.sensor.crop_size_px
    );
    // How far a contact alone moves the balance's fit (undrifted press frames): under drift
    // that error rides on the gain the input is undone with.
    let mut moved: Vec<f32> = frames
        .iter()
        .filter(|f| f.truth_mm.is_some())
        .map(|f| Balance::fit(&f.image, &reference, &mask).gain.iter().fold(0f32, |m, g| m.max((g - 1.0).abs())))
        .collect();
    moved.sort_by(f32::total_cmp);
    // A timeline too short for a press has nothing to say here.
    if let Some(&largest) = moved.last() {
        println!(
            "a contact alone moves the balance's fit (largest channel's |gain - 1| on {} undrifted press frames): \
             median {:.4}, 90th percentile {:.4}, largest {largest:.4}",
            moved.len(),
            moved[moved.len() / 2],
            moved[moved.len() * 9 / 10],
        );
    }
    println!();
    println!(
        "| drift | arm | untouched gated | untouched with false contact | presses gated shut | contact L1 mm | x undrifted | reference updates |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    let undrifted = measure(&predictor, &frames, &mask, [1.0; 3], 0.0, false, Arm::Undrifted)?;
    let base_l1 = mean(&undrifted.contact_l1_mm);
    print_row("none", "fixed reference", &undrifted, base_l1);
    for d in 0..2 * args.drifts {
        // The first half drift evenly, the second half the same gains with the slow drift on
        // one side of the frame only.
        let uneven = d >= args.drifts;
        let mut rng = SplitMix64::for_item(0xd41f7, d % args.drifts);
        let global = rng.range(0.9, 1.1);
        let gain: [f64; 3] = std::array::from_fn(|_| global * rng.range(0.95, 1.05));
        let per_minute_pct = 100.0 * args.per_minute;
        let slow = if uneven {
            format!("0 to {per_minute_pct} %/min left to right")
        } else {
            format!("{per_minute_pct} %/min")
        };
        let name = format!("x{:.3}/{:.3}/{:.3}, {slow}", gain[0], gain[1], gain[2]);
        for (arm, what) in [
            (Arm::FixedComparison, "before: fixed comparison, drifted input"),
            (Arm::Balanced, "balanced gate and input, fixed reference"),
            (Arm::Following, "balanced, reference follows"),
        ] {
            let t = measure(&predictor, &frames, &mask, gain, args.per_minute, uneven, arm)?;
            print_row(&name, what, &t, base_l1);
        }
    }
    Ok(())
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn print_row(drift: &str, arm: &str, t: &Tally, base_l1: f64) {
    let l1 = mean(&t.contact_l1_mm);
    println!(
        "| {drift} | {arm} | {}/{} ({:.1} %) | {} | {}/{} | {l1:.4} | {:.3} | {} |",
        t.gated,
        t.untouched,
        100.0 * t.gated as f64 / t.untouched.max(1) as f64,
        t.false_contact_frames,
        t.presses_shut,
        t.contact_l1_mm.len(),
        l1 / base_l1,
        t.updates
    );
}

/// `img` drifted: each channel times its gain, and times `1 + slope * x` across the frame (`x`
/// from -1 at the left edge to 1 at the right: drift that is not the same everywhere, as one
/// LED warming up).
fn drifted(img: &RgbImage, gain: [f64; 3], slope: f64) -> RgbImage {
    let mut out = img.clone();
    let half = img.width() as f64 / 2.0;
    for (x, _, p) in out.enumerate_pixels_mut() {
        let across = 1.0 + slope * (x as f64 - half) / half;
        p.0 = std::array::from_fn(|c| (p.0[c] as f64 * gain[c] * across).round().clamp(0.0, 255.0) as u8);
    }
    out
}

/// The gate's decision as it was before the balance: frame against reference as they are.
fn opens_unbalanced(img: &RgbImage, reference: &RgbImage, mask: &[bool], gate: &sensor::gate::ContactGate) -> bool {
    let (limit, comparison) = (gate.grey_levels * 3.0, Balance::NONE.comparison());
    let changed = img
        .pixels()
        .zip(reference.pixels())
        .zip(mask)
        .filter(|((p, q), m)| **m && comparison.difference(p.0, q.0) > limit)
        .count();
    changed >= gate.min_pixels
}

/// Runs the timeline through the predictor as `arm` says.
fn measure(
    predictor: &Predictor,
    frames: &[Frame],
    mask: &[bool],
    gain: [f64; 3],
    per_minute: f64,
    uneven: bool,
    arm: Arm,
) -> Result<Tally> {
    let mut live = predictor.clone();
    // Before: the network read drifted colours as they came.
    live.balance_input = arm != Arm::FixedComparison;
    let mut keeper = (arm == Arm::Following).then(|| ReferenceKeeper::new(RefreshConfig::default()));
    let gate = live.gate.context("the bundle has no contact gate")?;
    let mut tally = Tally::default();
    for f in frames {
        // Slow drift: the whole frame, or one side of it (the other side not at all).
        let minutes = f.t_s / 60.0;
        let (slow, slope) = if uneven {
            (1.0 + per_minute * minutes / 2.0, per_minute * minutes / 2.0)
        } else {
            (1.0 + per_minute * minutes, 0.0)
        };
        let image =
            if arm == Arm::Undrifted { f.image.clone() } else { drifted(&f.image, gain.map(|g| g * slow), slope) };
        let reference = live.reference.clone().context("the bundle has no reference image")?;
        let open = match arm {
            // Today's comparison before this change: no balance taken out.
            Arm::FixedComparison => opens_unbalanced(&image, &reference, mask, &gate),
            _ => live.has_contact(&image),
        };
        let depth = if open {
            live.predict_network(std::slice::from_ref(&image))?.remove(0)
        } else {
            sensor::DepthMap::zeros(live.file.sensor.crop_size_px)
        };
        let contact_px = depth.contact_px(CONTACT_THRESHOLD_MM).iter().filter(|&&c| c).count();
        match &f.truth_mm {
            Some(truth) => {
                tally.presses_shut += usize::from(!open);
                tally
                    .contact_l1_mm
                    .push(ImageErrors::of(0, formats::Split::Test, &depth.depth_mm, truth, mask).contact_l1_mm)
            }
            None => {
                tally.untouched += 1;
                tally.gated += usize::from(!open);
                tally.false_contact_frames += usize::from(contact_px > 0);
            }
        }
        if let Some(keeper) = keeper.as_mut()
            && let Some(updated) = keeper.observe(f.t_s, &image, contact_px == 0 && !open, &reference)
        {
            live.set_reference(predictor.undrifted(updated))?;
        }
    }
    tally.updates = keeper.map_or(0, |k| k.updates);
    Ok(tally)
}
