//! Where a stream's results go.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use super::{FrameResult, StreamReport};
use crate::Predictor;
use crate::cloud::ply_bytes;

/// Takes each frame's results; an error stops the stream.
pub trait Sink {
    fn frame(&mut self, predictor: &Predictor, result: &FrameResult) -> Result<(), SinkError>;

    /// A line for the end of the stream, if the sink has something to say.
    fn summary(&self) -> Option<String> {
        None
    }
}

/// Why a sink cannot take a frame (or cannot start).
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// A file could not be written: a full disk, permissions.
    #[error(transparent)]
    Write(#[from] formats::FsError),
    /// ROS 2's middleware refused a step (`what`).
    #[error("ROS 2: cannot {what}: {detail}")]
    Ros2 { what: &'static str, detail: String },
    /// The live view failed (a viewer gone, a recording's disk full).
    #[cfg(feature = "view")]
    #[error(transparent)]
    View(#[from] view::ViewError),
}

/// Per frame: `depth/NAME.png` (16-bit, micrometres, as `predict --depth-out`) and, for a frame
/// with contact, `cloud/NAME.ply` (contact patch, sensor frame, mm) and, from a bundle with the
/// force output, `pressure/NAME.png` (as `predict --pressure-out`); at the end `stream.json`
/// and `frames.csv` (with each frame's force). Every file is written whole or not at all.
pub struct FolderSink {
    out: PathBuf,
    /// Names used so far: frames of the same file name from two folders do not overwrite.
    used: HashSet<String>,
    /// Held while streaming: a second stream into the same folder is refused.
    _claim: formats::output::Claim,
}

impl FolderSink {
    /// `out` must have been checked against the inputs (`formats::output::check_dir`); it is
    /// claimed (created, marked and held) here.
    pub fn new(out: &Path) -> Result<Self, formats::output::OutputError> {
        let claim = formats::output::claim_dir(out, formats::output::OutputKind::Stream, &[])?;
        let failed = |path: PathBuf, e: std::io::Error| formats::output::OutputError { path, why: e.to_string() };
        // An earlier stream's results go: the folder holds this stream's alone.
        for file in ["stream.json", "frames.csv"] {
            match std::fs::remove_file(out.join(file)) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(failed(out.join(file), e)),
                _ => {}
            }
        }
        for sub in ["depth", "cloud", "pressure"] {
            let dir = out.join(sub);
            match std::fs::remove_dir_all(&dir) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(failed(dir, e)),
                _ => {}
            }
            std::fs::create_dir_all(&dir).map_err(|e| failed(dir.clone(), e))?;
        }
        Ok(FolderSink { out: out.to_path_buf(), used: HashSet::new(), _claim: claim })
    }

    /// The output name of a frame: its file's stem, made unique within the stream.
    fn name_for(&mut self, frame: &str) -> String {
        let stem = Path::new(frame).file_stem().map_or_else(|| "frame".into(), |s| s.to_string_lossy().into_owned());
        let mut name = stem.clone();
        let mut k = 1;
        while !self.used.insert(name.clone()) {
            k += 1;
            name = format!("{stem}-{k}");
        }
        name
    }

    /// Writes the summary and the per-frame records.
    pub fn finish(&self, report: &StreamReport) -> Result<(), formats::FsError> {
        let json = serde_json::to_vec_pretty(report).expect("report serialises");
        let csv = report.frames_csv();
        formats::fs::write_files_atomic(&[(&self.out.join("stream.json"), &json), (&self.out.join("frames.csv"), &csv)])
    }
}

impl Sink for FolderSink {
    fn frame(&mut self, _predictor: &Predictor, result: &FrameResult) -> Result<(), SinkError> {
        let name = self.name_for(result.name);
        // Unsynced: a frame's files are replaced whole, and a sync each would cost more than
        // the network at camera rate.
        let write = |path: PathBuf, bytes: &[u8]| formats::fs::write_atomic_unsynced(&path, bytes);
        write(self.out.join("depth").join(format!("{name}.png")), &result.depth.to_png_um())?;
        if result.contact_pixels > 0 {
            write(self.out.join("cloud").join(format!("{name}.ply")), &ply_bytes(result.cloud))?;
            if let Some(force) = result.force {
                write(self.out.join("pressure").join(format!("{name}.png")), &force.pressure.to_png())?;
            }
        }
        Ok(())
    }
}
