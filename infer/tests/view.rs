//! `infer stream --view-save`: the recording, read back with Rerun's own decoder, holds what the
//! stream computed, frame by frame, as its other outputs (the folder's files, frames.csv) do.

#![cfg(feature = "view")]

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{DEPTH_MM, bundle_with, constant, pressed, pressure_config};
use sensor::{CONTACT_THRESHOLD_MM, DepthMap};
use view::{FORCE_ARROW_MM_PER_N, entity, timeline};

fn infer(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infer")).arg("stream").args(args).output().unwrap()
}

/// The rows of frames.csv as (name, network_ran, contact_pixels, [fx, fy, fz]).
fn frames_csv(path: &Path) -> Vec<(String, bool, usize, [f64; 3])> {
    let mut rows = Vec::new();
    for record in csv::Reader::from_path(path).unwrap().deserialize::<std::collections::HashMap<String, String>>() {
        let r = record.unwrap();
        let f = |k: &str| r[k].parse::<f64>().unwrap();
        rows.push((
            r["name"].clone(),
            r["network_ran"] == "true",
            r["contact_pixels"].parse().unwrap(),
            [f("fx_n"), f("fy_n"), f("fz_n")],
        ));
    }
    rows
}

#[test]
fn a_recorded_stream_reads_back_as_its_files_say() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle = tmp.path().join("bundle");
    // Depth DEPTH_MM and a uniform pressure wherever the network runs (untared: every useful
    // pixel in contact), none where the gate keeps it from running.
    let renderer = bundle_with(&bundle, pressure_config(), constant);
    let input = tmp.path().join("in");
    std::fs::create_dir_all(&input).unwrap();
    let (_, pressed) = pressed(&renderer);
    let quiet = renderer.render(&vec![0.0; renderer.grid().len()], Some(4));
    let frames = [&quiet, &pressed, &pressed, &quiet];
    for (k, img) in frames.iter().enumerate() {
        std::fs::write(input.join(format!("f{k}.png")), sensor::frame::encode_png_rgb(img)).unwrap();
    }
    let (out, rrd) = (tmp.path().join("out"), tmp.path().join("run.rrd"));
    let pattern = format!("{}/*.png", input.display());
    let o = infer(&[
        "--bundle",
        bundle.to_str().unwrap(),
        "--source",
        &pattern,
        "--out",
        out.to_str().unwrap(),
        "--no-tare",
        "--view-save",
        rrd.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}{stdout}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains(&format!("wrote {}", rrd.display())), "{stdout}");
    assert!(!tmp.path().join("run.rrd.partial").exists(), "the recording keeps its working name");

    let rec = view::read_back(&rrd).unwrap();
    let entities: Vec<String> = rec.entities().iter().map(|e| e.trim_start_matches('/').to_string()).collect();
    for e in [entity::FRAME, entity::CONTACT, entity::DEPTH, entity::CLOUD, entity::PRESSURE, entity::FORCE_ARROW]
        .into_iter()
        .chain([entity::LATENCY_MS, entity::NETWORK_RAN, entity::FPS, entity::CONTACT_PIXELS, entity::MAX_DEPTH_MM])
        .chain(entity::FORCE_N)
    {
        assert!(entities.iter().any(|x| x == e), "{e} missing from {entities:?}");
    }
    // The layout came with the data: the panels of a force bundle's stream.
    assert_eq!(rec.panels(), view::panels_by_name(&view::stream_columns(true)));
    let rows = frames_csv(&out.join("frames.csv"));
    assert_eq!(rows.len(), frames.len());
    let t = timeline::FRAME;
    let (images, masks, depths) =
        (rec.colour_images(entity::FRAME, t), rec.masks(entity::CONTACT, t), rec.depth_images(entity::DEPTH, t));
    let (clouds, ran) = (rec.points(entity::CLOUD, t), rec.scalars(entity::NETWORK_RAN, t));
    for series in [images.len(), masks.len(), depths.len(), clouds.len(), ran.len()] {
        assert_eq!(series, frames.len());
    }
    let n = renderer.grid().width;
    let mut pressed_frames = 0;
    for (k, (name, network_ran, contact_pixels, force)) in rows.iter().enumerate() {
        // The frame as the camera gave it, bit for bit, at its frame number.
        assert_eq!(images[k].0, k as i64);
        assert_eq!((images[k].1.0, images[k].1.1.as_slice()), ([n, n], frames[k].as_raw().as_slice()));
        // The depth as the folder's 16-bit micrometre PNG has it (to its half step).
        let stem = Path::new(name).file_stem().unwrap().to_str().unwrap();
        let png = DepthMap::load_png_um(&out.join("depth").join(format!("{stem}.png"))).unwrap();
        let (size, depth) = &depths[k].1;
        assert_eq!(*size, [png.size_px, png.size_px]);
        assert!(depth.iter().zip(&png.depth_mm).all(|(a, b)| (a - b).abs() <= 0.5e-3 + 1e-6), "{name}");
        // The mask is the contact threshold on that depth; the cloud has a point per contact pixel.
        let classes: Vec<u8> = depth.iter().map(|&d| u8::from(d > CONTACT_THRESHOLD_MM)).collect();
        assert_eq!(masks[k].1.1, classes, "{name}");
        assert_eq!(clouds[k].1.len(), *contact_pixels, "{name}");
        assert_eq!(ran[k].1, f64::from(u8::from(*network_ran)), "{name}");
        for (series, want) in entity::FORCE_N.iter().zip(force) {
            let got = rec.scalars(series, t)[k].1;
            assert!((got - want).abs() <= 1e-9 * want.abs().max(1.0), "{series} {name}: {got} against {want}");
        }
        if *network_ran {
            pressed_frames += 1;
            assert!(depth.iter().any(|&d| (d - DEPTH_MM).abs() < 1e-3), "{name}: the network's depth is shown");
            // The arrow is the force at the view's scale.
            let arrow = rec.arrows(entity::FORCE_ARROW, t).into_iter().find(|(i, _)| *i == k as i64).unwrap().1;
            for (a, f) in arrow[0].iter().zip(force) {
                assert!((f64::from(*a) - f * f64::from(FORCE_ARROW_MM_PER_N)).abs() <= 1e-4 * (1.0 + f.abs()));
            }
        } else {
            assert_eq!(*contact_pixels, 0, "{name}: the gate kept the network from an untouched frame");
        }
    }
    assert_eq!(pressed_frames, 2, "the gate opened for the pressed frames alone");

    // `--view-every 2`: the pictures of frames 0 and 2 only, the time series of all four; with
    // `--view-jpeg-quality` the frames as JPEG, which decode to the frame within JPEG's error.
    let sparse = tmp.path().join("sparse.rrd");
    let o = infer(&[
        "--bundle",
        bundle.to_str().unwrap(),
        "--source",
        &pattern,
        "--no-tare",
        "--view-save",
        sparse.to_str().unwrap(),
        "--view-every",
        "2",
        "--view-jpeg-quality",
        "90",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = view::read_back(&sparse).unwrap();
    assert!(rec.colour_images(entity::FRAME, t).is_empty(), "raw frames beside the JPEG ones");
    let jpegs = rec.encoded_images(entity::FRAME, t);
    assert_eq!(jpegs.iter().map(|i| i.0).collect::<Vec<_>>(), [0, 2]);
    for (k, (size, rgb)) in &jpegs {
        assert_eq!(*size, [n, n]);
        let frame = frames[*k as usize].as_raw();
        let mean_error =
            rgb.iter().zip(frame).map(|(&a, &b)| f64::from(a.abs_diff(b))).sum::<f64>() / frame.len() as f64;
        assert!(mean_error < 3.0, "frame {k}: the JPEG is {mean_error:.2} grey levels off on average");
    }
    assert_eq!(rec.depth_images(entity::DEPTH, t).iter().map(|i| i.0).collect::<Vec<_>>(), [0, 2]);
    assert_eq!(rec.points(entity::CLOUD, t).iter().map(|i| i.0).collect::<Vec<_>>(), [0, 2]);
    assert_eq!(rec.scalars(entity::NETWORK_RAN, t).len(), frames.len());
    assert_eq!(rec.scalars(entity::FORCE_N[2], t).len(), frames.len());
    let o = infer(&["--bundle", bundle.to_str().unwrap(), "--source", &pattern, "--view-every", "0"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--view-every"));
    let o = infer(&["--bundle", bundle.to_str().unwrap(), "--source", &pattern, "--view-jpeg-quality", "0"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--view-jpeg-quality"));

    // A recording that cannot be written stops the stream before it starts, naming the file;
    // the view's options need each other's absence.
    let missing = tmp.path().join("no-such-folder").join("run.rrd");
    let o =
        infer(&["--bundle", bundle.to_str().unwrap(), "--source", &pattern, "--view-save", missing.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("no-such-folder"), "{err}");
    let o = infer(&["--bundle", bundle.to_str().unwrap(), "--source", &pattern, "--view", "--view-save", "x.rrd"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--view"));
}
