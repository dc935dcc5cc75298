//! `infer stream`: every frame once and in order, results equal to `predict`'s, stale frames
//! dropped and counted on a live source, bad frames skipped by name, the CLI's files.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use common::{bundle, pressed};
use dataset::Renderer;
use infer::Predictor;
use infer::stream::{FolderSink, FolderSource, GlobSource, Sink, StreamLimits, StreamReport};

/// `n` frames named `f000.png`...: every third untouched (a noisy reference), the others pressed.
fn frames(renderer: &Renderer, dir: &Path, n: usize) -> Vec<(PathBuf, image::RgbImage)> {
    std::fs::create_dir_all(dir).unwrap();
    let (_, pressed) = pressed(renderer);
    let quiet = renderer.render(&vec![0.0; renderer.grid().len()], Some(4));
    (0..n)
        .map(|i| {
            let path = dir.join(format!("f{i:03}.png"));
            let img = if i % 3 == 0 { quiet.clone() } else { pressed.clone() };
            std::fs::write(&path, sensor::frame::encode_png_rgb(&img)).unwrap();
            (path, img)
        })
        .collect()
}

fn run(p: &Predictor, source: Box<dyn infer::stream::Source>, out: Option<&Path>) -> StreamReport {
    let mut sink = out.map(|o| FolderSink::new(o).unwrap());
    let mut sinks: Vec<&mut dyn Sink> = sink.iter_mut().map(|s| s as &mut dyn Sink).collect();
    let report = infer::stream::run(p, source, &mut sinks, &StreamLimits::default(), &AtomicBool::new(false)).unwrap();
    if let Some(sink) = &sink {
        sink.finish(&report).unwrap();
    }
    report
}

fn names(report: &StreamReport) -> Vec<String> {
    report.frames.iter().map(|r| r.name.clone()).collect()
}

/// A bundle in a temporary folder, its predictor, and `n` frames in `tmp/FOLDER`.
fn setup(folder: &str, n: usize) -> (tempfile::TempDir, Predictor, Vec<(PathBuf, image::RgbImage)>) {
    let tmp = tempfile::tempdir().unwrap();
    let renderer = bundle(&tmp.path().join("bundle"));
    let p = Predictor::load(&tmp.path().join("bundle"), &model::backend::default_device()).unwrap();
    let frames = frames(&renderer, &tmp.path().join(folder), n);
    (tmp, p, frames)
}

/// A camera drifting (every channel brighter by up to 8 %, the blue more): the gate still
/// closes on every untouched frame, and the reference follows them, a pressed frame resetting
/// the wait; with `Fixed` it never moves.
#[test]
fn the_reference_follows_a_drifting_camera_and_drift_does_not_open_the_gate() {
    let tmp = tempfile::tempdir().unwrap();
    let renderer = bundle(&tmp.path().join("bundle"));
    let p = Predictor::load(&tmp.path().join("bundle"), &model::backend::default_device()).unwrap();
    let dir = tmp.path().join("in");
    std::fs::create_dir_all(&dir).unwrap();
    let (_, pressed) = pressed(&renderer);
    let n = 40;
    for i in 0..n {
        let img = if i == 10 {
            pressed.clone()
        } else {
            let quiet = renderer.render(&vec![0.0; renderer.grid().len()], Some(200 + i as u64));
            let g = 1.0 + 0.08 * i as f32 / n as f32;
            let gain = [g, g * 0.99, g * 1.02];
            image::RgbImage::from_fn(quiet.width(), quiet.height(), |x, y| {
                let q = quiet.get_pixel(x, y).0;
                image::Rgb([0, 1, 2].map(|c| (q[c] as f32 * gain[c]).round().min(255.0) as u8))
            })
        };
        std::fs::write(dir.join(format!("f{i:03}.png")), sensor::frame::encode_png_rgb(&img)).unwrap();
    }
    let pattern = format!("{}/*.png", dir.display());
    let fast = infer::RefreshConfig { settle_s: 0.05, window_s: 0.1, weight: 0.25, min_frames: 2 };
    let stream = |reference| {
        let limits = StreamLimits { reference, ..Default::default() };
        let source = Box::new(GlobSource::new(&pattern, Some(40.0)).unwrap());
        infer::stream::run(&p, source, &mut [], &limits, &AtomicBool::new(false)).unwrap()
    };
    let followed = stream(infer::stream::ReferencePolicy::Follow(fast));
    // Only the pressed frame ran the network: drift did not open the gate.
    let ran: Vec<&str> = followed.frames.iter().filter(|r| r.network_ran).map(|r| r.name.as_str()).collect();
    assert!(ran.len() == 1 && ran[0].ends_with("f010.png"), "{ran:?}");
    assert!(followed.reference_follows && followed.reference_updates >= 3, "{} updates", followed.reference_updates);
    assert!(followed.summary().contains(&format!("updated {} times", followed.reference_updates)));
    let fixed = stream(infer::stream::ReferencePolicy::Fixed);
    assert_eq!(fixed.reference_updates, 0);
    assert!(!fixed.reference_follows && fixed.summary().contains("the bundle's throughout"));
}

#[test]
fn every_frame_of_a_glob_in_order_with_predicts_results() {
    let (tmp, p, frames) = setup("in", 7);
    let pattern = format!("{}/*.png", tmp.path().join("in").display());
    let out = tmp.path().join("out");
    let report = run(&p, Box::new(GlobSource::new(&pattern, None).unwrap()), Some(&out));

    let expected: Vec<String> = frames.iter().map(|(path, _)| path.display().to_string()).collect();
    assert_eq!(names(&report), expected);
    assert_eq!((report.arrived, report.processed, report.dropped, report.unreadable), (7, 7, 0, 0));
    // The gate answered the untouched frames (0, 3, 6) without the network.
    assert_eq!(report.network_runs, 4);
    assert_eq!(report.latency_ms.count, 7);
    assert!(report.latency_ms.p50 > 0.0 && report.latency_ms.max >= report.latency_ms.p99);
    for (i, (path, img)) in frames.iter().enumerate() {
        let stem = path.file_stem().unwrap().to_str().unwrap();
        let depth = p.predict(img).unwrap();
        let written = std::fs::read(out.join("depth").join(format!("{stem}.png"))).unwrap();
        assert_eq!(written, depth.to_png_um(), "{stem}: the stream's depth differs from predict's");
        let record = &report.frames[i];
        assert_eq!(record.network_ran, i % 3 != 0);
        assert_eq!(record.max_depth_mm, depth.max_mm());
        let cloud_path = out.join("cloud").join(format!("{stem}.ply"));
        if record.contact_pixels > 0 {
            let cloud = infer::cloud::read_ply(&cloud_path).unwrap();
            assert_eq!(cloud, p.point_cloud(&depth, sensor::CONTACT_THRESHOLD_MM));
        } else {
            assert!(!cloud_path.exists(), "{stem}: no contact, no cloud");
        }
    }
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("stream.json")).unwrap()).unwrap();
    assert_eq!(json["processed"], 7);
    assert_eq!(json["delivery"], "every");
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 8);
}

/// A clock that moves 1 ms at each reading and whose sleeps take no time.
#[derive(Default)]
struct StepClock {
    now: Duration,
}

impl infer::stream::Clock for StepClock {
    fn elapsed(&mut self) -> Duration {
        let now = self.now;
        self.now += Duration::from_millis(1);
        now
    }

    fn sleep(&mut self, d: Duration, _stop: &AtomicBool) {
        self.now += d;
    }

    fn instant(&self, _at: Duration) -> std::time::Instant {
        std::time::Instant::now()
    }
}

#[test]
fn a_paced_glob_faster_than_the_network_drops_stale_frames_and_counts_them() {
    let n = 40;
    let (tmp, p, _) = setup("in", n);
    let pattern = format!("{}/*.png", tmp.path().join("in").display());
    // 5000 fps on a clock that moves 1 ms between readings (and sleeps take no time): frame 0
    // is released, then 5 more are due at each reading until the last, frame 39, is; the 38 in
    // between are stale at the source, whatever the machine's speed. Frame 0 may still be
    // replaced in the mailbox by frame 39 before the network takes it.
    let source = GlobSource::new(&pattern, Some(5000.0)).unwrap().with_clock(Box::new(StepClock::default()));
    let report = run(&p, Box::new(source), None);
    assert_eq!(report.delivery, infer::stream::Delivery::Live);
    assert_eq!(report.arrived, n as u64);
    assert_eq!(report.processed + report.dropped + report.unreadable, n as u64, "{}", report.summary());
    assert!(report.dropped >= 38 && report.unreadable == 0, "{}", report.summary());
    assert!(report.processed >= 1);
    let got = names(&report);
    assert!(got.windows(2).all(|w| w[0] < w[1]), "out of order or repeated: {got:?}");
    // The last frame is never stale: nothing newer replaces it.
    assert!(got.last().unwrap().ends_with(&format!("f{:03}.png", n - 1)), "{got:?}");
}

#[test]
fn a_folder_is_read_as_frames_appear_each_once_whole_and_bad_ones_are_skipped_by_name() {
    let (tmp, p, staged) = setup("staged", 6);
    let watched = tmp.path().join("watched");
    std::fs::create_dir_all(&watched).unwrap();
    std::fs::copy(&staged[0].0, watched.join("a-before.png")).unwrap();
    // No idle limit: the writer stops the stream once its last frame came through.
    let (source, already) = FolderSource::new(&watched, Duration::from_millis(2), None).unwrap();
    assert_eq!(already, 1);

    // Each frame is written once the one before came out of the stream (a condition, not a
    // clock): however slow the machine, no frame waits while a newer one arrives.
    let (done_tx, done_rx) = std::sync::mpsc::channel::<String>();
    let mut signal = Signal(done_tx);
    let stop = AtomicBool::new(false);
    let (stop_ref, staged, watched_ref) = (&stop, &staged, &watched);
    let report = std::thread::scope(|scope| {
        scope.spawn(move || {
            let wait = || done_rx.recv_timeout(Duration::from_secs(120)).expect("the stream passed the frame on");
            for (i, (path, _)) in staged.iter().enumerate() {
                if i > 0 {
                    wait();
                }
                let bytes = std::fs::read(path).unwrap();
                let target = watched_ref.join(format!("b{i}.png"));
                if i == 2 {
                    // Written in place in two halves: it must not be read half-written.
                    std::fs::write(&target, &bytes[..bytes.len() / 2]).unwrap();
                    std::thread::sleep(Duration::from_millis(100));
                    std::fs::write(&target, &bytes).unwrap();
                } else {
                    formats::fs::write_atomic_unsynced(&target, &bytes).unwrap();
                }
                if i == 3 {
                    // Whole by its markers but not an image; not a frame at all.
                    let mut junk = b"\x89PNG\r\n\x1a\n".to_vec();
                    junk.extend([7u8; 40]);
                    junk.extend([0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xae, 0x42, 0x60, 0x82]);
                    formats::fs::write_atomic_unsynced(&watched_ref.join("b3x.png"), &junk).unwrap();
                    std::fs::write(watched_ref.join("notes.txt"), b"not a frame").unwrap();
                }
            }
            wait();
            stop_ref.store(true, std::sync::atomic::Ordering::Relaxed);
        });
        let mut sinks: [&mut dyn Sink; 1] = [&mut signal];
        infer::stream::run(&p, Box::new(source), &mut sinks, &StreamLimits::default(), &stop).unwrap()
    });
    let got = names(&report);
    let expected: Vec<String> = (0..6).map(|i| watched.join(format!("b{i}.png")).display().to_string()).collect();
    // Each frame came after the one before was done: none is stale.
    assert_eq!(got, expected, "{}", report.summary());
    assert_eq!((report.unreadable, report.dropped), (1, 0), "{}", report.summary());
    assert!(report.problems[0].contains("b3x.png"), "{:?}", report.problems);
    // The half-written frame was read whole: it is a pressed frame, so the network ran.
    assert!(report.frames[2].network_ran);
    assert!(!report.frames[0].network_ran && !report.frames[3].network_ran);
}

/// A sink that says which frame came through.
struct Signal(std::sync::mpsc::Sender<String>);

impl Sink for Signal {
    fn frame(&mut self, _: &Predictor, result: &infer::stream::FrameResult) -> Result<(), infer::stream::SinkError> {
        let _ = self.0.send(result.name.to_string());
        Ok(())
    }
}

fn infer(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infer")).arg("stream").args(args).output().unwrap()
}

#[test]
fn the_command_streams_a_glob_stops_at_max_frames_and_refuses_bad_sources() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle_dir = tmp.path().join("bundle");
    let renderer = bundle(&bundle_dir);
    let input = tmp.path().join("in");
    frames(&renderer, &input, 5);
    let b = bundle_dir.to_str().unwrap();
    let out = tmp.path().join("out");
    let pattern = format!("{}/*.png", input.display());
    let o = infer(&["--bundle", b, "--source", &pattern, "--out", out.to_str().unwrap(), "--max-frames", "3"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}{stdout}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("p50") && stdout.contains("p99"), "{stdout}");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("stream.json")).unwrap()).unwrap();
    assert_eq!(json["processed"], 3);
    assert_eq!(std::fs::read_dir(out.join("depth")).unwrap().count(), 3);
    // The reference follows the camera unless told not to.
    assert_eq!(json["reference_follows"], true);
    assert!(stdout.contains("reference frame followed the camera"), "{stdout}");
    // Workers polling between frames change no result (nor does a fixed reference over three
    // frames: it could move only after 2 s without contact).
    let polled = tmp.path().join("polled");
    let o = infer(
        &["--bundle", b, "--source", &pattern, "--out", polled.to_str().unwrap(), "--max-frames", "3"]
            .into_iter()
            .chain(["--spin-ms", "30", "--fixed-reference"])
            .collect::<Vec<_>>(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Each summary says what its latencies were measured with.
    let polled_json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(polled.join("stream.json")).unwrap()).unwrap();
    assert_eq!((json["spin_ms"].as_f64(), polled_json["spin_ms"].as_f64()), (Some(0.0), Some(30.0)));
    assert_eq!(polled_json["reference_follows"], false);
    for entry in std::fs::read_dir(out.join("depth")).unwrap() {
        let name = entry.unwrap().file_name();
        let [a, b] = [&out, &polled].map(|d| std::fs::read(d.join("depth").join(&name)).unwrap());
        assert!(a == b, "{name:?} differs with --spin-ms");
    }

    let refused = |args: &[&str], words: &[&str]| {
        let o = infer(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        for w in words {
            assert!(err.contains(w), "{args:?}: {err}");
        }
    };
    refused(&["--bundle", b, "--source", &pattern, "--max-frames", "0"], &["--max-frames", "0"]);
    refused(&["--bundle", b, "--source", &pattern, "--fixed-reference", "--follow-reference"], &["--fixed-reference"]);
    let missing = format!("{}/nothing-*.png", input.display());
    refused(&["--bundle", b, "--source", &missing], &["no PNG or JPEG frame matches", "nothing-"]);
    #[cfg(not(feature = "v4l2"))]
    refused(&["--bundle", b, "--source", "/dev/video9"], &["/dev/video9", "--features v4l2"]);
    #[cfg(not(feature = "ros2"))]
    refused(&["--bundle", b, "--source", &pattern, "--ros2"], &["--ros2", "--features ros2"]);
    #[cfg(not(feature = "view"))]
    refused(&["--bundle", b, "--source", &pattern, "--view-save", "x.rrd"], &["--view-save", "--features view"]);
    #[cfg(feature = "ros2")]
    {
        refused(
            &["--bundle", b, "--source", &pattern, "--ros2", "--ros2-namespace", "no slash"],
            &["ROS 2", "no slash"],
        );
        refused(&["--bundle", b, "--source", &pattern, "--ros2", "--ros2-domain", "233"], &["233", "0 to 232"]);
        let o = Command::new(env!("CARGO_BIN_EXE_infer"))
            .args(["stream", "--bundle", b, "--source", &pattern, "--ros2"])
            .env("ROS_DOMAIN_ID", "seven")
            .output()
            .unwrap();
        assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("ROS_DOMAIN_ID=\"seven\""));
    }
    // The output may not be the watched folder, nor a folder of another kind.
    refused(&["--bundle", b, "--source", input.to_str().unwrap(), "--out", input.to_str().unwrap()], &["in"]);
    refused(&["--bundle", b, "--source", &pattern, "--out", b], &["bundle"]);
    // A source with no usable frame fails the run, naming the first problem.
    let grey = tmp.path().join("grey.png");
    image::GrayImage::new(570, 570).save(&grey).unwrap();
    refused(&["--bundle", b, "--source", grey.to_str().unwrap()], &["grey.png", "greyscale"]);
}

/// SIGTERM and SIGHUP (systemd, Docker, `timeout`, a closed terminal) end a stream as Ctrl-C
/// does: exit 0 with the summary and the folder's files; a frame that never completed is named;
/// a second stream into the folder leaves none of the first one's results.
#[test]
fn a_terminated_stream_writes_its_summary_and_names_frames_never_completed() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle_dir = tmp.path().join("bundle");
    let renderer = bundle(&bundle_dir);
    let watched = tmp.path().join("watched");
    std::fs::create_dir(&watched).unwrap();
    let staged = tmp.path().join("staged");
    let made = frames(&renderer, &staged, 2);
    let out = tmp.path().join("out");
    for (round, signal) in ["TERM", "HUP"].into_iter().enumerate() {
        let mut child = Command::new(env!("CARGO_BIN_EXE_infer"))
            .args(["stream", "--bundle", bundle_dir.to_str().unwrap(), "--source", watched.to_str().unwrap()])
            .args(["--out", out.to_str().unwrap(), "--poll-ms", "10"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Once it says it streams (its folder claimed, its signal handler in place): a frame
        // written whole, and (first round) one cut short that never completes.
        let stderr = child.stderr.take().unwrap();
        let (ready, started) = std::sync::mpsc::channel();
        let reader = std::thread::spawn(move || {
            let mut text = String::new();
            for line in std::io::BufRead::lines(std::io::BufReader::new(stderr)).map_while(Result::ok) {
                if line.starts_with("streaming") {
                    let _ = ready.send(());
                }
                text += &line;
                text.push('\n');
            }
            text
        });
        started.recv_timeout(Duration::from_secs(120)).expect("the stream starts");
        let name = format!("r{round}.png");
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        std::fs::copy(&made[round].0, watched.join(&name)).unwrap();
        if round == 0 {
            let bytes = std::fs::read(&made[1].0).unwrap();
            std::fs::write(watched.join("cut.png"), &bytes[..bytes.len() / 2]).unwrap();
        }
        let stem = name.trim_end_matches(".png");
        while !out.join(format!("depth/{stem}.png")).is_file() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let killed = Command::new("kill").args([&format!("-{signal}"), &child.id().to_string()]).status().unwrap();
        assert!(killed.success());
        let output = child.wait_with_output().unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout);
        let stderr = reader.join().unwrap();
        assert!(output.status.success(), "SIG{signal}: {:?}\n{stdout}{stderr}", output.status);
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("stream.json")).unwrap()).unwrap();
        assert_eq!(json["processed"], 1, "SIG{signal}: {json}");
        assert!(std::fs::read_to_string(out.join("frames.csv")).unwrap().contains(stem));
        let depth: Vec<_> = std::fs::read_dir(out.join("depth")).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(depth, vec![std::ffi::OsString::from(format!("{stem}.png"))], "SIG{signal}: only this stream's");
        let cut_named = stdout.contains("cut.png") && stdout.contains("never written whole");
        assert_eq!(cut_named, round == 0, "SIG{signal}: {stdout}");
        if round == 0 {
            std::fs::remove_file(watched.join("cut.png")).unwrap();
        }
    }
}
