//! A V4L2 camera as a stream source (feature `v4l2`): MJPEG or YUYV at the sensor's frame size.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use v4l::FourCC;
use v4l::buffer::Type;
use v4l::io::traits::CaptureStream;
use v4l::prelude::{Device, MmapStream};
use v4l::video::Capture;

use super::source::{Delivered, Delivery, RawFrame, Source, yuyv_to_rgb};

/// How long one wait for a frame lasts before the stop flag is looked at again (ms).
const POLL_MS: i32 = 100;

/// The pixel formats read, best first: MJPEG keeps USB bandwidth for full frames at 30 fps.
const FORMATS: [&[u8; 4]; 2] = [b"MJPG", b"YUYV"];

pub struct CameraSource {
    path: String,
    // The stream's buffers are mapped from the device's handle, which it shares (an `Arc`):
    // the device outlives nothing it needs, so the stream's lifetime is not tied to it.
    stream: MmapStream<'static>,
    _device: Device,
    fourcc: FourCC,
    width: u32,
    height: u32,
    stride: usize,
    started: bool,
    sequence: u64,
}

impl CameraSource {
    /// Opens `path` at `width` x `height` (the sensor's camera frame), MJPEG if it offers it,
    /// else YUYV, at `fps` if given; a camera that offers neither, or not that size, is refused
    /// with what it offers.
    pub fn open(path: &str, width: u32, height: u32, fps: Option<f64>) -> std::io::Result<Self> {
        let refuse = |message: String| std::io::Error::new(std::io::ErrorKind::Unsupported, message);
        let device = Device::with_path(path)?;
        let offered: Vec<FourCC> = device.enum_formats()?.into_iter().map(|f| f.fourcc).collect();
        let fourcc = FORMATS
            .iter()
            .map(|f| FourCC::new(f))
            .find(|f| offered.contains(f))
            .ok_or_else(|| refuse(format!("the camera offers {offered:?}; MJPG or YUYV is read")))?;
        let format = device.set_format(&v4l::Format::new(width, height, fourcc))?;
        if (format.width, format.height) != (width, height) || format.fourcc != fourcc {
            return Err(refuse(format!(
                "asked for {width}x{height} {fourcc}, the camera gives {}x{} {}; the bundle's sensor expects \
                 {width}x{height} frames",
                format.width, format.height, format.fourcc
            )));
        }
        if let Some(fps) = fps {
            device.set_params(&v4l::video::capture::Parameters::with_fps(fps.round().max(1.0) as u32))?;
        }
        let stream = MmapStream::with_buffers(&device, Type::VideoCapture, 4)?;
        Ok(CameraSource {
            path: path.to_string(),
            stream,
            _device: device,
            fourcc,
            width,
            height,
            stride: format.stride as usize,
            started: false,
            sequence: 0,
        })
    }
}

impl Source for CameraSource {
    fn next(&mut self, stop: &AtomicBool) -> Option<Delivered> {
        let name = format!("{}#{}", self.path, self.sequence);
        // v4l's own timeout leaves its buffer bookkeeping wrong, so the wait is a poll of the
        // handle before the dequeue (which then returns at once). Before the first frame the
        // stream is not started, and the first `next` starts it.
        if self.started {
            loop {
                if stop.load(Ordering::Relaxed) {
                    return None;
                }
                match self.stream.handle().poll(libc::POLLIN, POLL_MS) {
                    Ok(0) => continue,
                    Ok(_) => break,
                    Err(e) => return Some(Delivered::Unreadable { name, message: e.to_string() }),
                }
            }
        }
        let (buf, meta) = match self.stream.next() {
            Ok(v) => v,
            Err(e) => {
                stop.store(true, Ordering::Relaxed);
                return Some(Delivered::Unreadable { name, message: format!("the camera stopped: {e}") });
            }
        };
        self.started = true;
        let arrived = Instant::now();
        self.sequence += 1;
        let bytes = &buf[..(meta.bytesused as usize).min(buf.len())];
        let raw = if self.fourcc == FourCC::new(b"MJPG") {
            RawFrame::Encoded(bytes.to_vec())
        } else {
            match yuyv_to_rgb(bytes, self.width, self.height, self.stride.max(2 * self.width as usize)) {
                Some(img) => RawFrame::Rgb(img),
                None => {
                    let message =
                        format!("a YUYV frame of {} bytes is short for {}x{}", bytes.len(), self.width, self.height);
                    return Some(Delivered::Unreadable { name, message });
                }
            }
        };
        Some(Delivered::Frame { name, arrived, raw })
    }

    fn delivery(&self) -> Delivery {
        Delivery::Live
    }

    fn describe(&self) -> String {
        format!("camera {} ({}x{} {})", self.path, self.width, self.height, self.fourcc)
    }
}
