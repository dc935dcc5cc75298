//! ROS 2 out (feature `ros2`), through a pure-Rust DDS client: no ROS installation needed.
//!
//! Per frame, under the namespace given (default `/densetact`):
//! - `points`: `sensor_msgs/PointCloud2` of the contact patch, x, y, z float32 in metres, in
//!   the sensor frame (`frame_id` as given), as ROS expects;
//! - `depth`: `sensor_msgs/Image`, `32FC1`, metres, the crop's grid (zero outside the disk);
//! - `contact`: `std_msgs/String`, a JSON summary (`frame`, `contact_pixels`, `max_depth_mm`,
//!   `network_ran`, `sensor_radius_mm`, and with a force bundle `force_n`), readable from any
//!   ROS 2 tool without a custom message package;
//! - from a bundle with the force output, `wrench`: `geometry_msgs/WrenchStamped` (N and N m,
//!   sensor frame, torque about the dome's centre) and `pressure`: `sensor_msgs/Image`,
//!   `32FC1`, pascals, the crop's grid.

use std::time::{SystemTime, UNIX_EPOCH};

use ros2_client::qos::{Reliability, WhenFull};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, Publisher, QosProfile};

use super::{FrameResult, Sink, SinkError};
use crate::Predictor;

/// The ROS 2 messages published, field for field as their `.msg` definitions (CDR follows the
/// field order).
pub mod msg {
    use serde::{Deserialize, Serialize};

    /// `builtin_interfaces/Time`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Time {
        pub sec: i32,
        pub nanosec: u32,
    }

    /// `std_msgs/Header`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: String,
    }

    /// `sensor_msgs/PointField`.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    pub struct PointField {
        pub name: String,
        pub offset: u32,
        pub datatype: u8,
        pub count: u32,
    }

    /// `PointField.FLOAT32`.
    pub const FLOAT32: u8 = 7;

    /// `sensor_msgs/PointCloud2`.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    pub struct PointCloud2 {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub fields: Vec<PointField>,
        pub is_bigendian: bool,
        pub point_step: u32,
        pub row_step: u32,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
        pub is_dense: bool,
    }

    /// `sensor_msgs/Image`.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    pub struct Image {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub encoding: String,
        pub is_bigendian: u8,
        pub step: u32,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
    }

    /// `geometry_msgs/Vector3`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    /// `geometry_msgs/Wrench`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Wrench {
        pub force: Vector3,
        pub torque: Vector3,
    }

    /// `geometry_msgs/WrenchStamped`.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct WrenchStamped {
        pub header: Header,
        pub wrench: Wrench,
    }
}

/// ROS's unit is the metre; ours the millimetre.
const MM_PER_M: f32 = 1000.0;

/// ROS's unit of pressure is the pascal; ours the kilopascal.
const PA_PER_KPA: f32 = 1000.0;

/// Little-endian float32 metres, as PointCloud2's and Image's `data` hold them.
fn metres_le_bytes<'a>(mm: impl Iterator<Item = &'a f32>) -> Vec<u8> {
    mm.flat_map(|mm| (mm / MM_PER_M).to_le_bytes()).collect()
}

/// A square plane of the crop as a `32FC1` image.
fn plane_image(header: msg::Header, side: u32, data: Vec<u8>) -> msg::Image {
    msg::Image { header, height: side, width: side, encoding: "32FC1".into(), is_bigendian: 0, step: 4 * side, data }
}

/// The force messages of one frame from a bundle with the force output: the wrench (N, N m)
/// and the pressure image (Pa).
pub fn force_messages(result: &FrameResult, header: msg::Header) -> Option<(msg::WrenchStamped, msg::Image)> {
    let force = result.force?;
    let v = |a: [f64; 3], scale: f64| msg::Vector3 { x: a[0] * scale, y: a[1] * scale, z: a[2] * scale };
    let wrench = msg::WrenchStamped {
        header: header.clone(),
        wrench: msg::Wrench {
            force: v(force.wrench.force_n, 1.0),
            torque: v(force.wrench.torque_nmm, 1.0 / MM_PER_M as f64),
        },
    };
    let pa = force.pressure.pressure_kpa.iter().flat_map(|kpa| (kpa * PA_PER_KPA).to_le_bytes()).collect();
    Some((wrench, plane_image(header, force.pressure.size_px, pa)))
}

/// The messages of one frame.
pub fn messages(
    predictor: &Predictor,
    result: &FrameResult,
    header: msg::Header,
) -> (msg::PointCloud2, msg::Image, String) {
    let points = &result.cloud.points_mm;
    let data = metres_le_bytes(points.iter().flatten());
    let field =
        |name: &str, offset: u32| msg::PointField { name: name.into(), offset, datatype: msg::FLOAT32, count: 1 };
    let cloud = msg::PointCloud2 {
        header: header.clone(),
        height: 1,
        width: points.len() as u32,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        is_bigendian: false,
        point_step: 12,
        row_step: 12 * points.len() as u32,
        data,
        is_dense: true,
    };
    let image = plane_image(header, result.depth.size_px, metres_le_bytes(result.depth.depth_mm.iter()));
    let mut summary = serde_json::json!({
        "frame": result.name,
        "contact_pixels": result.contact_pixels,
        "max_depth_mm": result.depth.max_mm(),
        "network_ran": result.network_ran,
        "sensor_radius_mm": predictor.file.sensor.radius_mm,
    });
    if let Some(force) = result.force {
        summary["force_n"] = serde_json::json!(force.wrench.force_n);
    }
    (cloud, image, summary.to_string())
}

/// Publishes each frame's cloud, depth and contact summary.
pub struct Ros2Sink {
    frame_id: String,
    /// Where it publishes, for the summary: namespace and domain.
    place: String,
    sent: u64,
    unsent: u64,
    points: Publisher<msg::PointCloud2>,
    depth: Publisher<msg::Image>,
    contact: Publisher<String>,
    wrench: Publisher<msg::WrenchStamped>,
    pressure: Publisher<msg::Image>,
    // Kept alive while publishing: its DDS participant carries the publishers.
    _node: ros2_client::Node,
}

impl Ros2Sink {
    /// Publishes under `namespace` (absolute, such as `/densetact`) in DDS domain `domain_id`
    /// (ROS 2's `ROS_DOMAIN_ID`; 0 by default), messages stamped with `frame_id`.
    pub fn new(namespace: &str, frame_id: &str, domain_id: u16) -> Result<Self, SinkError> {
        let fail = |what: &'static str, e: &dyn std::fmt::Debug| SinkError::Ros2 { what, detail: format!("{e:?}") };
        let context =
            Context::with_options(ContextOptions::new().domain_id(domain_id)).map_err(|e| fail("start DDS", &e))?;
        let mut node = context
            .new_node(
                NodeName::new(namespace, "densetact_stream").map_err(|e| fail("name the node", &e))?,
                NodeOptions::new(),
            )
            .map_err(|e| fail("create the node", &e))?;
        // Reliable, which both reliable and best-effort subscribers (rviz2, `ros2 topic echo`)
        // accept, keeping the last message only; a subscriber too slow to acknowledge makes a
        // message unsent (counted), never a stalled stream.
        let qos = QosProfile::publisher_default().reliability(Reliability::Reliable { when_full: WhenFull::Fail });
        let topic = |name: &str, package: &str, type_name: &str| {
            let topic_name = Name::new(namespace, name).map_err(|e| fail("name a topic", &e))?;
            node.create_topic(&topic_name, MessageTypeName::new(package, type_name), &qos)
                .map_err(|e| fail("create a topic", &e))
        };
        let (points, depth, contact, wrench, pressure) = (
            topic("points", "sensor_msgs", "PointCloud2")?,
            topic("depth", "sensor_msgs", "Image")?,
            topic("contact", "std_msgs", "String")?,
            topic("wrench", "geometry_msgs", "WrenchStamped")?,
            topic("pressure", "sensor_msgs", "Image")?,
        );
        Ok(Ros2Sink {
            frame_id: frame_id.into(),
            place: format!("under {namespace} in domain {domain_id}"),
            sent: 0,
            unsent: 0,
            points: node.create_publisher(&points, None).map_err(|e| fail("publish points", &e))?,
            depth: node.create_publisher(&depth, None).map_err(|e| fail("publish depth", &e))?,
            contact: node.create_publisher(&contact, None).map_err(|e| fail("publish contact", &e))?,
            wrench: node.create_publisher(&wrench, None).map_err(|e| fail("publish wrench", &e))?,
            pressure: node.create_publisher(&pressure, None).map_err(|e| fail("publish pressure", &e))?,
            _node: node,
        })
    }

    /// Messages handed to DDS, and messages it refused (a subscriber's window full, or another
    /// publish error).
    pub fn counts(&self) -> (u64, u64) {
        (self.sent, self.unsent)
    }
}

impl Sink for Ros2Sink {
    fn frame(&mut self, predictor: &Predictor, result: &FrameResult) -> Result<(), SinkError> {
        // The frame's arrival on the wall clock.
        let arrived = SystemTime::now().checked_sub(result.arrived.elapsed()).unwrap_or_else(SystemTime::now);
        let now = arrived.duration_since(UNIX_EPOCH).unwrap_or_default();
        let header = msg::Header {
            stamp: msg::Time { sec: now.as_secs() as i32, nanosec: now.subsec_nanos() },
            frame_id: self.frame_id.clone(),
        };
        let force = force_messages(result, header.clone());
        let (cloud, image, summary) = messages(predictor, result, header);
        let mut results = vec![
            self.points.publish(cloud).is_ok(),
            self.depth.publish(image).is_ok(),
            self.contact.publish(summary).is_ok(),
        ];
        if let Some((wrench, pressure)) = force {
            results.push(self.wrench.publish(wrench).is_ok());
            results.push(self.pressure.publish(pressure).is_ok());
        }
        let sent = results.iter().filter(|&&ok| ok).count() as u64;
        self.sent += sent;
        self.unsent += results.len() as u64 - sent;
        Ok(())
    }

    fn summary(&self) -> Option<String> {
        Some(format!(
            "ROS 2: {} messages published {}, {} not sent (refused by DDS: a subscriber's window full)",
            self.sent, self.place, self.unsent
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The force messages carry the frame's wrench in N and N m and its pressure in pascals on
    /// the crop's grid, stamped as the other messages; a depth-only frame has none.
    #[test]
    fn force_messages_are_in_ros_units() {
        let side = 3u32;
        let pressure = sensor::PressureMap { size_px: side, pressure_kpa: (0..9).map(|i| i as f32 * 1.5).collect() };
        let wrench = sensor::Wrench { force_n: [0.5, -1.0, -20.0], torque_nmm: [100.0, -50.0, 0.0] };
        let force = crate::Force { pressure, wrench };
        let depth = sensor::DepthMap::zeros(side);
        let cloud = crate::PointCloud::default();
        let image = image::RgbImage::new(side, side);
        let mut result = FrameResult {
            name: "f",
            arrived: std::time::Instant::now(),
            image: &image,
            depth: &depth,
            contact: &[],
            contact_pixels: 0,
            cloud: &cloud,
            network_ran: true,
            force: Some(&force),
        };
        let header = msg::Header { stamp: msg::Time { sec: 5, nanosec: 7 }, frame_id: "tip".into() };
        let (w, image) = force_messages(&result, header.clone()).unwrap();
        assert_eq!(w.header, header);
        assert_eq!((w.wrench.force.x, w.wrench.force.y, w.wrench.force.z), (0.5, -1.0, -20.0));
        assert_eq!((w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z), (0.1, -0.05, 0.0));
        assert_eq!((image.encoding.as_str(), image.width, image.height, image.step), ("32FC1", 3, 3, 12));
        let pa: Vec<f32> = image.data.chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert_eq!(pa, (0..9).map(|i| i as f32 * 1500.0).collect::<Vec<_>>());
        result.force = None;
        assert!(force_messages(&result, header).is_none());
    }
}
