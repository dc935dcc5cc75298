//! What a stream measured: throughput, drops and latency percentiles, per frame and in all.

use std::time::Duration;

use serde::Serialize;

use super::mailbox::Counts;
use super::source::Delivery;

/// One processed frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    pub name: String,
    /// Arrival, seconds after the stream started.
    pub arrived_s: f64,
    /// Arrival to results handed to every sink.
    pub latency_ms: f64,
    pub network_ran: bool,
    pub contact_pixels: usize,
    pub max_depth_mm: f32,
    /// The contact force (N, sensor frame), from a bundle with the force output.
    pub fx_n: Option<f64>,
    pub fy_n: Option<f64>,
    pub fz_n: Option<f64>,
}

/// Percentiles of a set of times (ms), by the project's one quantile rule
/// (`formats::stats`: numpy's); all zero for an empty set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    pub count: usize,
    pub mean: f64,
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
}

impl Percentiles {
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let v = formats::stats::sorted(values);
        if v.is_empty() {
            return Percentiles::default();
        }
        let rank = |p: f64| formats::stats::quantile_sorted(&v, p);
        Percentiles {
            count: v.len(),
            mean: v.iter().sum::<f64>() / v.len() as f64,
            p50: rank(0.5),
            p90: rank(0.9),
            p99: rank(0.99),
            max: v[v.len() - 1],
        }
    }
}

/// A stream's summary (`stream.json`), its per-frame records beside it (`frames.csv`).
#[derive(Clone, Debug, Serialize)]
pub struct StreamReport {
    pub source: String,
    /// `live` (stale frames dropped) or `every` (the source waited).
    pub delivery: Delivery,
    /// Frames that arrived: processed, dropped, unreadable, or left when the stream stopped.
    pub arrived: u64,
    pub processed: u64,
    /// Stale frames dropped for newer ones: the network fell behind the source.
    pub dropped: u64,
    pub unreadable: u64,
    /// The first problems, each naming its frame.
    pub problems: Vec<String>,
    /// Frames the network ran on (the others the contact gate answered).
    pub network_runs: u64,
    pub wall_s: f64,
    /// Processed frames per second of wall time.
    pub throughput_fps: f64,
    /// Arrivals (dropped and unreadable ones too) per second of wall time.
    pub arrival_fps: f64,
    /// Frame in to result out, every processed frame.
    pub latency_ms: Percentiles,
    /// The same, frames the network ran on.
    pub network_latency_ms: Percentiles,
    /// The same, frames the gate answered without the network.
    pub gated_latency_ms: Percentiles,
    /// Whether the reference frame followed the camera (the default; false with
    /// `--fixed-reference` or a bundle without a reference frame).
    pub reference_follows: bool,
    /// Times the reference frame moved towards the untouched frames.
    pub reference_updates: u64,
    /// How long the network's CPU workers kept polling for work after each frame
    /// (`--spin-ms`; 0: they slept), which the latencies depend on.
    pub spin_ms: f64,
    #[serde(skip)]
    pub frames: Vec<FrameRecord>,
}

impl StreamReport {
    pub(crate) fn new(source: String, delivery: Delivery) -> Self {
        StreamReport {
            source,
            delivery,
            arrived: 0,
            processed: 0,
            dropped: 0,
            unreadable: 0,
            problems: Vec::new(),
            network_runs: 0,
            wall_s: 0.0,
            throughput_fps: 0.0,
            arrival_fps: 0.0,
            latency_ms: Percentiles::default(),
            network_latency_ms: Percentiles::default(),
            gated_latency_ms: Percentiles::default(),
            reference_follows: false,
            reference_updates: 0,
            spin_ms: model::backend::spin().as_secs_f64() * 1e3,
            frames: Vec::new(),
        }
    }

    pub(crate) fn update(&mut self, records: &[FrameRecord], counts: &Counts, wall: Duration) {
        self.arrived = counts.arrived;
        self.processed = records.len() as u64;
        self.dropped = counts.dropped;
        self.unreadable = counts.unreadable;
        self.problems = counts.problems.clone();
        self.network_runs = records.iter().filter(|r| r.network_ran).count() as u64;
        self.wall_s = wall.as_secs_f64();
        self.throughput_fps = if self.wall_s > 0.0 { self.processed as f64 / self.wall_s } else { 0.0 };
        self.arrival_fps = if self.wall_s > 0.0 { self.arrived as f64 / self.wall_s } else { 0.0 };
        self.latency_ms = Percentiles::of(records.iter().map(|r| r.latency_ms));
        self.network_latency_ms = Percentiles::of(records.iter().filter(|r| r.network_ran).map(|r| r.latency_ms));
        self.gated_latency_ms = Percentiles::of(records.iter().filter(|r| !r.network_ran).map(|r| r.latency_ms));
    }

    pub fn progress_line(&self) -> String {
        format!(
            "{:.1} s: {} frames, {:.1} fps, {} dropped, {} unreadable; latency p50 {:.1} ms, p99 {:.1} ms",
            self.wall_s,
            self.processed,
            self.throughput_fps,
            self.dropped,
            self.unreadable,
            self.latency_ms.p50,
            self.latency_ms.p99
        )
    }

    /// The summary for people.
    pub fn summary(&self) -> String {
        let line = |what: &str, p: &Percentiles| {
            format!(
                "  {what:<22} {:>6} frames  p50 {:7.2}  p90 {:7.2}  p99 {:7.2}  max {:7.2}  mean {:7.2} ms",
                p.count, p.p50, p.p90, p.p99, p.max, p.mean
            )
        };
        [
            format!("source: {} ({})", self.source, self.delivery.name()),
            format!(
                "{} frames arrived, {} processed ({} by the network, {} answered by the contact gate), {} dropped as \
                 stale, {} unreadable",
                self.arrived,
                self.processed,
                self.network_runs,
                self.processed - self.network_runs,
                self.dropped,
                self.unreadable
            ),
            format!(
                "throughput {:.2} fps over {:.2} s (arrivals {:.2} fps); latency, frame in to result out:",
                self.throughput_fps, self.wall_s, self.arrival_fps
            ),
            line("all", &self.latency_ms),
            line("network ran", &self.network_latency_ms),
            line("gate (no contact)", &self.gated_latency_ms),
            match self.reference_follows {
                true => format!(
                    "reference frame followed the camera: updated {} times from untouched frames",
                    self.reference_updates
                ),
                false => "reference frame: the bundle's throughout (--fixed-reference, or none to follow)".into(),
            },
        ]
        .into_iter()
        .chain(self.problems.iter().map(|p| format!("  problem: {p}")))
        .collect::<Vec<_>>()
        .join("\n")
    }

    /// `frames.csv`: one row a processed frame.
    pub fn frames_csv(&self) -> Vec<u8> {
        let mut out = csv::Writer::from_writer(Vec::new());
        for r in &self.frames {
            out.serialize(r).expect("records serialise");
        }
        out.into_inner().expect("in memory")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate_as_numpy_does() {
        // numpy.percentile(range(1, 101), [50, 90, 99]) = 50.5, 90.1, 99.01
        let p = Percentiles::of((1..=100).map(f64::from));
        assert_eq!((p.count, p.max, p.mean), (100, 100.0, 50.5));
        for (got, want) in [(p.p50, 50.5), (p.p90, 90.1), (p.p99, 99.01)] {
            assert!((got - want).abs() < 1e-9, "{got} against {want}");
        }
        // Order does not matter; a single value is every percentile.
        let p = Percentiles::of([3.0, 1.0, 2.0]);
        assert!((p.p50, p.max) == (2.0, 3.0) && (p.p90 - 2.8).abs() < 1e-12);
        assert_eq!(Percentiles::of([7.5]).p99, 7.5);
        assert_eq!(Percentiles::of([]), Percentiles::default());
    }

    #[test]
    fn rates_and_splits_follow_the_records() {
        let record = |i: usize, ran: bool| FrameRecord {
            name: format!("{i}"),
            arrived_s: i as f64 * 0.1,
            latency_ms: if ran { 20.0 } else { 2.0 },
            network_ran: ran,
            contact_pixels: 0,
            max_depth_mm: 0.0,
            fx_n: None,
            fy_n: None,
            fz_n: None,
        };
        // Frames 0, 2, 4, ..., 10 processed (every other one dropped); 2, 6 and 10 ran the network.
        let records: Vec<FrameRecord> = (0..=10).step_by(2).map(|i| record(i, i % 4 == 2)).collect();
        let counts = Counts { arrived: 11, dropped: 5, unreadable: 0, problems: vec![] };
        let mut report = StreamReport::new("test".into(), Delivery::Live);
        report.update(&records, &counts, Duration::from_secs(2));
        assert_eq!((report.processed, report.network_runs, report.dropped), (6, 3, 5));
        assert!((report.throughput_fps - 3.0).abs() < 1e-12);
        assert!((report.arrival_fps - 5.5).abs() < 1e-12, "{}", report.arrival_fps);
        assert_eq!((report.network_latency_ms.count, report.network_latency_ms.max), (3, 20.0));
        assert_eq!((report.gated_latency_ms.count, report.gated_latency_ms.max), (3, 2.0));
        report.frames = records;
        let csv = String::from_utf8(report.frames_csv()).unwrap();
        assert_eq!(csv.lines().count(), 7);
        // The force columns stay empty for a bundle without the force output.
        let header = "name,arrived_s,latency_ms,network_ran,contact_pixels,max_depth_mm,fx_n,fy_n,fz_n\n";
        assert!(csv.starts_with(header) && csv.lines().nth(1).unwrap().ends_with(",,,"), "{csv}");
    }
}
