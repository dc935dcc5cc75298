//! The Python package's tests (`python/tests/test_*.py`), run by pytest against the extension
//! module this build made, on fixtures made here with the workspace's crates: a bundle, a
//! simulated capture session, a dataset, and `infer predict`'s own files for some frames, which
//! the Python predictor must equal bit for bit, and the whole predictor's ONNX file, which ONNX
//! Runtime must run to within 1e-3 mm of them (where `onnxruntime` is installed).

#[path = "../../infer/tests/common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// The build's output folder (`target/<profile>`): this test runs from its `deps/`.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent().and_then(Path::parent).unwrap().to_path_buf()
}

/// The package the tests import, in `site`: the wheel `DENSETACT_WHEEL` names, installed by pip
/// as a user installs it (CI builds it with maturin), or else the package as pip would lay it
/// out from this build: the Python sources beside the extension module the build made.
fn install_package(target: &Path, site: &Path) {
    if let Some(wheel) = std::env::var_os("DENSETACT_WHEEL") {
        let wheel = PathBuf::from(wheel);
        assert!(
            wheel.is_absolute() && wheel.is_file(),
            "DENSETACT_WHEEL={}: not a wheel file's absolute path (the tests run in python/)",
            wheel.display()
        );
        let out = Command::new(python())
            .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps", "--no-index"])
            .arg("--target")
            .arg(site)
            .arg(&wheel)
            .output()
            .expect("python3 runs");
        let report = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "pip install {}:\n{report}", wheel.display());
        return;
    }
    // `cargo test` leaves the extension among the dependencies (`deps/`), a build of the crate
    // itself beside them; the newer is this build's.
    let names = ["lib_densetact.so", "lib_densetact.dylib"];
    let found = [target.to_path_buf(), target.join("deps")].into_iter().flat_map(|d| names.map(|n| d.join(n)));
    let ext = found
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max_by_key(|(modified, _)| *modified)
        .map(|(_, p)| p);
    let ext = ext.unwrap_or_else(|| {
        panic!("no extension module in {}: build the workspace (cargo test --workspace)", target.display())
    });
    let package = site.join("densetact");
    std::fs::create_dir_all(&package).unwrap();
    let sources = Path::new(env!("CARGO_MANIFEST_DIR")).join("densetact");
    for entry in std::fs::read_dir(&sources).unwrap() {
        let path = entry.unwrap().path();
        if path.is_file() {
            std::fs::copy(&path, package.join(path.file_name().unwrap())).unwrap();
        }
    }
    std::fs::copy(ext, package.join("_densetact.abi3.so")).unwrap();
}

/// The interpreter the tests run under (`PYTHON`, or `python3`).
fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

/// The interpreter with the package installed under `root/site` first on its path, run from
/// `root`: not from the crate's folder, since `python -m` puts the working folder first on the
/// path, where the package's sources lie without the extension.
fn python_on(root: &Path) -> Command {
    let mut command = Command::new(python());
    command.current_dir(root).env("PYTHONPATH", root.join("site")).env("PYTHONDONTWRITEBYTECODE", "1");
    command
}

/// A simulated capture session of `unit`: full camera frames as PNG, the log, the reference
/// and saw-tooth frames, the true geometry in `.simulation/truth.json`.
fn session(unit: &dataset::SensorUnit, dir: &Path, frames: u32) {
    let kit = dataset::Kit::procedural(unit.sensor.radius_mm as f32);
    let camera = dataset::session::RendererCamera::new(unit, None);
    let params = formats::dataset::GeneratorParams {
        unit: unit.seed,
        test_fraction: 0.3,
        ..formats::dataset::GeneratorParams::new(7, frames, &kit.source)
    };
    let writer = dataset::session::SessionWriter {
        out: dir.to_path_buf(),
        kit: &kit,
        camera: &camera,
        params,
        rig: Default::default(),
        sweep: None,
    };
    writer.run().unwrap();
}

#[test]
#[ignore = "needs python3 with numpy and pytest (pip install numpy pytest): CI installs them"]
fn the_python_package_passes_its_tests() {
    let target = target_dir();
    let infer = target.join("infer");
    assert!(infer.is_file(), "{} is not built: build the workspace (cargo test --workspace)", infer.display());
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    install_package(&target, &root.join("site"));

    let renderer = common::bundle(&root.join("bundle"));
    // The whole predictor as ONNX, as `train onnx` writes it, for ONNX Runtime.
    let device = model::backend::default_device();
    let (net, file) = model::bundle::load_bundle(&root.join("bundle"), &device).unwrap();
    let reference = model::bundle::load_reference(&root.join("bundle"), &file).unwrap();
    let whole = model::onnx::WholePredictor { net: &net, file: &file, reference: reference.as_ref() };
    std::fs::write(root.join("predictor.onnx"), model::onnx::export_whole(&whole).unwrap()).unwrap();
    let unit = renderer.unit().clone();
    session(&unit, &root.join("session"), 8);
    common::dataset_of(&renderer, &root.join("data"), 6, 0.34);

    // A whole JPEG of a frame and one cut short, as a capture program killed mid-write leaves it.
    let log = formats::session::CaptureLog::read(&root.join("session")).unwrap();
    let first = sensor::frame::read(&root.join("session").join(&log.rows[0].frame)).unwrap();
    let jpeg = sensor::frame::encode_jpeg_rgb(&first, 92);
    std::fs::write(root.join("whole.jpg"), &jpeg).unwrap();
    std::fs::write(root.join("cut.jpg"), &jpeg[..jpeg.len() / 3]).unwrap();

    // `infer predict`'s answers: float32 depth (.npy) and the point cloud (.ply).
    let expected = root.join("expected");
    std::fs::create_dir_all(&expected).unwrap();
    let mut cases = Vec::new();
    let frames = log.rows.iter().take(3).map(|r| root.join("session").join(&r.frame));
    for (k, frame) in frames.chain([root.join("whole.jpg")]).enumerate() {
        let (npy, ply) = (expected.join(format!("{k}.npy")), expected.join(format!("{k}.ply")));
        let out = Command::new(&infer)
            .args(["predict", "--bundle", root.join("bundle").to_str().unwrap()])
            .args(["--image", frame.to_str().unwrap(), "--depth-npy", npy.to_str().unwrap()])
            .args(["--ply", ply.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(out.status.success(), "infer predict: {}", String::from_utf8_lossy(&out.stderr));
        cases.push(serde_json::json!({ "frame": frame, "depth_npy": npy, "ply": ply }));
    }
    std::fs::write(root.join("cases.json"), serde_json::to_vec(&cases).unwrap()).unwrap();

    // The package imported is the one installed above (the wheel's, under DENSETACT_WHEEL).
    let out = python_on(root)
        .args(["-c", "import densetact._densetact as m; print(m.__file__)"])
        .output()
        .expect("python3 runs");
    let imported = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(
        out.status.success() && Path::new(&imported).starts_with(root.join("site")),
        "densetact imports from {imported:?}, not the installed package: {}",
        String::from_utf8_lossy(&out.stderr)
    );

    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let out = python_on(root)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", tests.to_str().unwrap()])
        .env("DENSETACT_TEST_DIR", root)
        .output()
        .expect("python3 runs");
    let report = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{report}");
    assert!(out.status.success(), "pytest failed:\n{report}");
}
