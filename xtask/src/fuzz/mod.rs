//! `cargo xtask fuzz`: every parser of outside files fed mutated and truncated real files. Each
//! case must end within a time limit with a valid value or an error that names the file; a
//! panic, a hang, a value that breaks the format's invariants or an anonymous error fails it.
//!
//! The real files are made here by the tools themselves (a dataset, a simulated capture
//! session, a trained bundle and its checkpoint, a point cloud, sensor descriptions) and taken
//! from the calibration kit when it is given (its STL meshes, and the same meshes as OBJ and
//! ASCII STL). The unmutated files must all be accepted, which checks the checks.

mod mutate;
mod resume;
mod targets;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use formats::SplitMix64;

pub use mutate::Shape;
pub use targets::build_targets;

/// What a parser made of one input.
#[derive(Debug)]
pub enum Outcome {
    /// Parsed, and the value holds the format's invariants.
    Accepted,
    /// Refused with this message.
    Refused(String),
    /// Parsed to a value that breaks an invariant (the reason).
    Invalid(String),
}

/// How a target judges one input (`path` names the file to the parser).
pub type Check = Arc<dyn Fn(&Path, &[u8]) -> Outcome + Send + Sync>;

/// A parser to feed: its real files and how to judge what it makes of a file.
pub struct Target {
    pub name: &'static str,
    /// The file name the parser is told (errors must name it).
    pub file: &'static str,
    pub shape: Shape,
    pub seeds: Vec<Vec<u8>>,
    pub check: Check,
}

/// One failed case: enough to replay it (`--target`, `--seed`, `--case`) and the input itself.
#[derive(Debug)]
pub struct Failure {
    pub case: u64,
    pub what: String,
    pub mutations: Vec<String>,
    pub input: Vec<u8>,
}

/// A target's run.
#[derive(Debug, Default)]
pub struct Tally {
    pub cases: u64,
    pub accepted: u64,
    pub refused: u64,
    pub slowest: Duration,
    pub total: Duration,
    pub failures: Vec<Failure>,
}

/// Case `case` of `target` for run seed `seed`: which real file, and the mutated bytes.
pub fn case_input(target: &Target, seed: u64, case: u64) -> (Vec<u8>, Vec<String>) {
    let name_hash =
        target.name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3));
    let mut rng = SplitMix64::for_item(seed ^ name_hash, case);
    let k = rng.below(target.seeds.len());
    let (bytes, mut log) = mutate::mutate(&mut rng, &target.seeds[k], &target.seeds, target.shape);
    log.insert(0, format!("real file {k}"));
    (bytes, log)
}

/// Runs one input through the target's check on a thread of its own, so that a panic is caught
/// and a hang noticed. `Err` is the failure; a hung thread is left behind (it cannot be killed).
fn run_one(target: &Target, input: Vec<u8>, limit: Duration) -> (Result<Outcome, String>, Duration) {
    let (tx, rx) = mpsc::channel();
    let check = target.check.clone();
    let path = PathBuf::from(format!("fuzz/{}", target.file));
    let start = Instant::now();
    let handle = std::thread::Builder::new()
        .name(format!("fuzz-{}", target.name))
        .spawn(move || {
            let outcome = check(&path, &input);
            let _ = tx.send(outcome);
        })
        .expect("a thread for the case");
    let result = match rx.recv_timeout(limit) {
        Ok(outcome) => {
            let _ = handle.join();
            Ok(outcome)
        }
        Err(RecvTimeoutError::Timeout) => Err(format!("no answer within {:.0} s (a loop?)", limit.as_secs_f64())),
        Err(RecvTimeoutError::Disconnected) => {
            let message = match handle.join() {
                Err(payload) => model::backend::panic_message(payload.as_ref()),
                Ok(()) => "the check ended without an answer".into(),
            };
            Err(format!("panicked: {message}"))
        }
    };
    (result, start.elapsed())
}

/// Judges an outcome: accepted, or refused with a message that names the file.
fn judge(target: &Target, outcome: Outcome) -> Result<bool, String> {
    match outcome {
        Outcome::Accepted => Ok(true),
        Outcome::Refused(message) if message.contains(target.file) => Ok(false),
        Outcome::Refused(message) => Err(format!("the error does not name the file: {message}")),
        Outcome::Invalid(why) => Err(format!("accepted a value that breaks the format: {why}")),
    }
}

/// Feeds `target` its real files unmutated (each must be accepted), then cases `cases` of run
/// `seed`. Stops early on a hang, whose thread keeps running.
pub fn run_target(target: &Target, seed: u64, cases: std::ops::Range<u64>, limit: Duration) -> Tally {
    let mut tally = Tally::default();
    for (k, file) in target.seeds.iter().enumerate() {
        let (result, _) = run_one(target, file.clone(), limit);
        let verdict = result.and_then(|outcome| match outcome {
            Outcome::Accepted => Ok(()),
            Outcome::Refused(message) => Err(format!("a real file is refused: {message}")),
            Outcome::Invalid(why) => Err(format!("a real file breaks the format: {why}")),
        });
        if let Err(what) = verdict {
            tally.failures.push(Failure {
                case: u64::MAX,
                what,
                mutations: vec![format!("real file {k}")],
                input: file.clone(),
            });
        }
    }
    for case in cases {
        let (input, mutations) = case_input(target, seed, case);
        let (result, took) = run_one(target, input.clone(), limit);
        tally.cases += 1;
        tally.total += took;
        tally.slowest = tally.slowest.max(took);
        let hung = matches!(&result, Err(w) if w.starts_with("no answer"));
        match result.and_then(|o| judge(target, o)) {
            Ok(true) => tally.accepted += 1,
            Ok(false) => tally.refused += 1,
            Err(what) => tally.failures.push(Failure { case, what, mutations, input }),
        }
        if hung {
            break;
        }
    }
    tally
}

/// Runs every target (two at a time) and returns their tallies in order.
pub fn run_all(targets: &[Target], seed: u64, cases: u64, limit: Duration) -> Vec<Tally> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<std::sync::Mutex<Option<Tally>>> = targets.iter().map(|_| Default::default()).collect();
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get()).min(targets.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(target) = targets.get(k) else { break };
                    let tally = run_target(target, seed, 0..cases, limit);
                    *results[k].lock().expect("no poisoned tally") = Some(tally);
                }
            });
        }
    });
    results.into_iter().map(|m| m.into_inner().expect("no poisoned tally").expect("every target ran")).collect()
}

/// A failure report: target, case, what went wrong, the mutations.
pub fn describe(target: &Target, seed: u64, f: &Failure) -> String {
    let case = if f.case == u64::MAX { "its real file".to_string() } else { format!("case {} of seed {seed}", f.case) };
    format!("{} ({case}): {}; input: {}", target.name, f.what, f.mutations.join(", "))
}

#[derive(clap::Args)]
pub struct Args {
    /// Mutated files per parser.
    #[arg(long, default_value_t = 2000)]
    cases: u64,
    /// Seed of the run (a failure is replayed with the same seed and `--case`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Only the parsers whose name contains this.
    #[arg(long)]
    target: Option<String>,
    /// Replays one case (with `--target`) and prints its outcome.
    #[arg(long)]
    case: Option<u64>,
    /// The calibration kit, for its meshes; without it, procedural meshes stand in.
    #[arg(long, default_value = "../shared/densetact-kit")]
    kit: PathBuf,
    /// Seconds a case may take before it counts as a hang.
    #[arg(long, default_value_t = 10.0)]
    limit_s: f64,
    /// Folder for the inputs of failed cases.
    #[arg(long, default_value = "target/fuzz-failures")]
    save: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let work = tempfile::tempdir().context("a temporary folder for the real files")?;
    let kit = args.kit.is_dir().then_some(args.kit.as_path());
    if kit.is_none() {
        eprintln!("{}: no kit there; procedural meshes stand in for its STL files", args.kit.display());
    }
    let start = Instant::now();
    let mut targets = build_targets(work.path(), kit)?;
    eprintln!("real files made in {:.1} s", start.elapsed().as_secs_f64());
    if let Some(filter) = &args.target {
        targets.retain(|t| t.name.contains(filter.as_str()));
        if targets.is_empty() {
            bail!("no parser's name contains {filter:?}");
        }
    }
    let limit = Duration::from_secs_f64(args.limit_s);
    if let Some(case) = args.case {
        for t in &targets {
            let (input, mutations) = case_input(t, args.seed, case);
            let (result, took) = run_one(t, input, limit);
            println!(
                "{} case {case}: {} -> {result:?} in {:.1} ms",
                t.name,
                mutations.join(", "),
                took.as_secs_f64() * 1e3
            );
        }
        return Ok(());
    }
    let start = Instant::now();
    let tallies = run_all(&targets, args.seed, args.cases, limit);
    println!("| parser | file | cases | accepted | refused | failed | mean ms | slowest ms |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    let mut failed = 0;
    for (t, tally) in targets.iter().zip(&tallies) {
        println!(
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.1} |",
            t.name,
            t.file,
            tally.cases,
            tally.accepted,
            tally.refused,
            tally.failures.len(),
            tally.total.as_secs_f64() * 1e3 / tally.cases.max(1) as f64,
            tally.slowest.as_secs_f64() * 1e3
        );
        for f in &tally.failures {
            failed += 1;
            eprintln!("FAILED {}", describe(t, args.seed, f));
            let file = args.save.join(format!("{}-{}-{}", t.name, args.seed, f.case));
            std::fs::create_dir_all(&args.save).with_context(|| args.save.display().to_string())?;
            formats::fs::write_atomic(&file, &f.input)?;
        }
    }
    println!("seed {}, {} cases per parser, {:.0} s", args.seed, args.cases, start.elapsed().as_secs_f64());
    if failed > 0 {
        bail!("{failed} case(s) failed; inputs saved in {}", args.save.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixed cases CI runs: every parser, its real files and 150 mutations of them.
    fn fuzz(kit: Option<&Path>, only_meshes: bool) {
        let work = tempfile::tempdir().unwrap();
        let mut targets = build_targets(work.path(), kit).unwrap();
        targets.retain(|t| t.name.starts_with("mesh") == only_meshes);
        assert!(!targets.is_empty());
        let tallies = run_all(&targets, 1, 150, Duration::from_secs(20));
        let failures: Vec<String> = targets
            .iter()
            .zip(&tallies)
            .flat_map(|(t, tally)| tally.failures.iter().map(move |f| describe(t, 1, f)))
            .collect();
        assert!(failures.is_empty(), "{} failure(s):\n{}", failures.len(), failures.join("\n"));
        for (t, tally) in targets.iter().zip(&tallies) {
            // Both answers happen: the mutations reach past the first check, and they break files.
            assert!(tally.refused > 0, "{}: no mutated file was refused", t.name);
            assert_eq!(tally.cases, 150, "{}", t.name);
        }
    }

    #[test]
    fn every_parser_survives_mutated_real_files() {
        fuzz(None, false);
    }

    #[test]
    fn procedural_meshes_survive_mutation() {
        fuzz(None, true);
    }

    #[test]
    #[ignore = "needs ../shared"]
    fn the_kits_meshes_survive_mutation() {
        fuzz(Some(&sensor::shared::shared_dir("DENSETACT_KIT", "densetact-kit")), true);
    }

    #[test]
    fn a_panic_a_hang_and_an_anonymous_error_are_failures() {
        let target = |check: Check| Target {
            name: "probe",
            file: "probe.bin",
            shape: Shape::Binary,
            seeds: vec![b"1234".to_vec()],
            check,
        };
        // Generous for the panics (printing a backtrace can take a second on a loaded machine),
        // short for the hang.
        let limit = Duration::from_secs(20);
        let panics =
            target(Arc::new(|_: &Path, b: &[u8]| if b == b"1234" { Outcome::Accepted } else { panic!("boom") }));
        let t = run_target(&panics, 0, 0..3, limit);
        assert_eq!(t.failures.len(), 3);
        assert!(t.failures[0].what.contains("panicked: boom"), "{:?}", t.failures[0]);
        // The real file answers at once, but on a loaded machine a thread can take a while to
        // start: three seconds for it, and a hang far longer than that.
        let hangs = target(Arc::new(|_: &Path, b: &[u8]| {
            if b != b"1234" {
                std::thread::sleep(Duration::from_secs(60));
            }
            Outcome::Accepted
        }));
        let t = run_target(&hangs, 0, 0..3, Duration::from_secs(3));
        assert_eq!((t.failures.len(), t.cases), (1, 1), "a hang stops the target");
        assert!(t.failures[0].what.contains("no answer"));
        let anonymous = target(Arc::new(|p: &Path, b: &[u8]| {
            if b == b"1234" {
                Outcome::Refused(format!("{}: fine", p.display()))
            } else {
                Outcome::Refused("bad".into())
            }
        }));
        let t = run_target(&anonymous, 0, 0..2, limit);
        assert_eq!(t.failures.len(), 3, "the real file refused, then two anonymous errors: {:?}", t.failures);
    }
}
