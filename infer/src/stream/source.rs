//! Where a stream's frames come from: a folder as frames appear in it, a glob of existing
//! frames (every one, or paced like a camera), a V4L2 camera (feature `v4l2`).

use std::collections::{HashSet, VecDeque};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use image::RgbImage;

/// A frame as a source delivers it, before decoding and cropping.
pub enum RawFrame {
    /// A PNG or JPEG file's bytes.
    Encoded(Vec<u8>),
    /// Pixels already decoded (a camera's YUYV frame, converted).
    Rgb(RgbImage),
}

/// What a source hands over.
pub enum Delivered {
    /// A frame; `arrived` is when it came into being for us (the camera's dequeue, the moment
    /// a watched file was seen whole, a paced frame's release time).
    Frame { name: String, arrived: Instant, raw: RawFrame },
    /// Frames that went stale before they were read (a paced source behind its schedule):
    /// counted, never decoded.
    Skipped(u64),
    /// A frame that could not be read; the stream goes on.
    Unreadable { name: String, message: String },
}

/// How a source's frames meet a busy network (`live` or `every` in `stream.json`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Delivery {
    /// Live: the newest frame replaces a waiting one, which counts as dropped.
    Live,
    /// Every frame, in order: the source waits for the network (offline batches).
    Every,
}

impl Delivery {
    /// Its name, as `stream.json` writes it.
    pub fn name(self) -> &'static str {
        match self {
            Delivery::Live => "live",
            Delivery::Every => "every",
        }
    }
}

/// A stream's frame source. `next` blocks until something arrives and returns `None` at the
/// end of the stream or once `stop` is set.
pub trait Source: Send {
    fn next(&mut self, stop: &AtomicBool) -> Option<Delivered>;
    fn delivery(&self) -> Delivery;
    /// For people: what is read.
    fn describe(&self) -> String;
    /// Once the stream has ended: frames the source saw begin but never saw whole (a camera
    /// program killed mid-write), each `name: why`, for the summary. Default: none.
    fn unfinished(&self) -> Vec<String> {
        Vec::new()
    }
}

/// Whether `name` looks like a frame: `.png`, `.jpg` or `.jpeg` (any case), not hidden (atomic
/// writers, ours included, write `.NAME.tmp` first).
fn is_frame_name(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    !name.starts_with('.') && [".png", ".jpg", ".jpeg"].iter().any(|e| lower.ends_with(e))
}

/// Sleeps up to `d` in short steps, returning early once `stop` is set.
fn sleep_unless_stopped(d: Duration, stop: &AtomicBool) {
    let end = Instant::now() + d;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= end {
            return;
        }
        std::thread::sleep((end - now).min(Duration::from_millis(20)));
    }
}

/// New frames in a folder, each once, in name order. Frames already there at the start are
/// not read (a glob reads those). A file is read when it is whole (PNG ending in IEND, JPEG in
/// its end-of-image marker), so a camera program that writes in place is read correctly too.
pub struct FolderSource {
    dir: PathBuf,
    poll: Duration,
    /// Stop after this long without a new frame (`None`: until stopped).
    idle_exit: Option<Duration>,
    seen: HashSet<OsString>,
    /// Whole, unread frames in name order, with when each was seen whole.
    pending: VecDeque<(String, Vec<u8>, Instant)>,
    last_new: Instant,
}

impl FolderSource {
    /// Watches `dir`, looking every `poll`; returns how many frames were there already.
    pub fn new(dir: &Path, poll: Duration, idle_exit: Option<Duration>) -> std::io::Result<(Self, usize)> {
        let mut source = FolderSource {
            dir: dir.to_path_buf(),
            poll,
            idle_exit,
            seen: HashSet::new(),
            pending: VecDeque::new(),
            last_new: Instant::now(),
        };
        let before = source.new_names()?;
        let count = before.len();
        source.seen.extend(before);
        Ok((source, count))
    }

    /// Frame names in the folder not seen yet, sorted.
    fn new_names(&self) -> std::io::Result<Vec<OsString>> {
        let mut names = Vec::new();
        for entry in std::fs::read_dir(&self.dir)? {
            let name = entry?.file_name();
            if !self.seen.contains(&name) && name.to_str().is_some_and(is_frame_name) {
                names.push(name);
            }
        }
        names.sort();
        Ok(names)
    }

    /// One look at the folder: whole new frames join `pending`; a frame still being written
    /// is looked at again next time.
    fn look(&mut self) -> Result<(), Delivered> {
        let unreadable = |name: String, e: std::io::Error| Delivered::Unreadable { name, message: e.to_string() };
        let names = self.new_names().map_err(|e| unreadable(self.dir.display().to_string(), e))?;
        for name in names {
            let path = self.dir.join(&name);
            let shown = path.display().to_string();
            match std::fs::read(&path) {
                Ok(bytes) if formats::fs::image_bytes_complete(&bytes) => {
                    self.seen.insert(name);
                    self.pending.push_back((shown, bytes, Instant::now()));
                }
                Ok(_) => {}                                              // still being written
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {} // renamed away meanwhile
                Err(e) => {
                    self.seen.insert(name);
                    return Err(unreadable(shown, e));
                }
            }
        }
        Ok(())
    }
}

impl Source for FolderSource {
    fn next(&mut self, stop: &AtomicBool) -> Option<Delivered> {
        loop {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            if self.pending.is_empty()
                && let Err(bad) = self.look()
            {
                return Some(bad);
            }
            // Several frames found in one look go out one by one, oldest first: whether one is
            // stale is the network's business (the mailbox's), not the poll's timing.
            if let Some((name, bytes, arrived)) = self.pending.pop_front() {
                self.last_new = arrived;
                return Some(Delivered::Frame { name, arrived, raw: RawFrame::Encoded(bytes) });
            }
            if self.idle_exit.is_some_and(|idle| self.last_new.elapsed() >= idle) {
                return None;
            }
            sleep_unless_stopped(self.poll, stop);
        }
    }

    fn delivery(&self) -> Delivery {
        Delivery::Live
    }

    fn describe(&self) -> String {
        format!("new frames in {}", self.dir.display())
    }

    fn unfinished(&self) -> Vec<String> {
        let names = self.new_names().unwrap_or_default();
        names
            .into_iter()
            .map(|name| self.dir.join(name))
            .filter(|path| std::fs::read(path).is_ok_and(|bytes| !formats::fs::image_bytes_complete(&bytes)))
            .map(|path| format!("{}: never written whole while the stream ran (not read)", path.display()))
            .collect()
    }
}

/// Time as a paced source sees it: the wall clock ([`WallClock`]), or one a test steps, so that
/// what pacing does can be tested without depending on how fast the machine is.
pub trait Clock: Send {
    /// Time since the clock's first reading.
    fn elapsed(&mut self) -> Duration;
    /// Waits `d`, or less once `stop` is set.
    fn sleep(&mut self, d: Duration, stop: &AtomicBool);
    /// The instant of `at` since the first reading (a frame's arrival).
    fn instant(&self, at: Duration) -> Instant;
}

/// The wall clock, started at its first reading.
#[derive(Debug, Default)]
pub struct WallClock {
    start: Option<Instant>,
}

impl Clock for WallClock {
    fn elapsed(&mut self) -> Duration {
        self.start.get_or_insert_with(Instant::now).elapsed()
    }

    fn sleep(&mut self, d: Duration, stop: &AtomicBool) {
        sleep_unless_stopped(d, stop);
    }

    fn instant(&self, at: Duration) -> Instant {
        self.start.map_or_else(Instant::now, |s| s + at)
    }
}

/// Existing frames matching a glob pattern, in name order: every one as fast as the network
/// takes them, or released at `fps` like a camera's (stale ones skipped).
pub struct GlobSource {
    pattern: String,
    paths: Vec<PathBuf>,
    next_index: usize,
    fps: Option<f64>,
    clock: Box<dyn Clock>,
}

/// Why a source cannot start.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SourceError {
    #[error("--source {pattern:?}: not a valid glob: {why}")]
    Glob { pattern: String, why: String },
    #[error("--source {0:?}: no PNG or JPEG frame matches")]
    NoFrames(String),
    #[error("--fps must be a positive number of frames per second, got {0}")]
    Fps(f64),
}

impl GlobSource {
    /// The frames matching `pattern`; an invalid pattern or none matching is an error.
    pub fn new(pattern: &str, fps: Option<f64>) -> Result<Self, SourceError> {
        let matches =
            glob::glob(pattern).map_err(|e| SourceError::Glob { pattern: pattern.to_string(), why: e.to_string() })?;
        let mut paths: Vec<PathBuf> = matches
            .filter_map(Result::ok)
            .filter(|p| p.is_file() && p.file_name().and_then(|n| n.to_str()).is_some_and(is_frame_name))
            .collect();
        paths.sort();
        if paths.is_empty() {
            return Err(SourceError::NoFrames(pattern.to_string()));
        }
        if let Some(fps) = fps
            && !(fps.is_finite() && fps > 0.0)
        {
            return Err(SourceError::Fps(fps));
        }
        Ok(GlobSource {
            pattern: pattern.to_string(),
            paths,
            next_index: 0,
            fps,
            clock: Box::new(WallClock::default()),
        })
    }

    /// The same source paced by `clock` instead of the wall clock.
    pub fn with_clock(mut self, clock: Box<dyn Clock>) -> Self {
        self.clock = clock;
        self
    }

    pub fn len(&self) -> usize {
        self.paths.len()
    }

    pub fn is_empty(&self) -> bool {
        self.paths.is_empty()
    }
}

impl Source for GlobSource {
    fn next(&mut self, stop: &AtomicBool) -> Option<Delivered> {
        if stop.load(Ordering::Relaxed) || self.next_index >= self.paths.len() {
            return None;
        }
        let mut arrived = Instant::now();
        if let Some(fps) = self.fps {
            // The frame the camera would show now; those released before it are stale.
            // The last frame is never stale: nothing newer replaces it.
            let now = self.clock.elapsed();
            let due = ((now.as_secs_f64() * fps) as usize).min(self.paths.len() - 1);
            if due > self.next_index {
                let stale = (due - self.next_index) as u64;
                self.next_index = due;
                return Some(Delivered::Skipped(stale));
            }
            let release = Duration::from_secs_f64(self.next_index as f64 / fps);
            self.clock.sleep(release.saturating_sub(now), stop);
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            arrived = self.clock.instant(release);
        }
        let path = &self.paths[self.next_index];
        self.next_index += 1;
        let name = path.display().to_string();
        Some(match std::fs::read(path) {
            Ok(bytes) => Delivered::Frame { name, arrived, raw: RawFrame::Encoded(bytes) },
            Err(e) => Delivered::Unreadable { name, message: e.to_string() },
        })
    }

    fn delivery(&self) -> Delivery {
        if self.fps.is_some() { Delivery::Live } else { Delivery::Every }
    }

    fn describe(&self) -> String {
        match self.fps {
            Some(fps) => format!("{} frames matching {:?}, released at {fps} fps", self.paths.len(), self.pattern),
            None => format!("{} frames matching {:?}, every one", self.paths.len(), self.pattern),
        }
    }
}

/// YUYV 4:2:2 (V4L2's `YUYV`: Y0 U Y1 V per two pixels, BT.601 limited range, as webcams send)
/// to RGB. `stride` is the bytes per row (at least `2 * width`); `None` when the buffer is too
/// short or the width odd.
pub fn yuyv_to_rgb(data: &[u8], width: u32, height: u32, stride: usize) -> Option<RgbImage> {
    let (w, h) = (width as usize, height as usize);
    if w % 2 != 0 || stride < 2 * w || data.len() < stride * h.saturating_sub(1) + 2 * w {
        return None;
    }
    let mut out = vec![0u8; w * h * 3];
    let clamp = |v: i32| v.clamp(0, 255) as u8;
    for (y, row) in out.chunks_exact_mut(w * 3).enumerate() {
        let src = &data[y * stride..y * stride + 2 * w];
        for (pair, px) in src.chunks_exact(4).zip(row.chunks_exact_mut(6)) {
            let (u, v) = (pair[1] as i32 - 128, pair[3] as i32 - 128);
            // BT.601 in 16.16 fixed point: R = 1.164 (Y-16) + 1.596 V, G = ... - 0.392 U - 0.813 V,
            // B = ... + 2.017 U.
            let (dr, dg, db) = (104_597 * v, -25_675 * u - 53_279 * v, 132_201 * u);
            for (k, &luma) in [pair[0], pair[2]].iter().enumerate() {
                let c = 76_309 * (luma as i32 - 16) + 32_768;
                px[3 * k] = clamp((c + dr) >> 16);
                px[3 * k + 1] = clamp((c + dg) >> 16);
                px[3 * k + 2] = clamp((c + db) >> 16);
            }
        }
    }
    RgbImage::from_raw(width, height, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// BT.601 limited-range forward transform, for the round trip.
    fn yuv_of(rgb: [u8; 3]) -> [u8; 3] {
        let [r, g, b] = rgb.map(|c| c as f64);
        let y = 16.0 + 0.257 * r + 0.504 * g + 0.098 * b;
        let u = 128.0 - 0.148 * r - 0.291 * g + 0.439 * b;
        let v = 128.0 + 0.439 * r - 0.368 * g - 0.071 * b;
        [y, u, v].map(|c| c.round().clamp(0.0, 255.0) as u8)
    }

    #[test]
    fn yuyv_decodes_to_rgb_in_rgb_order() {
        // Pairs of equal pixels (4:2:2 shares chroma across a pair): red, green, blue, white,
        // black, an LED-like orange; a 2-byte pad at each row's end tests the stride.
        let colours: [[u8; 3]; 6] =
            [[230, 20, 20], [20, 200, 30], [25, 30, 220], [255, 255, 255], [0, 0, 0], [240, 150, 40]];
        let (w, h, stride) = (12u32, 2u32, 26usize);
        let mut data = vec![0u8; stride * h as usize];
        for y in 0..h as usize {
            for (i, c) in colours.iter().enumerate() {
                let [yy, u, v] = yuv_of(*c);
                data[y * stride + 4 * i..y * stride + 4 * i + 4].copy_from_slice(&[yy, u, yy, v]);
            }
        }
        let img = yuyv_to_rgb(&data, w, h, stride).unwrap();
        for y in 0..h {
            for (i, c) in colours.iter().enumerate() {
                for x in [2 * i as u32, 2 * i as u32 + 1] {
                    let got = img.get_pixel(x, y).0;
                    for k in 0..3 {
                        assert!((got[k] as i32 - c[k] as i32).abs() <= 3, "pixel {x},{y}: {got:?} for {c:?}");
                    }
                }
            }
        }
        // Red stays in the first channel.
        assert!(img.get_pixel(0, 0).0[0] > 200 && img.get_pixel(0, 0).0[2] < 40);
        // Short buffers and odd widths are refused, not read past.
        // The last row's padding may be missing, not its pixels.
        let needed = stride * (h as usize - 1) + 2 * w as usize;
        assert!(yuyv_to_rgb(&data[..needed], w, h, stride).is_some());
        assert!(yuyv_to_rgb(&data[..needed - 1], w, h, stride).is_none());
        assert!(yuyv_to_rgb(&data, 11, h, stride).is_none());
        assert!(yuyv_to_rgb(&data, w, h, 20).is_none());
    }

    #[test]
    fn frame_names_are_pngs_and_jpegs_not_hidden_temporaries() {
        for yes in ["a.png", "0001.JPG", "x.jpeg"] {
            assert!(is_frame_name(yes), "{yes}");
        }
        for no in [".a.png.1234.tmp", ".hidden.png", "a.bmp", "notes.txt", "png"] {
            assert!(!is_frame_name(no), "{no}");
        }
    }
}
