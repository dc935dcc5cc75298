//! A recording: where it goes, and the tactile data's shapes as Rerun archetypes.

use std::path::{Path, PathBuf};

use image::RgbImage;
use rerun::components::Colormap;
use rerun::datatypes::{ChannelDatatype, ImageFormat};
use rerun::{RecordingStream, RecordingStreamBuilder};
use sensor::PressureMap;

use crate::Target;
use crate::layout::{Panel, blueprint};
use rerun::blueprint::BlueprintActivation;

/// Why a view failed.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("cannot send the view to {target}: {detail}")]
    Start { target: String, detail: String },
    #[error("cannot write the view to {target}: {detail}")]
    Write { target: String, detail: String },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a Rerun recording this build can read: {detail}")]
    Read { path: PathBuf, detail: String },
    #[error("the view could not log {entity}: {detail}")]
    Log { entity: String, detail: String },
}

/// An open view. Logging is cheap for the caller: the SDK batches and writes on its own thread.
pub struct View {
    rec: RecordingStream,
    /// For a recording to a file: the file being written and the name it gets when done.
    saving: Option<(PathBuf, PathBuf)>,
}

impl View {
    /// Opens a view named `application` (the viewer's title) on `target`.
    pub fn open(application: &'static str, target: &Target) -> Result<View, ViewError> {
        let start = |detail: String| ViewError::Start { target: target.describe(), detail };
        let builder = RecordingStreamBuilder::new(application);
        let (rec, saving) = match target {
            Target::Spawn => (builder.spawn().map_err(|e| start(e.to_string()))?, None),
            Target::Connect(url) => (builder.connect_grpc_opts(url.clone()).map_err(|e| start(e.to_string()))?, None),
            Target::Save(path) => {
                let partial = partial_path(path);
                let rec = builder.save(&partial).map_err(|e| start(e.to_string()))?;
                (rec, Some((partial, path.clone())))
            }
        };
        Ok(View { rec, saving })
    }

    /// Lays the viewer out in `columns` of panels ([`crate::stream_columns`],
    /// [`crate::training_columns`]): sent with the data, so a recording opens laid out too.
    pub fn lay_out(&self, columns: &[Vec<Panel>]) -> Result<(), ViewError> {
        blueprint(columns)
            .send(&self.rec, BlueprintActivation { make_active: true, make_default: true })
            .map_err(|e| ViewError::Log { entity: "the layout".into(), detail: e.to_string() })
    }

    /// Where the following logs sit on `timeline` (a sequence: frame or step number).
    pub fn at(&self, timeline: &'static str, index: i64) {
        self.rec.set_time_sequence(timeline, index);
    }

    /// Where the following logs sit on `timeline` (a duration, seconds).
    pub fn at_seconds(&self, timeline: &'static str, seconds: f64) {
        self.rec.set_duration_secs(timeline, seconds);
    }

    fn log(&self, entity: &str, what: &impl rerun::AsComponents) -> Result<(), ViewError> {
        self.rec.log(entity, what).map_err(|e| ViewError::Log { entity: entity.into(), detail: e.to_string() })
    }

    /// An RGB image.
    pub fn rgb(&self, entity: &str, image: &RgbImage) -> Result<(), ViewError> {
        self.log(entity, &rerun::Image::from_rgb24(image.as_raw().clone(), [image.width(), image.height()]))
    }

    /// An RGB image as JPEG of `quality` (1..=100), for views that log every frame of a camera:
    /// far fewer bytes than the raw pixels, for the time spent encoding.
    pub fn rgb_jpeg(&self, entity: &str, image: &RgbImage, quality: u8) -> Result<(), ViewError> {
        let jpeg = sensor::frame::encode_jpeg_rgb(image, quality);
        self.log(entity, &rerun::EncodedImage::new(jpeg).with_media_type(rerun::MediaType::jpeg()))
    }

    /// A depth map of `size_px` (width, height), row-major (mm; one depth unit per world unit,
    /// so the viewer's 3D view agrees with the clouds' millimetres), false colour from 0 to
    /// `max_mm`, as float32: every value as it is.
    pub fn depth(&self, entity: &str, size_px: [u32; 2], depth_mm: &[f32], max_mm: f32) -> Result<(), ViewError> {
        let image = rerun::DepthImage::from_data_type_and_bytes(f32_bytes(depth_mm), size_px, ChannelDatatype::F32)
            .with_meter(1.0);
        self.log(entity, &coloured(image, max_mm))
    }

    /// [`View::depth`] in half the bytes: the 16-bit micrometre steps a dataset's depth PNGs hold
    /// (`sensor::depth_step`), for views that log every frame.
    pub fn depth_um(&self, entity: &str, size_px: [u32; 2], depth_mm: &[f32], max_mm: f32) -> Result<(), ViewError> {
        let bytes: Vec<u8> = depth_mm.iter().flat_map(|&d| sensor::depth_step(d).to_le_bytes()).collect();
        let image = rerun::DepthImage::from_data_type_and_bytes(bytes, size_px, ChannelDatatype::U16)
            .with_meter(sensor::DEPTH_STEPS_PER_MM);
        self.log(entity, &coloured(image, max_mm * sensor::DEPTH_STEPS_PER_MM))
    }

    /// A pressure map (kPa, single-channel float: the viewer shows its values on hover).
    pub fn pressure(&self, entity: &str, pressure: &PressureMap) -> Result<(), ViewError> {
        let n = pressure.size_px;
        let format = ImageFormat::from_color_model([n, n], rerun::ColorModel::L, ChannelDatatype::F32);
        self.log(entity, &rerun::Image::new(f32_bytes(&pressure.pressure_kpa), format))
    }

    /// A mask over an image of `size_px` squared: class 1 where true, drawn half transparent.
    pub fn mask(&self, entity: &str, size_px: u32, mask: &[bool]) -> Result<(), ViewError> {
        let classes: Vec<u8> = mask.iter().map(|&m| u8::from(m)).collect();
        let format = ImageFormat::segmentation([size_px, size_px], ChannelDatatype::U8);
        self.log(entity, &rerun::SegmentationImage::new(classes, format).with_opacity(0.5))
    }

    /// Points (mm), coloured where `colours` are given (one per point).
    pub fn points_mm(
        &self,
        entity: &str,
        points_mm: &[[f32; 3]],
        colours: Option<&[[u8; 3]]>,
    ) -> Result<(), ViewError> {
        let mut points = rerun::Points3D::new(points_mm.iter().copied()).with_radii([0.05f32]);
        if let Some(colours) = colours {
            points = points.with_colors(colours.iter().map(|&[r, g, b]| rerun::Color::from_rgb(r, g, b)));
        }
        self.log(entity, &points)
    }

    /// An arrow from `origin_mm` along `vector_mm`.
    pub fn arrow_mm(&self, entity: &str, origin_mm: [f32; 3], vector_mm: [f32; 3]) -> Result<(), ViewError> {
        self.log(entity, &rerun::Arrows3D::from_vectors([vector_mm]).with_origins([origin_mm]))
    }

    /// Takes away what `entity` showed (a force arrow once the contact is gone).
    pub fn clear(&self, entity: &str) -> Result<(), ViewError> {
        self.log(entity, &rerun::Clear::flat())
    }

    /// One value of a time series.
    pub fn scalar(&self, entity: &str, value: f64) -> Result<(), ViewError> {
        self.log(entity, &rerun::Scalars::single(value))
    }

    /// Sends what is pending and, for a recording, closes the file and gives it its name;
    /// returns that name.
    pub fn finish(self) -> Result<Option<PathBuf>, ViewError> {
        let target = self.saving.as_ref().map_or_else(|| "the viewer".to_string(), |(_, p)| p.display().to_string());
        // A failed write (a full disk) comes back here, from the sink's thread.
        self.rec.flush_blocking().map_err(|e| ViewError::Write { target, detail: e.to_string() })?;
        // Dropping the last handle drops the file sink, which writes the file's footer and
        // joins its thread: the file is whole after this line.
        drop(self.rec);
        let Some((partial, path)) = self.saving else { return Ok(None) };
        std::fs::rename(&partial, &path).map_err(|source| ViewError::Io { path: path.clone(), source })?;
        Ok(Some(path))
    }
}

/// The name a recording has while it is written.
pub(crate) fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

/// A depth image in false colour from 0 to `max` (in the image's own units).
fn coloured(image: rerun::DepthImage, max: f32) -> rerun::DepthImage {
    image.with_colormap(Colormap::Turbo).with_depth_range([0.0, f64::from(max.max(f32::MIN_POSITIVE))])
}

/// Little-endian bytes of `values` (Rerun's buffers are byte blobs).
fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}
