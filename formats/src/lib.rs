//! The on-disk contracts that several of the project's crates read and write, kept light so
//! that training and inference need none of the generator's dependencies:
//!
//! - [`dataset`]: the dataset folder's manifest, sample records and splits;
//! - [`training`]: what a bundle records of its training;
//! - [`session`]: a capture session's log (`captures.csv`) as a lab writes it;
//! - [`fs`]: atomic file and folder writes (a reader never sees half a file);
//! - [`output`]: which folders and files a command may write (never its inputs, never what
//!   another tool left);
//! - [`json`]: JSON files that name themselves in every error;
//! - [`names`]: names that must be one of a known list;
//! - [`rng`]: the seeded random streams that fix a dataset's content and a run's data order;
//! - [`progress`]: what long jobs show while they run;
//! - [`stats`]: the one quantile rule of every reported figure.

#![deny(unsafe_code)]

pub mod dataset;
pub mod fs;
pub mod json;
pub mod names;
pub mod output;
pub mod progress;
pub mod rng;
pub mod session;
pub mod shard;
pub mod stats;
pub mod training;

pub use dataset::{Manifest, SampleRecord, Split};
pub use fs::FsError;
pub use json::{FormatError, read_json, write_json};
pub use names::{UnknownName, find_by_name};
pub use progress::Progress;
pub use rng::SplitMix64;
pub use shard::Shard;
