//! Project automation: `cargo xtask quickstart` (the README's main command) and the benchmarks
//! (`cargo xtask bench ...`).

#![deny(unsafe_code)]

mod bench_calibrate;
mod bench_drift;
mod bench_finetune;
mod bench_force;
mod bench_foreign;
mod bench_icp_index;
mod bench_loader;
mod bench_looks;
mod bench_model;
mod bench_raycast;
mod bench_register;
mod bench_render;
mod bench_table;
mod fuzz;
mod ort_peer;
mod peer;
mod quickstart;
mod timing;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "xtask", about = "DenseTact project automation")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Benchmarks (results go to stdout; copy them into BENCHMARKS.md with the command).
    Bench {
        #[command(subcommand)]
        what: Bench,
    },
    /// Every parser of outside files fed mutated and truncated real files: errors or valid
    /// values, never a panic or a hang.
    Fuzz(fuzz::Args),
    /// The whole pipeline on the embedded kit: dataset, training, bundle, evaluation, examples.
    Quickstart(quickstart::Args),
}

#[derive(Subcommand)]
enum Bench {
    /// Ray-cast ground truth: rays/s and ms per scene, with and without skipping, vs Open3D.
    Raycast(bench_raycast::Args),
    /// DenseDepth forward and train step on the CPU, vs PyTorch.
    Model(bench_model::Args),
    /// Simulated unit images: time per stage of a sample; saw-tooth calibration time and error.
    Render(bench_render::Args),
    /// Saw-tooth calibration over many units of the project's renderer or of the independent
    /// image model: calibrated, refused (why), error against the truth and the stated bound.
    Calibrate(bench_calibrate::Args),
    /// The README's real-sensor commands on a session filmed by the independent image model,
    /// beside the same scenes through the project's renderer.
    Foreign(bench_foreign::Args),
    /// Registration from the frames: simulated sweep sessions with a rig's errors, filmed by the
    /// renderer and by `gelcam`, labelled with and without `--register` against the truth.
    Register(bench_register::Args),
    /// Run time against error: every preset and input size, same training budget, each backend;
    /// writes its section of BENCHMARKS.md and an SVG scatter.
    Table(bench_table::Args),
    /// Fine-tuning a unit-A model for unit B with 5/10/25 % of B's data, vs training on all of B.
    Finetune(bench_finetune::Args),
    /// Training on random looks against the unit's own look, read zero-shot by cameras no run
    /// trained on (the independent image model).
    Looks(bench_looks::Args),
    /// ICP's nearest-neighbour index against kiddo's k-d tree on the pinch example's clouds:
    /// build and query time, and whether every answer is the same.
    IcpIndex(bench_icp_index::Args),
    /// Data loading against the train step: decoded samples/s beside train-step samples/s.
    Loader(bench_loader::Args),
    /// A camera drifting for twenty minutes: untouched frames gated, false contacts, contact
    /// L1, with the gate before and after its drift balance and with a following reference.
    Drift(bench_drift::Args),
    /// The elastomer's contact model: Hertz and Boussinesq against the model on two grids, and
    /// the force labels' cost and grid convergence on the kit's scenes.
    Force(bench_force::Args),
}

fn main() -> ExitCode {
    model::backend::cpu_unless_asked();
    sensor::alloc::keep_freed_memory();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bench { what: Bench::Raycast(args) } => bench_raycast::run(args),
        Command::Bench { what: Bench::Model(args) } => bench_model::run(args),
        Command::Bench { what: Bench::Render(args) } => bench_render::run(args),
        Command::Bench { what: Bench::Calibrate(args) } => bench_calibrate::run(args),
        Command::Bench { what: Bench::Foreign(args) } => bench_foreign::run(args),
        Command::Bench { what: Bench::Register(args) } => bench_register::run(args),
        Command::Bench { what: Bench::Finetune(args) } => bench_finetune::run(args),
        Command::Bench { what: Bench::Drift(args) } => bench_drift::run(args),
        Command::Bench { what: Bench::Force(args) } => bench_force::run(args),
        Command::Bench { what: Bench::IcpIndex(args) } => bench_icp_index::run(args),
        Command::Bench { what: Bench::Loader(args) } => bench_loader::run(args),
        Command::Bench { what: Bench::Looks(args) } => bench_looks::run(args),
        Command::Bench { what: Bench::Table(args) } => bench_table::run(args),
        Command::Quickstart(args) => quickstart::run(args),
        Command::Fuzz(args) => fuzz::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
