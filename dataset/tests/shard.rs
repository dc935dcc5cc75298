//! Generation and labelling as job arrays: the shares (`--shard K/N`) merged by `dataset merge`
//! are the dataset one run writes, byte for byte; a merge that one run would not have made is
//! refused with the reason.

use std::path::Path;
use std::process::Output;

use crate::common;
use common::{all_files, dataset, ok, refused};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A small dataset with everything a sample can have: images of a unit, force labels, the
/// paper's 8-bit depth, tilts.
const DRAWS: [&str; 11] =
    ["--count", "11", "--seed", "4", "--unit", "6", "--a-deg", "0,20", "--lifted-fraction", "0.2", "--depth-u8"];

fn generate(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["generate", "--out", s(out)];
    args.extend(DRAWS);
    args.extend(extra);
    dataset(&args)
}

#[test]
fn merged_shares_are_the_dataset_one_run_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = |name: &str| tmp.path().join(name);
    ok(generate(&d("whole"), &[]));
    for k in 0..3 {
        let report = ok(generate(&d(&format!("s{k}")), &["--shard", &format!("{k}/3")]));
        assert!(report.contains(&format!("(shard {k}/3)")), "{report}");
    }
    // Share 0 of 3 holds ids 0, 3, 6, 9.
    let share: formats::Manifest = formats::read_json(&d("s0").join("manifest.json")).unwrap();
    assert_eq!(share.samples.iter().map(|r| r.id).collect::<Vec<_>>(), [0, 3, 6, 9]);
    let report = ok(dataset(&["merge", s(&d("s2")), s(&d("s0")), s(&d("s1")), "--out", s(&d("merged"))]));
    assert!(report.contains("11 samples") && report.contains("3 shares"), "{report}");
    let (whole, merged) = (all_files(&d("whole")), all_files(&d("merged")));
    assert_eq!(
        whole.iter().map(|f| &f.0).collect::<Vec<_>>(),
        merged.iter().map(|f| &f.0).collect::<Vec<_>>(),
        "the same files"
    );
    for (a, b) in whole.iter().zip(&merged) {
        assert!(a.1 == b.1, "{} differs", a.0);
    }
    // Merging again into the same folder (a resumed merge) leaves it as it is.
    ok(dataset(&["merge", s(&d("s0")), s(&d("s1")), s(&d("s2")), "--out", s(&d("merged"))]));
    assert!(all_files(&d("merged")) == merged);

    // What one run would not have made.
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s1")), "--out", s(&d("m1"))]));
    assert!(e.contains("2/3") && e.contains("missing"), "{e}");
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s0")), s(&d("s1")), "--out", s(&d("m2"))]));
    assert!(e.contains("both share 0/3"), "{e}");
    let e = refused(dataset(&["merge", s(&d("whole")), s(&d("s1")), "--out", s(&d("m3"))]));
    assert!(e.contains("whole") && e.contains("without --shard"), "{e}");
    ok(generate(&d("other"), &["--shard", "2/3", "--test-fraction", "0.5"]));
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s1")), s(&d("other")), "--out", s(&d("m4"))]));
    assert!(e.contains("different runs") && e.contains("test_fraction"), "{e}");
    ok(generate(&d("quarter"), &["--shard", "3/4"]));
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s1")), s(&d("quarter")), "--out", s(&d("m5"))]));
    assert!(e.contains("same number"), "{e}");
    // A share killed before it finished has no manifest yet.
    std::fs::remove_file(d("s1").join("manifest.json")).unwrap();
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s1")), s(&d("s2")), "--out", s(&d("m6"))]));
    assert!(e.contains("s1") && e.contains("has not finished"), "{e}");
    // The merge never writes into a share.
    ok(generate(&d("s1"), &["--shard", "1/3"]));
    let e = refused(dataset(&["merge", s(&d("s0")), s(&d("s1")), s(&d("s2")), "--out", s(&d("s0"))]));
    assert!(e.contains("s0"), "{e}");
    for bad in ["3/3", "1", "0/0"] {
        let e = refused(generate(&d("bad"), &["--shard", bad]));
        assert!(e.contains("--shard") && e.contains("shard"), "{bad}: {e}");
    }
}

#[test]
fn merged_label_shares_are_the_labelling_one_run_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = |name: &str| tmp.path().join(name);
    let session = d("session");
    ok(dataset(&[
        "generate",
        "--session",
        s(&session),
        "--count",
        "7",
        "--seed",
        "2",
        "--unit",
        "3",
        "--jpeg-quality",
        "90",
    ]));
    let truth = session.join(".simulation/truth.json");
    let label = |out: &Path, extra: &[&str]| {
        let mut args = vec!["label", "--session", s(&session), "--sensor", s(&truth), "--out", s(out)];
        args.extend(extra);
        ok(dataset(&args))
    };
    label(&d("whole"), &[]);
    label(&d("l0"), &["--shard", "0/2"]);
    label(&d("l1"), &["--shard", "1/2"]);
    let share: formats::Manifest = formats::read_json(&d("l1").join("manifest.json")).unwrap();
    assert_eq!(share.samples.iter().map(|r| r.id).collect::<Vec<_>>(), [1, 3, 5], "rows 1, 3 and 5 of the log");
    ok(dataset(&["merge", s(&d("l1")), s(&d("l0")), "--out", s(&d("merged"))]));
    let (whole, merged) = (all_files(&d("whole")), all_files(&d("merged")));
    assert_eq!(whole.len(), merged.len());
    for (a, b) in whole.iter().zip(&merged) {
        assert!(a.0 == b.0 && a.1 == b.1, "{} / {} differ", a.0, b.0);
    }
}
