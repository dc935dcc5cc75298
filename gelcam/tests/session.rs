//! A capture session filmed by a camera the project did not draw (`gelcam`), labelled with the
//! `dataset` command as a lab would: its frames (JPEG with 4:2:0 chroma, or PNG) are read, cut
//! around the optical centre and labelled with the depth the generator casts for the same
//! poses; the contact gate fitted to its labelled frames misses none with contact.

use std::path::Path;

use dataset::label::{Labeller, OnBadRow, report_lines};
use dataset::session::SessionWriter;
use formats::dataset::{GeneratorParams, Manifest};
use gelcam::{GelSession, GelUnit};

#[test]
fn a_session_from_another_image_model_labels_to_the_generators_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let (session, labelled) = (tmp.path().join("s"), tmp.path().join("l"));
    let kit = dataset::Kit::procedural(25.0);
    for (seed, jpeg) in [(3, Some(85)), (4, None)] {
        let mut unit = GelUnit::from_seed(seed, 25.0);
        unit.look.jpeg_quality = jpeg;
        let camera = GelSession::new(&unit);
        let params = GeneratorParams { lifted_fraction: 0.25, ..GeneratorParams::new(11, 12, &kit.source) };
        let dir = session.join(seed.to_string());
        SessionWriter { out: dir.clone(), kit: &kit, camera: &camera, params, rig: Default::default(), sweep: None }
            .run()
            .unwrap();
        let ext = if jpeg.is_some() { "jpg" } else { "png" };
        assert!(dir.join(format!("frames/000000.{ext}")).is_file() && dir.join(format!("reference.{ext}")).is_file());

        let out = labelled.join(seed.to_string());
        let labeller = Labeller {
            session: dir.clone(),
            out: out.clone(),
            sensor: &unit.sensor,
            kit: &kit,
            on_bad_row: OnBadRow::Stop,
            z: Default::default(),
            force: None,
            shard: None,
            register: false,
        };
        let report = report_lines(&labeller.run().unwrap()).join("\n");
        assert!(!report.contains("logging slip"), "no untouched frame differs beyond this unit's noise: {report}");

        let manifest = Manifest::load(&out).unwrap();
        assert_eq!(manifest.samples.len(), 12);
        let contact: Vec<_> = manifest.samples.iter().filter(|s| s.stats.contact_fraction > 0.0).collect();
        assert!(!contact.is_empty() && contact.len() < 12, "pressed and lifted frames: {}", contact.len());
        // Every labelled frame is the crop of its camera frame.
        for s in &manifest.samples {
            let crop = image::open(out.join(s.image.as_ref().unwrap())).unwrap();
            assert_eq!((crop.width(), crop.height()), (570, 570));
        }
        gate_keeps_every_contact_frame(&out);
    }
}

/// The gate `train` fits for a bundle, on this dataset: no labelled contact frame is closed on.
fn gate_keeps_every_contact_frame(data: &Path) {
    let manifest = Manifest::load(data).unwrap();
    let sensor = &manifest.sensor;
    let reference = sensor::frame::read_reference(&data.join("unit/reference.png"), sensor.crop_size_px).unwrap();
    let mask = sensor.valid_mask();
    let frames: Vec<_> = manifest
        .samples
        .iter()
        .map(|s| {
            let frame = sensor::frame::read_crop(&data.join(s.image.as_ref().unwrap()), sensor).unwrap();
            let depth_path = data.join(&s.depth);
            let depth = sensor::DepthMap::decode_png_um(&depth_path, &std::fs::read(&depth_path).unwrap()).unwrap();
            sensor::gate::GateFrame::labelled(&frame, &reference, &mask, &depth)
        })
        .collect();
    let gate = sensor::gate::fit(&frames).expect("frames with contact");
    let tally = sensor::gate::Tally::of(&gate, &frames);
    assert_eq!(tally.misses, 0, "{gate:?}: {tally:?}");
}
