//! A recording read back with the Rerun SDK's own decoder: what a viewer would be shown.

use std::collections::BTreeSet;
use std::io::BufReader;
use std::path::Path;

use re_chunk::Chunk;
use re_log_encoding::rrd::DecoderApp;
use re_log_types::{LogMsg, TimelineName};
use rerun::ComponentDescriptor;
use rerun::blueprint::components::{ViewClass, ViewOrigin};
use rerun::components::{Blob, ImageBuffer, ImageFormat, Name, Position3D, Scalar, Vector3D};
use rerun::datatypes::ChannelDatatype;
use rerun::external::re_sdk_types::blueprint::archetypes::ViewBlueprint;

use crate::{Panel, ViewError};

/// The data of a `.rrd` file, chunk by chunk, and the layout it came with.
pub struct Recording {
    chunks: Vec<Chunk>,
    blueprint: Vec<Chunk>,
}

/// Reads the recording at `path`.
pub fn read_back(path: &Path) -> Result<Recording, ViewError> {
    let bad = |detail: String| ViewError::Read { path: path.to_path_buf(), detail };
    let file = std::fs::File::open(path).map_err(|source| ViewError::Io { path: path.to_path_buf(), source })?;
    let (mut chunks, mut blueprint) = (Vec::new(), Vec::new());
    for msg in DecoderApp::decode_lazy(BufReader::new(file)) {
        if let LogMsg::ArrowMsg(store, arrow) = msg.map_err(|e| bad(e.to_string()))? {
            let chunk = Chunk::from_arrow_msg(&arrow).map_err(|e| bad(e.to_string()))?;
            if store.is_blueprint() { blueprint.push(chunk) } else { chunks.push(chunk) }
        }
    }
    Ok(Recording { chunks, blueprint })
}

/// One logged value: where it sits on the timeline asked for, and the value.
pub type Logged<T> = (i64, T);

impl Recording {
    /// The entity paths that hold data (`/camera/frame` and the like, as Rerun writes them).
    pub fn entities(&self) -> BTreeSet<String> {
        self.chunks.iter().map(|c| c.entity_path().to_string()).collect()
    }

    /// The panels of the layout the recording came with, by name (as [`crate::panels_by_name`]
    /// lists a layout's).
    pub fn panels(&self) -> Vec<Panel> {
        let descriptor = |d: ComponentDescriptor| d.component;
        let (class, name, origin) = (
            descriptor(ViewBlueprint::descriptor_class_identifier()),
            descriptor(ViewBlueprint::descriptor_display_name()),
            descriptor(ViewBlueprint::descriptor_space_origin()),
        );
        let mut panels = Vec::new();
        for chunk in &self.blueprint {
            let classes = chunk.iter_component::<ViewClass>(class);
            let names = chunk.iter_component::<Name>(name);
            let origins = chunk.iter_component::<ViewOrigin>(origin);
            for ((c, n), o) in classes.zip(names).zip(origins) {
                let (Some(c), Some(n), Some(o)) = (c.first(), n.first(), o.first()) else { continue };
                let class = match c.0.as_str() {
                    "2D" => "2D",
                    "3D" => "3D",
                    "TimeSeries" => "TimeSeries",
                    _ => "other",
                };
                panels.push(Panel { class, name: n.as_str().to_string(), origin: o.0.to_string() });
            }
        }
        panels.sort_by(|a, b| a.name.cmp(&b.name));
        panels
    }

    /// The batches of `component` logged to `entity`, by their index on `timeline`.
    fn column<C: rerun::Component + Clone>(
        &self,
        entity: &str,
        timeline: &str,
        descriptor: ComponentDescriptor,
    ) -> Vec<Logged<Vec<C>>> {
        let entity = re_log_types::EntityPath::from(entity);
        let Ok(timeline) = TimelineName::try_new(timeline) else { return Vec::new() };
        let mut rows = Vec::new();
        for chunk in self.chunks.iter().filter(|c| *c.entity_path() == entity) {
            let indices = chunk.iter_component_indices(timeline, descriptor.component);
            for ((time, _), batch) in indices.zip(chunk.iter_component::<C>(descriptor.component)) {
                rows.push((time.as_i64(), batch.to_vec()));
            }
        }
        rows.sort_by_key(|(t, _)| *t);
        rows
    }

    /// The time series logged to `entity`.
    pub fn scalars(&self, entity: &str, timeline: &str) -> Vec<Logged<f64>> {
        let rows = self.column::<Scalar>(entity, timeline, rerun::Scalars::descriptor_scalars());
        rows.into_iter().filter_map(|(t, v)| v.first().map(|s| (t, s.0.0))).collect()
    }

    /// The images logged to `entity` (by their archetype's descriptors): format and bytes.
    fn images(
        &self,
        entity: &str,
        timeline: &str,
        buffer: ComponentDescriptor,
        format: ComponentDescriptor,
    ) -> Vec<Logged<(ImageFormat, Vec<u8>)>> {
        let buffers = self.column::<ImageBuffer>(entity, timeline, buffer);
        let formats = self.column::<ImageFormat>(entity, timeline, format);
        buffers
            .into_iter()
            .zip(formats)
            .filter_map(|((t, b), (_, f))| Some((t, (*f.first()?, b.first()?.0.0.to_vec()))))
            .collect()
    }

    /// The depth images logged to `entity`: size (px) and values (mm), from float32 or from
    /// 16-bit micrometres ([`crate::View::depth_um`]).
    pub fn depth_images(&self, entity: &str, timeline: &str) -> Vec<Logged<([u32; 2], Vec<f32>)>> {
        let images = self.images(
            entity,
            timeline,
            rerun::DepthImage::descriptor_buffer(),
            rerun::DepthImage::descriptor_format(),
        );
        let values = |f: &ImageFormat, bytes: &[u8]| match f.datatype() {
            ChannelDatatype::U16 => {
                bytes.chunks_exact(2).map(|b| sensor::step_depth_mm(u16::from_le_bytes([b[0], b[1]]))).collect()
            }
            _ => f32s(bytes),
        };
        images.into_iter().map(|(t, (f, bytes))| (t, ([f.width, f.height], values(&f, &bytes)))).collect()
    }

    /// The encoded (JPEG, PNG) images logged to `entity`, decoded: size (px) and RGB bytes.
    pub fn encoded_images(&self, entity: &str, timeline: &str) -> Vec<Logged<([u32; 2], Vec<u8>)>> {
        let blobs = self.column::<Blob>(entity, timeline, rerun::EncodedImage::descriptor_blob());
        blobs
            .into_iter()
            .filter_map(|(t, b)| {
                let image = image::load_from_memory(&b.first()?.0.0).ok()?.to_rgb8();
                Some((t, ([image.width(), image.height()], image.into_raw())))
            })
            .collect()
    }

    /// The colour (or single-channel) images logged to `entity`: size (px) and raw bytes.
    pub fn colour_images(&self, entity: &str, timeline: &str) -> Vec<Logged<([u32; 2], Vec<u8>)>> {
        let images =
            self.images(entity, timeline, rerun::Image::descriptor_buffer(), rerun::Image::descriptor_format());
        images.into_iter().map(|(t, (f, bytes))| (t, ([f.width, f.height], bytes))).collect()
    }

    /// The segmentation images logged to `entity`: size (px) and classes.
    pub fn masks(&self, entity: &str, timeline: &str) -> Vec<Logged<([u32; 2], Vec<u8>)>> {
        let images = self.images(
            entity,
            timeline,
            rerun::SegmentationImage::descriptor_buffer(),
            rerun::SegmentationImage::descriptor_format(),
        );
        images.into_iter().map(|(t, (f, bytes))| (t, ([f.width, f.height], bytes))).collect()
    }

    /// The points logged to `entity`.
    pub fn points(&self, entity: &str, timeline: &str) -> Vec<Logged<Vec<[f32; 3]>>> {
        let rows = self.column::<Position3D>(entity, timeline, rerun::Points3D::descriptor_positions());
        rows.into_iter().map(|(t, p)| (t, p.iter().map(|p| p.0.0).collect())).collect()
    }

    /// The arrows' vectors logged to `entity`.
    pub fn arrows(&self, entity: &str, timeline: &str) -> Vec<Logged<Vec<[f32; 3]>>> {
        let rows = self.column::<Vector3D>(entity, timeline, rerun::Arrows3D::descriptor_vectors());
        rows.into_iter().map(|(t, v)| (t, v.iter().map(|v| v.0.0).collect())).collect()
    }
}

fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}
