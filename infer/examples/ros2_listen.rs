//! A ROS 2 listener without ROS: subscribes to `infer stream --ros2`'s topics and prints, every
//! 5 s and at the end, the message rates and the delay from a frame's arrival (the messages'
//! stamp) to a cloud's arrival here. For checking a robot's network, and for measuring the
//! stream with a subscriber attached.
//!
//! ```sh
//! cargo run --release -p infer --features ros2 --example ros2_listen -- [NAMESPACE] [SECONDS] [DOMAIN]
//! ```
//!
//! Defaults: `/densetact`, 30 s, `$ROS_DOMAIN_ID` or 0.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use infer::stream::ros2_msg::{Image, PointCloud2};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile};

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let namespace = args.first().cloned().unwrap_or_else(|| "/densetact".into());
    let seconds: f64 = args.get(1).map_or(Ok(30.0), |s| s.parse()).map_err(|e| format!("SECONDS: {e}"))?;
    // As `infer stream --ros2`: the domain given, else $ROS_DOMAIN_ID, else 0.
    let domain_text =
        args.get(2).cloned().or_else(|| std::env::var("ROS_DOMAIN_ID").ok().filter(|v| !v.trim().is_empty()));
    let domain: u16 =
        domain_text.map_or(Ok(0), |s| s.trim().parse()).map_err(|e| format!("DOMAIN or ROS_DOMAIN_ID: {e}"))?;
    let fail = |e: &dyn std::fmt::Debug| format!("ROS 2: {e:?}");
    let context = Context::with_options(ContextOptions::new().domain_id(domain)).map_err(|e| fail(&e))?;
    let mut node = context
        .new_node(NodeName::new(&namespace, "densetact_listener").map_err(|e| fail(&e))?, NodeOptions::new())
        .map_err(|e| fail(&e))?;
    // Reliable, as the publisher offers: every message the network carries is seen.
    let qos = QosProfile::publisher_default();
    let topic = |name: &str, package: &str, ty: &str| {
        let name = Name::new(&namespace, name).map_err(|e| fail(&e))?;
        node.create_topic(&name, MessageTypeName::new(package, ty), &qos).map_err(|e| fail(&e))
    };
    let (tp, td, tc) = (
        topic("points", "sensor_msgs", "PointCloud2")?,
        topic("depth", "sensor_msgs", "Image")?,
        topic("contact", "std_msgs", "String")?,
    );
    let points = node.create_subscription::<PointCloud2>(&tp, None).map_err(|e| fail(&e))?;
    let depth = node.create_subscription::<Image>(&td, None).map_err(|e| fail(&e))?;
    let contact = node.create_subscription::<String>(&tc, None).map_err(|e| fail(&e))?;
    eprintln!("listening under {namespace} in domain {domain} for {seconds} s");

    let (mut n_points, mut n_depth, mut n_contact, mut n_cloud_points) = (0u64, 0u64, 0u64, 0u64);
    let mut delays_ms = Vec::new();
    let (start, mut last_print) = (Instant::now(), Instant::now());
    // The first and the latest cloud's arrival: rates are over that span.
    let mut first: Option<Instant> = None;
    let mut last = Instant::now();
    let report = |delays: &mut Vec<f64>, clouds: u64, images: u64, summaries: u64, points: u64, over_s: f64| {
        if clouds + images + summaries == 0 {
            println!("nothing received yet (is `infer stream --ros2` running, in this namespace and domain?)");
            return;
        }
        delays.sort_by(f64::total_cmp);
        let q = |p: f64| delays.get(((delays.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN);
        println!(
            "{clouds} clouds ({:.1}/s, {points} points), {images} depth images ({:.1}/s), {summaries} summaries; \
             frame in to cloud here: p50 {:.1} p90 {:.1} p99 {:.1} max {:.1} ms",
            clouds as f64 / over_s,
            images as f64 / over_s,
            q(0.5),
            q(0.9),
            q(0.99),
            delays.last().copied().unwrap_or(f64::NAN)
        );
    };
    while start.elapsed().as_secs_f64() < seconds {
        let mut idle = true;
        while let Some((m, _)) = points.take().map_err(|e| fail(&e))? {
            let now = SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default().as_secs_f64();
            let stamp = m.header.stamp.sec as f64 + m.header.stamp.nanosec as f64 * 1e-9;
            delays_ms.push((now - stamp) * 1e3);
            n_points += 1;
            n_cloud_points += m.width as u64;
            first.get_or_insert_with(Instant::now);
            last = Instant::now();
            idle = false;
        }
        while depth.take().map_err(|e| fail(&e))?.is_some() {
            n_depth += 1;
            idle = false;
        }
        while contact.take().map_err(|e| fail(&e))?.is_some() {
            n_contact += 1;
            idle = false;
        }
        if last_print.elapsed() >= Duration::from_secs(5) {
            last_print = Instant::now();
            let over = first.map_or(f64::NAN, |f| last.duration_since(f).as_secs_f64());
            report(&mut delays_ms.clone(), n_points, n_depth, n_contact, n_cloud_points, over);
        }
        if idle {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    let over = first.map_or(f64::NAN, |f| last.duration_since(f).as_secs_f64());
    report(&mut delays_ms, n_points, n_depth, n_contact, n_cloud_points, over);
    Ok(())
}
