//! ROS 2 out: a subscriber in this process, over DDS on loopback, receives the stream's point
//! cloud, depth image and contact summary, and their fields and values are `predict`'s.
#![cfg(feature = "ros2")]

use crate::common;

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use infer::Predictor;
use infer::stream::ros2_msg::{FLOAT32, Image, PointCloud2};
use infer::stream::{GlobSource, Ros2Sink, Sink, StreamLimits};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile, Subscription};

fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect()
}

#[test]
fn a_subscriber_receives_predicts_cloud_depth_and_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let renderer = common::bundle(&tmp.path().join("bundle"));
    let p = Predictor::load(&tmp.path().join("bundle"), &model::backend::default_device()).unwrap();
    let (_, frame) = common::pressed(&renderer);
    let path = tmp.path().join("pressed.png");
    std::fs::write(&path, sensor::frame::encode_png_rgb(&frame)).unwrap();
    // The untrained network reads little into the frame: the stream's own frame checks the
    // path through `run`, a 1 mm dent on the useful disk checks the values.
    let mut depth = sensor::DepthMap::zeros(570);
    for (d, m) in depth.depth_mm.iter_mut().zip(&p.mask).skip(570 * 260).take(570 * 50) {
        *d = if *m { 1.0 } else { 0.0 };
    }
    let cloud = p.point_cloud(&depth, sensor::CONTACT_THRESHOLD_MM);
    assert!(!cloud.points_mm.is_empty());
    let contact = Predictor::contact_mask(&depth, sensor::CONTACT_THRESHOLD_MM);
    let contact_pixels = contact.iter().filter(|&&c| c).count();
    let dent = infer::stream::FrameResult {
        name: "dent",
        arrived: Instant::now(),
        image: &frame,
        depth: &depth,
        contact: &contact,
        contact_pixels,
        cloud: &cloud,
        network_ran: true,
        force: None,
    };

    // A domain and a namespace of this run's own, so that other DDS traffic cannot answer.
    let namespace = format!("/densetact_test_{}", std::process::id());
    let domain = 1 + (std::process::id() % 100) as u16;
    let context = Context::with_options(ContextOptions::new().domain_id(domain)).unwrap();
    let mut node = context.new_node(NodeName::new(&namespace, "listener").unwrap(), NodeOptions::new()).unwrap();
    let qos = QosProfile::publisher_default();
    let topic = |node: &mut ros2_client::Node, name: &str, package: &str, ty: &str| {
        node.create_topic(&Name::new(&namespace, name).unwrap(), MessageTypeName::new(package, ty), &qos).unwrap()
    };
    let (tp, td, tc) = (
        topic(&mut node, "points", "sensor_msgs", "PointCloud2"),
        topic(&mut node, "depth", "sensor_msgs", "Image"),
        topic(&mut node, "contact", "std_msgs", "String"),
    );
    let points: Subscription<PointCloud2> = node.create_subscription(&tp, None).unwrap();
    let depth_sub: Subscription<Image> = node.create_subscription(&td, None).unwrap();
    let contact: Subscription<String> = node.create_subscription(&tc, None).unwrap();

    let mut sink = Ros2Sink::new(&namespace, "fingertip", domain).unwrap();
    // What must arrive: the streamed frame's depth as `predict` gives it, and the dent's cloud,
    // depth and summary. Messages are matched by content, each kind kept as it arrives.
    let metres = |d: &sensor::DepthMap| d.depth_mm.iter().map(|mm| mm / 1000.0).collect::<Vec<f32>>();
    let streamed_m = metres(&p.predict(&p.read_frame(&path).unwrap()).unwrap());
    let dent_m = metres(&depth);
    let (mut clouds, mut images, mut summaries) = (Vec::new(), Vec::new(), Vec::new());
    let has = |images: &[Image], want: &[f32]| images.iter().any(|m| f32s(&m.data) == want);
    let dent_cloud_m: Vec<f32> = cloud.points_mm.iter().flatten().map(|mm| mm / 1000.0).collect();
    let dent_cloud = |clouds: &[PointCloud2]| clouds.iter().find(|m| f32s(&m.data) == dent_cloud_m).cloned();
    let dent_summary = |summaries: &[String]| summaries.iter().find(|m| m.contains("\"dent\"")).cloned();
    let start = Instant::now();
    let mut rounds = 0;
    // Discovery takes a moment: the frame and the dent are sent again until everything arrives.
    while !(has(&images, &streamed_m) && has(&images, &dent_m))
        || dent_cloud(&clouds).is_none()
        || dent_summary(&summaries).is_none()
    {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "not received over DDS within 20 s: {} clouds, {} images, {} summaries",
            clouds.len(),
            images.len(),
            summaries.len()
        );
        let source = GlobSource::new(path.to_str().unwrap(), None).unwrap();
        let mut sinks: Vec<&mut dyn Sink> = vec![&mut sink];
        let report =
            infer::stream::run(&p, Box::new(source), &mut sinks, &StreamLimits::default(), &AtomicBool::new(false));
        assert_eq!(report.unwrap().processed, 1);
        sink.frame(&p, &dent).unwrap();
        rounds += 1;
        std::thread::sleep(Duration::from_millis(200));
        while let Some((m, _)) = points.take().unwrap() {
            clouds.push(m);
        }
        while let Some((m, _)) = depth_sub.take().unwrap() {
            images.push(m);
        }
        while let Some((m, _)) = contact.take().unwrap() {
            summaries.push(m);
        }
    }
    let (cloud_msg, summary) = (dent_cloud(&clouds).unwrap(), dent_summary(&summaries).unwrap());
    let image = images.iter().find(|m| f32s(&m.data) == dent_m).unwrap();
    // The streamed frame's summary names its file.
    assert!(summaries.iter().any(|m| m.contains(&serde_json::to_string(path.to_str().unwrap()).unwrap())));

    assert_eq!(cloud_msg.header.frame_id, "fingertip");
    assert!(cloud_msg.header.stamp.sec > 1_700_000_000, "stamped with the wall clock");
    let names: Vec<&str> = cloud_msg.fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["x", "y", "z"]);
    assert!(cloud_msg.fields.iter().all(|f| f.datatype == FLOAT32 && f.count == 1));
    assert_eq!((cloud_msg.height, cloud_msg.width as usize, cloud_msg.point_step), (1, cloud.points_mm.len(), 12));
    assert_eq!(cloud_msg.row_step, 12 * cloud_msg.width);
    // Metres, as ROS expects: the values are the predictor's cloud's (matched above).
    assert_eq!(f32s(&cloud_msg.data).len(), 3 * cloud.points_mm.len());

    assert_eq!((image.encoding.as_str(), image.width, image.height, image.step), ("32FC1", 570, 570, 4 * 570));
    assert!(images.iter().all(|m| m.header.frame_id == "fingertip" && m.encoding == "32FC1"));

    let summary: serde_json::Value = serde_json::from_str(&summary).unwrap();
    assert_eq!(summary["frame"], "dent");
    assert_eq!(summary["contact_pixels"], contact_pixels);
    assert_eq!(summary["network_ran"], true);
    // Three messages a frame, two frames a round.
    let (sent, unsent) = sink.counts();
    assert_eq!(sent + unsent, 6 * rounds);
    assert!(sent >= 6, "{sent} sent, {unsent} not sent");
    assert!(sink.summary().unwrap().contains(&format!("under {namespace} in domain {domain}")));
}
