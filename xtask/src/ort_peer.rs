//! ONNX Runtime as a peer process that times one forward at a time on request, so that a
//! benchmark can alternate its runs with flex's: on a shared machine whose speed drifts by
//! tens of percent over a minute, two sides timed one after the other compare two machines.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use anyhow::{Context, Result, bail};
use formats::stats::Summary;

/// `peers/onnx_runtime.py`, running.
pub struct OrtPeer {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    /// ONNX Runtime's version, as the peer reports it.
    pub version: String,
}

impl OrtPeer {
    /// Starts the peer on `model` (an ONNX file) for inputs of `channels` x `hw` with `threads`,
    /// its workers spinning after each run (ONNX Runtime's default) or not.
    pub fn start(
        python: &str,
        model: &str,
        channels: usize,
        [h, w]: [usize; 2],
        threads: usize,
        spin: bool,
    ) -> Result<Self> {
        let script = crate::peer::script("onnx_runtime.py");
        let [c, h, w, t] = [channels, h, w, threads].map(|v| v.to_string());
        let mut child = Command::new(python)
            .arg(&script)
            .args(["--model", model, "--channels", &c, "--height", &h, "--width", &w])
            .args(["--threads", &t])
            .args((!spin).then_some("--no-spin"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("running {python} {script}"))?;
        let (stdin, stdout) = (child.stdin.take().expect("piped"), child.stdout.take().expect("piped"));
        let mut peer = OrtPeer { child, stdin, stdout: BufReader::new(stdout), version: String::new() };
        let ready = peer.line()?;
        let Some(version) = ready.strip_prefix("ready version=") else {
            bail!("peer {script} did not start: {ready:?}");
        };
        peer.version = version.to_string();
        Ok(peer)
    }

    fn line(&mut self) -> Result<String> {
        let mut line = String::new();
        if self.stdout.read_line(&mut line)? == 0 {
            let status = self.child.wait()?;
            bail!("the ONNX Runtime peer ended ({status}); its errors are above");
        }
        Ok(line.trim().to_string())
    }

    /// One forward of a batch of `batch` images (the peer warms up on the first request of
    /// each batch size).
    pub fn forward(&mut self, batch: usize) -> Result<Frame> {
        writeln!(self.stdin, "{batch}")?;
        self.stdin.flush()?;
        let line = self.line()?;
        let field = |key| crate::peer::field(&line, key);
        match (field("forward_ms="), field("cpu_ms=")) {
            (Some(ms), Some(cpu_ms)) => Ok(Frame { ms, cpu_ms }),
            _ => bail!("the ONNX Runtime peer answered {line:?}"),
        }
    }

    /// ONNX Runtime's depth output for `images` (`batch` of them, [channels, height, width]
    /// each, row-major), passed through files in `dir`: the other side of the benchmark's error
    /// figure.
    pub fn depth(&mut self, dir: &Path, batch: usize, images: &[f32]) -> Result<Vec<f32>> {
        let path = dir.join(format!("ort_input_{batch}.f32"));
        std::fs::write(&path, images.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>())
            .with_context(|| format!("writing {}", path.display()))?;
        writeln!(self.stdin, "depth {batch} {}", path.display())?;
        self.stdin.flush()?;
        let line = self.line()?;
        if line != "depth written" {
            bail!("the ONNX Runtime peer answered {line:?} to a depth request");
        }
        // Where the peer writes it: the input's path with `.out` appended.
        let out = std::path::PathBuf::from(format!("{}.out", path.display()));
        let bytes = std::fs::read(&out).with_context(|| format!("reading {}", out.display()))?;
        Ok(bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
    }
}

/// How far `ours` is from `peer`'s values: the largest absolute difference, and that over the
/// largest absolute value of `peer` (an untrained network's outputs have no natural scale).
/// A length mismatch or a non-finite value is an error, not a figure.
pub fn difference(ours: &[f32], peer: &[f32]) -> Result<(f32, f32)> {
    if ours.len() != peer.len() {
        bail!("outputs of {} and {} values", ours.len(), peer.len());
    }
    if let Some(i) = ours.iter().chain(peer).position(|v| !v.is_finite()) {
        bail!("a non-finite output value (at {i} of both outputs laid end to end)");
    }
    let largest = ours.iter().zip(peer).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    let scale = peer.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
    Ok((largest, if scale > 0.0 { largest / scale } else { largest }))
}

impl Drop for OrtPeer {
    fn drop(&mut self) {
        // Its loop would end when its input closes; the benchmark is done with it either way.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One timed forward: its wall time, and its process's CPU time since the same side's previous
/// forward ended (the gap before it, where polling workers spend theirs, and the forward).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub ms: f64,
    pub cpu_ms: f64,
}

/// Both sides' times, one pair per repetition, and the ratio of each pair.
pub struct Interleaved {
    pub ours: Summary,
    pub peer: Summary,
    /// `ours / peer` of each repetition's pair.
    pub ratio: Summary,
    /// Each side's CPU milliseconds per timed frame.
    pub ours_cpu: Summary,
    pub peer_cpu: Summary,
}

/// How the two sides' forwards are spaced.
#[derive(Clone, Copy, Debug)]
pub struct Pacing {
    /// Between a side's untimed forward and its timed one: a camera's frame gap.
    pub gap: std::time::Duration,
    /// Idle before each side's turn, longer than either side's workers poll for work after a
    /// run (ONNX Runtime's spin about 60 ms by default; ours `model::backend::set_spin`'s
    /// window), so that neither side's polling takes a core from the other's run.
    pub settle: std::time::Duration,
}

impl Pacing {
    /// Frames `gap` apart, the sides apart by 100 ms more than our polling `spin` and at least
    /// 200 ms.
    pub fn new(gap: std::time::Duration, spin: std::time::Duration) -> Self {
        let settle = (spin + std::time::Duration::from_millis(100)).max(std::time::Duration::from_millis(200));
        Pacing { gap, settle }
    }
}

/// `reps` pairs of timed forwards, `ours` and `peer` alternating which goes first so neither
/// always runs on the other's heels. Each side's turn: idle `pacing.settle`, one untimed
/// forward (the frame before), idle `pacing.gap`, the timed forward.
pub fn interleave(
    reps: usize,
    pacing: Pacing,
    mut ours: impl FnMut() -> Frame,
    mut peer: impl FnMut() -> Result<Frame>,
) -> Result<Interleaved> {
    let turn = |side: &mut dyn FnMut() -> Result<Frame>| -> Result<Frame> {
        std::thread::sleep(pacing.settle);
        side()?;
        std::thread::sleep(pacing.gap);
        side()
    };
    let mut ours = || Ok(ours());
    let mut pairs = Vec::with_capacity(reps);
    for rep in 0..reps {
        let pair = if rep % 2 == 0 {
            let a = turn(&mut ours)?;
            (a, turn(&mut peer)?)
        } else {
            let b = turn(&mut peer)?;
            (turn(&mut ours)?, b)
        };
        pairs.push(pair);
    }
    Ok(summarise(&pairs))
}

fn summarise(pairs: &[(Frame, Frame)]) -> Interleaved {
    let of = |f: &dyn Fn(&(Frame, Frame)) -> f64| Summary::of(pairs.iter().map(f).collect::<Vec<_>>());
    Interleaved {
        ours: of(&|p| p.0.ms),
        peer: of(&|p| p.1.ms),
        ratio: of(&|p| p.0.ms / p.1.ms),
        ours_cpu: of(&|p| p.0.cpu_ms),
        peer_cpu: of(&|p| p.1.cpu_ms),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pair_is_compared_within_itself() {
        // The machine halves its speed half way: each pair still reads 0.5.
        let frame = |ms| Frame { ms, cpu_ms: 2.0 * ms };
        let pairs = [(10.0, 20.0), (11.0, 22.0), (20.0, 40.0), (22.0, 44.0)].map(|(a, b)| (frame(a), frame(b)));
        let i = summarise(&pairs);
        assert_eq!((i.ours_cpu.median, i.peer_cpu.median), (31.0, 62.0));
        assert_eq!((i.ratio.q1, i.ratio.median, i.ratio.q3), (0.5, 0.5, 0.5));
        assert_eq!(i.ours.median, 15.5);
        assert_eq!(i.peer.median, 31.0);
    }

    #[test]
    fn a_difference_is_measured_against_the_peers_scale_and_refuses_what_it_cannot_measure() {
        let (abs, rel) = difference(&[1.0, -2.0, 3.5], &[1.0, -2.5, 4.0]).unwrap();
        assert_eq!((abs, rel), (0.5, 0.125));
        assert_eq!(difference(&[0.0], &[0.0]).unwrap(), (0.0, 0.0));
        assert!(difference(&[1.0], &[1.0, 2.0]).is_err());
        assert!(difference(&[f32::NAN], &[1.0]).is_err());
        assert!(difference(&[1.0], &[f32::INFINITY]).is_err());
    }

    /// Whether the tests must find ONNX Runtime (CI says so through `DENSETACT_REQUIRE`, as
    /// for the Python package's tests), or may go without where it is not installed.
    fn onnxruntime_or_skip() -> bool {
        let here =
            Command::new("python3").args(["-c", "import onnxruntime, numpy"]).status().is_ok_and(|s| s.success());
        let required = std::env::var("DENSETACT_REQUIRE").is_ok_and(|r| r.split(',').any(|p| p == "onnxruntime"));
        assert!(here || !required, "DENSETACT_REQUIRE names onnxruntime, which python3 cannot import");
        if !here {
            eprintln!("skipped: python3 has no onnxruntime");
        }
        here
    }

    #[test]
    fn the_peer_runs_the_exported_network_to_flexs_output_and_times_it() {
        use burn::tensor::{Distribution, Tensor};
        if !onnxruntime_or_skip() {
            return;
        }
        let device = model::backend::default_device();
        let config = model::DenseDepthConfig::new(model::Preset::Tiny.config());
        let (channels, hw) = (config.input.count(), [32, 48]);
        let untrained = config.init(&device);
        let net = untrained.clone().folded();
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("tiny.onnx");
        let bundle = crate::bench_model::model_bundle_file(&config, hw);
        std::fs::write(&file, model::onnx::export(&untrained, &bundle).unwrap()).unwrap();
        let start = |spin| OrtPeer::start("python3", file.to_str().unwrap(), channels, hw, 1, spin).unwrap();
        let timed = |peer: &mut OrtPeer| {
            let frame = peer.forward(2).unwrap();
            assert!(frame.ms > 0.0 && frame.cpu_ms > 0.0, "{frame:?}");
        };
        timed(&mut start(false));
        // The spinning one (ONNX Runtime's default) serves the rest of the test.
        let mut peer = start(true);
        timed(&mut peer);
        assert!(!peer.version.is_empty());
        let images = Tensor::<4>::random([2, channels, hw[0], hw[1]], Distribution::Uniform(0.0, 1.0), &device);
        let ours = net.forward(images.clone()).into_data().try_into_vec::<f32>().unwrap();
        let theirs = peer.depth(dir.path(), 2, &images.into_data().try_into_vec::<f32>().unwrap()).unwrap();
        let (abs, rel) = difference(&ours, &theirs).unwrap();
        assert!(rel < 1e-4, "flex and ONNX Runtime differ by {abs} ({rel} of the output's scale)");
        // A file that cannot be written is an error naming it; so is a request the peer cannot
        // serve (three values are no batch of two images), which ends it.
        let err = peer.depth(&dir.path().join("missing"), 2, &[0.0; 3]).unwrap_err();
        assert!(format!("{err:#}").contains("missing"), "{err:#}");
        let err = peer.depth(dir.path(), 2, &[0.0; 3]).unwrap_err();
        assert!(format!("{err:#}").contains("ONNX Runtime peer"), "{err:#}");
    }

    #[test]
    fn each_timed_forward_follows_an_untimed_one_and_the_order_alternates() {
        let log = std::cell::RefCell::new(Vec::new());
        let ms = std::time::Duration::from_millis;
        let pacing = Pacing { gap: ms(4), settle: ms(6) };
        let started = std::time::Instant::now();
        let i = interleave(
            3,
            pacing,
            || {
                log.borrow_mut().push('o');
                Frame { ms: 1.0, cpu_ms: 3.0 }
            },
            || {
                log.borrow_mut().push('p');
                Ok(Frame { ms: 4.0, cpu_ms: 5.0 })
            },
        )
        .unwrap();
        assert_eq!(log.into_inner().into_iter().collect::<String>(), "ooppppoooopp");
        assert_eq!((i.ratio.median, i.ours_cpu.median, i.peer_cpu.median), (0.25, 3.0, 5.0));
        // Six turns, each idle for the settle and the gap.
        assert!(started.elapsed() >= 6 * (pacing.gap + pacing.settle));
        // The settle outlasts our polling and ONNX Runtime's (60 ms).
        assert_eq!(Pacing::new(ms(50), ms(0)).settle, ms(200));
        assert_eq!(Pacing::new(ms(33), ms(150)).settle, ms(250));
    }
}
