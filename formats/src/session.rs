//! A capture session: what a lab brings from its rig, and what `dataset label` reads.
//!
//! ```text
//! SESSION/captures.csv        one row per camera frame: frame,split,trial,a_deg,b_deg,c_deg,z_mm
//!                             (header names in any order and case; further columns are kept)
//! SESSION/<frame paths>       the frames the rows name, relative to SESSION (PNG or JPEG, the
//!                             camera's full frame or the sensor's crop)
//! SESSION/reference.png|.jpg  a frame with nothing touching the sensor
//! ```
//!
//! `split` is `train` or `test`: which index of the kit the trial comes from (the kit's train
//! and test trials share no indicator-indenter combination); `trial` is the trial's number in
//! that index. The pose is the rig's: A and C tilts, B turn (degrees) and z travel (mm), as
//! [`RigPose`] defines them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::dataset::{RigPose, Split};

/// The log's file name in a session folder.
pub const CAPTURES_CSV: &str = "captures.csv";

/// The columns every log must have, in the order a written log puts them.
pub const REQUIRED_COLUMNS: [&str; 7] = ["frame", "split", "trial", "a_deg", "b_deg", "c_deg", "z_mm"];

/// The optional columns of a force-torque sensor under the indenter: the force (N) and torque
/// (N mm) the contact applies to the sensor, in the sensor frame (z along the dome's axis, out
/// of the dome; torque about the dome's centre). All six or none; a row may leave all six empty.
pub const WRENCH_COLUMNS: [&str; 6] = ["fx_n", "fy_n", "fz_n", "tx_nmm", "ty_nmm", "tz_nmm"];

/// One row of `captures.csv`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Capture {
    /// Line of the row in the file (1-based; the header is line 1).
    pub line: usize,
    /// The frame's path relative to the session folder, as written.
    pub frame: String,
    pub split: Split,
    pub trial: u32,
    pub pose: RigPose,
    /// The row's other columns, by header name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub extra: BTreeMap<String, String>,
    /// The wrench a force-torque sensor measured for this frame ([`WRENCH_COLUMNS`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured: Option<crate::dataset::Wrench>,
}

/// A problem with the log: the file, the line and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: line {line}: {message}")]
    Row { path: PathBuf, line: usize, message: String },
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
}

impl SessionError {
    /// The line of the row it names, if it names one.
    pub fn line(&self) -> Option<usize> {
        match self {
            SessionError::Row { line, .. } => Some(*line),
            _ => None,
        }
    }
}

/// A parsed log: the rows that parse, and the ones that do not (each with its line), so that a
/// caller can stop at the first or skip them and say which.
#[derive(Debug)]
pub struct CaptureLog {
    pub path: PathBuf,
    pub rows: Vec<Capture>,
    pub bad: Vec<SessionError>,
}

impl CaptureLog {
    /// Reads `SESSION/captures.csv`. Errors of the file as a whole (missing, unreadable, no
    /// header, a required column absent) are returned; errors of single rows are collected in
    /// `bad`. A frame named twice is a bad row (the second time).
    pub fn read(session: &Path) -> Result<CaptureLog, SessionError> {
        let path = session.join(CAPTURES_CSV);
        let text = std::fs::read(&path).map_err(|source| SessionError::Io { path: path.clone(), source })?;
        Self::parse(&path, &text)
    }

    /// Parses the log's bytes (`path` names it in errors).
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<CaptureLog, SessionError> {
        let file = |message: String| SessionError::File { path: path.to_path_buf(), message };
        let mut reader =
            csv::ReaderBuilder::new().has_headers(true).flexible(true).trim(csv::Trim::All).from_reader(bytes);
        let headers: Vec<String> = reader
            .headers()
            .map_err(|e| file(format!("cannot read the header line: {e}")))?
            .iter()
            .map(|h| h.trim_start_matches('\u{feff}').to_ascii_lowercase())
            .collect();
        let mut column = BTreeMap::new();
        for (k, h) in headers.iter().enumerate() {
            if h.is_empty() {
                continue;
            }
            if column.insert(h.clone(), k).is_some() {
                return Err(file(format!("column {h:?} appears twice in the header")));
            }
        }
        let missing: Vec<&str> = REQUIRED_COLUMNS.iter().copied().filter(|c| !column.contains_key(*c)).collect();
        if !missing.is_empty() {
            return Err(file(format!(
                "the header lacks column(s) {}; a capture log needs {}",
                missing.join(", "),
                REQUIRED_COLUMNS.join(",")
            )));
        }
        let wrench_columns = WRENCH_COLUMNS.iter().filter(|c| column.contains_key(**c)).count();
        if wrench_columns > 0 && wrench_columns < WRENCH_COLUMNS.len() {
            let missing: Vec<&str> = WRENCH_COLUMNS.iter().copied().filter(|c| !column.contains_key(*c)).collect();
            return Err(file(format!(
                "the header has some force-torque columns but lacks {}; a measured wrench needs all of {}",
                missing.join(", "),
                WRENCH_COLUMNS.join(",")
            )));
        }
        let mut log = CaptureLog { path: path.to_path_buf(), rows: Vec::new(), bad: Vec::new() };
        let mut seen = BTreeMap::<String, usize>::new();
        let mut lines = LineCounter { bytes, at: 0, line: 1 };
        for record in reader.records() {
            let record = match record {
                Ok(r) => r,
                Err(e) => {
                    let line = e.position().map_or(0, |p| lines.line_at(p.byte() as usize));
                    log.bad.push(SessionError::Row { path: path.to_path_buf(), line, message: e.to_string() });
                    continue;
                }
            };
            let line = record.position().map_or(0, |p| lines.line_at(p.byte() as usize));
            if record.iter().all(str::is_empty) {
                continue;
            }
            let row = |message: String| SessionError::Row { path: path.to_path_buf(), line, message };
            let get = |name: &str| record.get(column[name]).unwrap_or("");
            let parsed = (|| {
                let written = get("frame");
                if written.is_empty() {
                    return Err(row("the frame column is empty".into()));
                }
                let frame = inside_session(written).map_err(row)?;
                let split: Split = get("split").parse().map_err(|e: crate::UnknownName| row(e.to_string()))?;
                let trial: u32 = get("trial")
                    .parse()
                    .map_err(|_| row(format!("trial must be a whole number, got {:?}", get("trial"))))?;
                let number = |name: &str| -> Result<f32, SessionError> {
                    let v: f32 =
                        get(name).parse().map_err(|_| row(format!("{name} must be a number, got {:?}", get(name))))?;
                    // As written: "1e308" overflows f32 to infinity, which the file never said.
                    if v.is_finite() {
                        Ok(v)
                    } else {
                        Err(row(format!("{name} must be a finite number, got {:?}", get(name))))
                    }
                };
                let pose = RigPose {
                    a_axis_deg: number("a_deg")?,
                    b_axis_deg: number("b_deg")?,
                    c_axis_deg: number("c_deg")?,
                    z_travel_mm: number("z_mm")?,
                };
                let measured = match wrench_columns {
                    0 => None,
                    _ if WRENCH_COLUMNS.iter().all(|c| get(c).is_empty()) => None,
                    _ => {
                        let v = WRENCH_COLUMNS.map(|name| number(name).map(f64::from));
                        let [fx, fy, fz, tx, ty, tz] = v;
                        Some(crate::dataset::Wrench { force_n: [fx?, fy?, fz?], torque_nmm: [tx?, ty?, tz?] })
                    }
                };
                let extra = column
                    .iter()
                    .filter(|(name, _)| {
                        !REQUIRED_COLUMNS.contains(&name.as_str()) && !WRENCH_COLUMNS.contains(&name.as_str())
                    })
                    .map(|(name, &k)| (name.clone(), record.get(k).unwrap_or("").to_string()))
                    .collect();
                if let Some(first) = seen.get(&frame) {
                    return Err(row(format!("frame {frame:?} is already listed on line {first}")));
                }
                Ok(Capture { line, frame, split, trial, pose, extra, measured })
            })();
            match parsed {
                Ok(c) => {
                    seen.insert(c.frame.clone(), line);
                    log.rows.push(c);
                }
                Err(e) => log.bad.push(e),
            }
        }
        if log.rows.is_empty() && log.bad.is_empty() {
            return Err(file("the log lists no frames".into()));
        }
        Ok(log)
    }

    /// The log as CSV text: the required columns, the force-torque columns where a row has a
    /// measured wrench, then the extra columns of the first row.
    pub fn to_csv(rows: &[Capture]) -> String {
        let extra: Vec<&String> = rows.first().map(|r| r.extra.keys().collect()).unwrap_or_default();
        let wrenches = rows.iter().any(|r| r.measured.is_some());
        let mut writer = csv::Writer::from_writer(Vec::new());
        let wrench_header = WRENCH_COLUMNS.iter().copied().filter(|_| wrenches);
        let header: Vec<&str> =
            REQUIRED_COLUMNS.iter().copied().chain(wrench_header).chain(extra.iter().map(|s| s.as_str())).collect();
        writer.write_record(&header).expect("in-memory CSV");
        for r in rows {
            let p = r.pose;
            let mut fields = vec![
                r.frame.clone(),
                r.split.to_string(),
                r.trial.to_string(),
                p.a_axis_deg.to_string(),
                p.b_axis_deg.to_string(),
                p.c_axis_deg.to_string(),
                p.z_travel_mm.to_string(),
            ];
            if wrenches {
                match &r.measured {
                    Some(w) => fields.extend(w.force_n.iter().chain(&w.torque_nmm).map(f64::to_string)),
                    None => fields.extend(std::iter::repeat_n(String::new(), WRENCH_COLUMNS.len())),
                }
            }
            fields.extend(extra.iter().map(|k| r.extra.get(*k).cloned().unwrap_or_default()));
            writer.write_record(&fields).expect("in-memory CSV");
        }
        String::from_utf8(writer.into_inner().expect("in-memory CSV")).expect("CSV of UTF-8 fields")
    }
}

/// A frame's path as the log writes it, made canonical within the session folder: `.` and `..`
/// resolved, so that one frame named two ways is found twice; a path that is absolute or leads
/// out of the session is refused (a session is moved and archived as one folder).
fn inside_session(written: &str) -> Result<String, String> {
    use std::path::Component;
    let path = Path::new(written);
    let mut parts: Vec<&std::ffi::OsStr> = Vec::new();
    for part in path.components() {
        match part {
            Component::Normal(p) => parts.push(p),
            Component::CurDir => {}
            Component::ParentDir if parts.pop().is_some() => {}
            Component::ParentDir | Component::RootDir | Component::Prefix(_) => {
                return Err(format!(
                    "frame {written:?} lies outside the session folder; frames are named relative to it, inside it"
                ));
            }
        }
    }
    if parts.is_empty() {
        return Err(format!("frame {written:?} names no file"));
    }
    let joined: PathBuf = parts.iter().collect();
    Ok(joined.to_string_lossy().into_owned())
}

/// Line numbers of byte offsets, counted forward as records are read. The CSV reader's own
/// count is one short after a CRLF line end (a record then starts at the `\n` that the `\r`
/// left) and misses lone `\r` line ends, so the record's first byte that is not a line end is
/// what counts, and every kind of line end counts once.
struct LineCounter<'a> {
    bytes: &'a [u8],
    at: usize,
    line: usize,
}

impl LineCounter<'_> {
    fn line_at(&mut self, offset: usize) -> usize {
        let mut offset = offset.min(self.bytes.len());
        while offset < self.bytes.len() && matches!(self.bytes[offset], b'\r' | b'\n') {
            offset += 1;
        }
        if offset < self.at {
            // Offsets only move forward; an error may name an earlier one.
            self.at = 0;
            self.line = 1;
        }
        // A line ends at `\n`, `\r\n` or a lone `\r`, as the CSV reader ends records.
        let ends = (self.at..offset)
            .filter(|&k| match self.bytes[k] {
                b'\n' => true,
                b'\r' => self.bytes.get(k + 1) != Some(&b'\n'),
                _ => false,
            })
            .count();
        self.line += ends;
        self.at = offset;
        self.line
    }
}

/// The session's reference frame (`reference.png`, or `.jpg`/`.jpeg`), if it has one.
pub fn reference_frame(session: &Path) -> Option<PathBuf> {
    ["reference.png", "reference.jpg", "reference.jpeg", "reference.PNG", "reference.JPG"]
        .into_iter()
        .map(|name| session.join(name))
        .find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<CaptureLog, SessionError> {
        CaptureLog::parse(Path::new("s/captures.csv"), text.as_bytes())
    }

    #[test]
    fn rows_parse_with_extra_columns_and_round_trip() {
        let log = parse(
            "Frame,split,trial,a_deg,b_deg,c_deg,z_mm,operator\n\
             f/0.png,train,3,45,12.5,0,1.25,ana\n\
             f/1.jpg, Test ,1,0,-90,45,-0.5,bo\n",
        )
        .unwrap();
        assert!(log.bad.is_empty(), "{:?}", log.bad);
        assert_eq!(log.rows.len(), 2);
        let r = &log.rows[1];
        assert_eq!((r.line, r.frame.as_str(), r.split, r.trial), (3, "f/1.jpg", Split::Test, 1));
        assert_eq!(r.pose, RigPose { a_axis_deg: 0.0, b_axis_deg: -90.0, c_axis_deg: 45.0, z_travel_mm: -0.5 });
        assert_eq!(r.extra["operator"], "bo");
        let again = parse(&CaptureLog::to_csv(&log.rows)).unwrap();
        assert_eq!(again.rows, log.rows);
    }

    /// A force-torque sensor's columns become the row's measured wrench (all six, or all empty
    /// for a frame without a reading); half a set, or a cell that is no number, is refused with
    /// the file, the line and the column.
    #[test]
    fn force_torque_columns_are_a_measured_wrench() {
        let log = parse(
            "frame,split,trial,a_deg,b_deg,c_deg,z_mm,FX_N,fy_n,fz_n,tx_nmm,ty_nmm,tz_nmm,note\n\
             f/0.png,train,3,0,0,0,1,0.5,-0.25,-12.5,1.5,0,-2,x\n\
             f/1.png,train,4,0,0,0,1,,,,,,,y\n\
             f/2.png,train,5,0,0,0,1,0.5,,-12.5,1.5,0,-2,z\n\
             f/3.png,train,6,0,0,0,1,0.5,abc,-12.5,1.5,0,-2,w\n",
        )
        .unwrap();
        let w = log.rows[0].measured.expect("a measured wrench");
        assert_eq!((w.force_n, w.torque_nmm), ([0.5, -0.25, -12.5], [1.5, 0.0, -2.0]));
        assert_eq!(log.rows[0].extra.keys().collect::<Vec<_>>(), ["note"], "the wrench is not an extra column");
        assert_eq!(log.rows[1].measured, None);
        assert_eq!(log.rows.len(), 2);
        let bad: Vec<String> = log.bad.iter().map(|e| e.to_string()).collect();
        assert!(bad[0].contains("s/captures.csv: line 4") && bad[0].contains("fy_n"), "{bad:?}");
        assert!(bad[1].contains("line 5") && bad[1].contains("fy_n") && bad[1].contains("abc"), "{bad:?}");
        let again = parse(&CaptureLog::to_csv(&log.rows)).unwrap();
        assert_eq!(again.rows, log.rows);
        let e = parse("frame,split,trial,a_deg,b_deg,c_deg,z_mm,fx_n,fy_n\nf.png,train,1,0,0,0,0,1,2\n").unwrap_err();
        let e = e.to_string();
        assert!(e.contains("s/captures.csv") && e.contains("fz_n") && e.contains("tz_nmm"), "{e}");
    }

    #[test]
    fn bad_rows_and_files_are_named() {
        let e = parse("frame,split,trial,a_deg,b_deg,z_mm\nx.png,train,1,0,0,0\n").unwrap_err().to_string();
        assert!(e.contains("captures.csv") && e.contains("c_deg"), "{e}");
        let log = parse(
            "frame,split,trial,a_deg,b_deg,c_deg,z_mm\n\
             a.png,train,1,0,0,0,1\n\
             b.png,validation,1,0,0,0,1\n\
             c.png,train,x,0,0,0,1\n\
             d.png,train,1,0,nan,0,1\n\
             a.png,train,2,0,0,0,1\n\
             ,train,2,0,0,0,1\n\
             e.png,train,1,0,0,0,1e308\n",
        )
        .unwrap();
        assert_eq!(log.rows.len(), 1);
        let messages: Vec<String> = log.bad.iter().map(|e| e.to_string()).collect();
        assert_eq!(log.bad.iter().map(|e| e.line().unwrap()).collect::<Vec<_>>(), [3, 4, 5, 6, 7, 8], "{messages:?}");
        let wants = [
            "unknown split \"validation\": train, test",
            "whole number",
            "finite",
            "line 2",
            "empty",
            "finite number, got \"1e308\"",
        ];
        // Paths: resolved within the session, refused outside it, one frame named two ways found.
        let log = parse(
            "frame,split,trial,a_deg,b_deg,c_deg,z_mm\n\
             frames/a.png,train,1,0,0,0,1\n\
             frames/./a.png,train,1,0,0,0,1\n\
             frames/x/../b.png,train,1,0,0,0,1\n\
             ../../x.png,train,1,0,0,0,1\n\
             /etc/x.png,train,1,0,0,0,1\n\
             frames/../../s2/c.png,train,1,0,0,0,1\n",
        )
        .unwrap();
        assert_eq!(log.rows.iter().map(|r| r.frame.as_str()).collect::<Vec<_>>(), ["frames/a.png", "frames/b.png"]);
        let bad: Vec<String> = log.bad.iter().map(|e| e.to_string()).collect();
        assert!(bad[0].contains("line 3") && bad[0].contains("already listed on line 2"), "{bad:?}");
        for (m, line) in bad[1..].iter().zip([5, 6, 7]) {
            assert!(m.contains(&format!("line {line}")) && m.contains("outside the session"), "{m}");
        }
        for (m, want) in messages.iter().zip(wants) {
            assert!(m.contains("captures.csv") && m.contains(want), "{m}");
        }
        assert!(parse("frame,split,trial,a_deg,b_deg,c_deg,z_mm\n").unwrap_err().to_string().contains("no frames"));
    }

    #[test]
    fn lines_are_counted_alike_with_crlf_and_blank_lines() {
        let lf = "frame,split,trial,a_deg,b_deg,c_deg,z_mm\na.png,train,1,0,0,0,1\n\nb.png,train,x,0,0,0,1\nc.png,test,1,0,0,0,1\n";
        for text in [lf.to_string(), lf.replace('\n', "\r\n"), lf.replace('\n', "\r")] {
            let log = parse(&text).unwrap();
            assert_eq!(log.rows.iter().map(|r| r.line).collect::<Vec<_>>(), [2, 5], "{text:?}");
            assert_eq!(log.bad.iter().map(|e| e.line().unwrap()).collect::<Vec<_>>(), [4], "{text:?}");
        }
    }
}
