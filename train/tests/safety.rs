//! Nothing lost, no figure that lies: outputs never replace what is not theirs, bad samples are
//! counted in every split, diverged runs export nothing and leave a good checkpoint, settings
//! errors name the setting.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common;
use common::tiny_dataset;

const BIN: &str = env!("CARGO_BIN_EXE_train");

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

fn train(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn err(r: &Output) -> String {
    assert!(!r.status.success(), "expected a refusal: {}", String::from_utf8_lossy(&r.stdout));
    String::from_utf8_lossy(&r.stderr).into_owned()
}

fn ok(r: &Output) -> String {
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    String::from_utf8_lossy(&r.stdout).into_owned()
}

/// `train fit` on `data` into `out` with the tiny preset, one epoch by default, and `extra`.
fn fit(data: &Path, out: &Path, extra: &[&str]) -> Output {
    let (data, out) = (s(data), s(out));
    let mut args =
        vec!["fit", "--data", &data, "--out", &out, "--recipe", "paper", "--preset", "tiny", "--input", "64x64"];
    args.extend(["--epochs", "1", "--batch", "2", "--lr", "3e-3", "--checkpoint-every", "2"]);
    let mut args: Vec<String> = args.into_iter().map(String::from).collect();
    // `extra` overrides the flags above (a flag followed by its value) or adds to them.
    let mut k = 0;
    while k < extra.len() {
        let flag = extra[k];
        let value = extra.get(k + 1).filter(|v| !v.starts_with("--"));
        match (args.iter().position(|a| a == flag), value) {
            (Some(at), Some(v)) => args[at + 1] = v.to_string(),
            (_, v) => {
                args.push(flag.to_string());
                args.extend(v.map(|v| v.to_string()));
            }
        }
        k += 1 + value.is_some() as usize;
    }
    Command::new(BIN).args(&args).output().unwrap()
}

fn files_of(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = walk(dir);
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flat_map(|e| {
            let p = e.unwrap().path();
            if p.is_dir() { walk(&p) } else { vec![p] }
        })
        .collect()
}

#[test]
fn bundles_never_replace_a_dataset_a_run_or_unrelated_files() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let run = tmp.path().join("run");
    let before = files_of(&data);
    // --bundle onto the dataset: refused before any training.
    let e = err(&fit(&data, &run, &["--bundle", &s(&data)]));
    assert!(e.contains("is also an input"), "{e}");
    assert!(!run.exists(), "nothing was trained");
    ok(&fit(&data, &run, &[]));
    // export --run R --out R.
    let e = err(&train(&["export", "--run", &s(&run), "--out", &s(&run)]));
    assert!(e.contains("is also an input"), "{e}");
    assert!(run.join("checkpoint/state.json").is_file());
    // A folder of the user's own files.
    let mine = tmp.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), b"mine").unwrap();
    let e = err(&train(&["export", "--run", &s(&run), "--out", &s(&mine)]));
    assert!(e.contains("notes.txt") && e.contains("did not write"), "{e}");
    assert_eq!(std::fs::read(mine.join("notes.txt")).unwrap(), b"mine");
    // A run folder onto the dataset is refused too, and the dataset is untouched throughout.
    let e = err(&fit(&data, &data, &[]));
    assert!(e.contains("is also an input"), "{e}");
    assert_eq!(files_of(&data), before);
    // A bundle replaces a bundle.
    let bundle = tmp.path().join("bundle");
    ok(&train(&["export", "--run", &s(&run), "--out", &s(&bundle)]));
    ok(&train(&["export", "--run", &s(&run), "--out", &s(&bundle)]));
    assert_eq!(formats::output::marker_kind(&bundle), Some(formats::output::OutputKind::Bundle));
}

#[test]
fn bad_samples_are_counted_in_every_split_and_stop_stops_on_any() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let manifest = formats::dataset::Manifest::load(&data).unwrap();
    let test = manifest.samples.iter().find(|r| r.split == formats::Split::Test).unwrap();
    let test_image = data.join(test.image.as_ref().unwrap());
    let good = std::fs::read(&test_image).unwrap();
    std::fs::write(&test_image, b"\x89PNG\r\n\x1a\nbroken").unwrap();
    // With the test split validating (no hold-out), a bad test image stops the run...
    let e = err(&fit(&data, &tmp.path().join("a"), &["--val-fraction", "0"]));
    assert!(e.contains("bad test sample") && e.contains(test_image.file_name().unwrap().to_str().unwrap()), "{e}");
    // ...or, skipped, is counted, and the bundle records no test error rather than one over
    // part of the split.
    let bundle = tmp.path().join("b");
    let out = ok(&fit(
        &data,
        &tmp.path().join("b-run"),
        &["--val-fraction", "0", "--on-bad-data", "skip", "--bundle", &s(&bundle)],
    ));
    assert!(out.contains("1 bad validation samples skipped"), "{out}");
    let file = model::bundle::BundleFile::read(&bundle).unwrap();
    let Some(formats::training::TrainingRecord::Trained(t)) = file.training else { panic!("a trained record") };
    assert!(t.test.is_none() && t.test_missing.unwrap().contains("could not be read"));
    std::fs::write(&test_image, good).unwrap();

    // A missing training image is skipped with skip (it stopped the run at its start before).
    let train_image =
        data.join(manifest.samples.iter().find(|r| r.split == formats::Split::Train).unwrap().image.as_ref().unwrap());
    std::fs::remove_file(&train_image).unwrap();
    let out = ok(&fit(&data, &tmp.path().join("c"), &["--on-bad-data", "skip"]));
    assert!(out.contains(train_image.file_name().unwrap().to_str().unwrap()), "{out}");
    let e = err(&fit(&data, &tmp.path().join("d"), &[]));
    assert!(e.contains(train_image.file_name().unwrap().to_str().unwrap()), "{e}");
}

#[test]
fn a_split_with_nothing_to_measure_is_an_error_not_a_zero() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    common::generated(&data, 3, 12, 25.0, 0.0);
    let e = err(&fit(&data, &tmp.path().join("a"), &["--val-fraction", "0"]));
    assert!(e.contains("no test split to validate on"), "{e}");
    // With a hold-out it trains; the bundle says there is no test split instead of 0 mm.
    let bundle = tmp.path().join("b");
    ok(&fit(&data, &tmp.path().join("run"), &["--bundle", &s(&bundle)]));
    let file = model::bundle::BundleFile::read(&bundle).unwrap();
    let Some(formats::training::TrainingRecord::Trained(t)) = file.training else { panic!("a trained record") };
    assert!(t.test.is_none() && t.test_missing.unwrap().contains("no test split"));
}

#[test]
fn a_diverging_run_exports_nothing_and_keeps_a_good_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    // Infinite learning rates are refused by name; huge ones diverge.
    let e = err(&fit(&data, &tmp.path().join("inf"), &["--lr", "inf"]));
    assert!(e.contains("--lr"), "{e}");
    let bundle = tmp.path().join("b");
    let e = err(&fit(&data, &tmp.path().join("huge"), &["--lr", "1e30", "--bundle", &s(&bundle)]));
    assert!(e.contains("non-finite") || e.contains("diverged"), "{e}");
    assert!(!bundle.exists(), "a diverged run exports nothing");
    // A good first epoch, then divergence: the run stops, and the checkpoint it points to loads,
    // resumes and exports (its metrics may hold NaN, written as null).
    let run = tmp.path().join("run");
    ok(&fit(&data, &run, &["--epochs", "1"]));
    let state = train::checkpoint::read_state(&train::checkpoint::latest(&run).unwrap()).unwrap();
    let mut broken = state.clone();
    broken.history[0].val_l1_mm = f64::NAN;
    formats::write_json(&run.join("checkpoint/state.json"), &broken).unwrap();
    assert!(std::fs::read_to_string(run.join("checkpoint/state.json")).unwrap().contains("null"));
    ok(&train(&["export", "--run", &s(&run), "--out", &s(&tmp.path().join("exported"))]));
    ok(&fit(&data, &run, &["--epochs", "1", "--resume"]));
}

#[test]
fn settings_errors_name_the_setting_with_both_values() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    for (flag, value) in [("--batch", "0"), ("--epochs", "0"), ("--lr", "nan"), ("--val-fraction", "1")] {
        let e = err(&fit(&data, &tmp.path().join("x"), &[flag, value]));
        assert!(e.contains(flag), "{flag} {value}: {e}");
    }
    let run = tmp.path().join("run");
    ok(&fit(&data, &run, &["--epochs", "1"]));
    let e = err(&fit(&data, &run, &["--epochs", "2", "--resume"]));
    assert!(e.contains("epochs: 1 before, 2 now"), "{e}");
    let e = err(&fit(&data, &run, &["--epochs", "1", "--resume", "--preset", "compact"]));
    assert!(e.contains("model: tiny before, compact now"), "{e}");
}

/// A run on the CPU never starts a GPU runtime: a resume used to load the Vulkan loader (and
/// print its complaints) through Burn's default device.
#[test]
fn a_cpu_resume_loads_no_gpu_runtime() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let run = tmp.path().join("run");
    ok(&fit(&data, &run, &[]));
    let loader_lines = |extra: &[&str]| {
        let mut cmd = Command::new(BIN);
        let (d, o) = (s(&data), s(&run));
        cmd.args(["fit", "--data", &d, "--out", &o, "--recipe", "paper", "--preset", "tiny", "--input", "64x64"]);
        cmd.args(["--epochs", "1"]);
        cmd.args(["--batch", "2", "--lr", "3e-3", "--checkpoint-every", "2"]).args(extra);
        let r = cmd.env("VK_LOADER_DEBUG", "error,warn,info").env_remove("BURN_DEVICE").output().unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        String::from_utf8_lossy(&r.stderr).lines().filter(|l| l.to_ascii_lowercase().contains("loader")).count()
    };
    assert_eq!(loader_lines(&["--resume"]), 0, "the Vulkan loader ran during a CPU resume");
}

/// A run folder another process is training into (here: held by this test) is refused by
/// name before any work; once it is let go, the same command trains.
#[test]
fn a_run_folder_being_written_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let run = tmp.path().join("run");
    let held = formats::output::claim_dir(&run, formats::output::OutputKind::Run, &[]).unwrap();
    let e = err(&fit(&data, &run, &[]));
    assert!(e.contains(&s(&run)) && e.contains("another process is writing a training run"), "{e}");
    assert!(!run.join("checkpoint").exists());
    drop(held);
    ok(&fit(&data, &run, &[]));
    assert!(run.join("checkpoint").exists());
}
