//! SVG figures drawn with plotters: the paper's violin plot of per-image error, and the
//! run-time-versus-error scatter of the benchmark table.

use anyhow::{Result, anyhow};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use formats::stats::Summary;

/// The uncertainty of 3D-printed ground truth (mm), drawn on the violin plot as in the paper.
pub const GROUND_TRUTH_UNCERTAINTY_MM: f64 = 0.11;

const PALETTE: [RGBColor; 6] = [
    RGBColor(0x4c, 0x72, 0xb0),
    RGBColor(0xdd, 0x84, 0x52),
    RGBColor(0x55, 0xa8, 0x68),
    RGBColor(0xc4, 0x4e, 0x52),
    RGBColor(0x81, 0x72, 0xb3),
    RGBColor(0x93, 0x78, 0x60),
];
const UNCERTAINTY: RGBColor = RGBColor(0xcc, 0, 0);

fn err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("drawing the SVG: {e}")
}

/// Gaussian kernel density of `sorted` at `steps + 1` points spanning it, Silverman's bandwidth
/// (at least `min_bw`): (value, density scaled to a peak of 1).
fn density(sorted: &[f64], min_bw: f64, steps: usize) -> Vec<(f64, f64)> {
    let s = Summary::of(sorted.iter().copied());
    let bw = (1.06 * s.sd.max(1e-9) * (sorted.len() as f64).powf(-0.2)).max(min_bw);
    let (lo, hi) = ((s.min - 2.0 * bw).max(0.0), s.max + 2.0 * bw);
    let dens: Vec<(f64, f64)> = (0..=steps)
        .map(|k| {
            let t = lo + (hi - lo) * k as f64 / steps as f64;
            (t, sorted.iter().map(|x| (-0.5 * ((t - x) / bw).powi(2)).exp()).sum::<f64>())
        })
        .collect();
    let peak = dens.iter().map(|d| d.1).fold(0.0, f64::max).max(1e-300);
    dens.into_iter().map(|(t, d)| (t, d / peak)).collect()
}

/// What a violin plot shows: its caption, its value axis, and a dashed reference line.
pub struct ViolinAxis {
    pub caption: &'static str,
    pub y_desc: &'static str,
    /// The line's value and its label.
    pub reference: (f64, String),
}

impl ViolinAxis {
    /// Per-image depth L1 (mm) against the ground truth's uncertainty, as in the paper.
    pub fn depth() -> Self {
        ViolinAxis {
            caption: "Per-image mean L1 error over useful pixels",
            y_desc: "L1 (mm)",
            reference: (
                GROUND_TRUTH_UNCERTAINTY_MM,
                format!("ground-truth uncertainty {GROUND_TRUTH_UNCERTAINTY_MM} mm"),
            ),
        }
    }

    /// Per-image force error (N) against DenseTact 2.0's reported 0.41 N.
    pub fn force() -> Self {
        ViolinAxis {
            caption: "Per-image contact force error |F - F_true|",
            y_desc: "force error (N)",
            reference: (DENSETACT2_FORCE_ERROR_N, format!("DenseTact 2.0: {DENSETACT2_FORCE_ERROR_N} N")),
        }
    }
}

/// The force error DenseTact 2.0 reports (N), the figure this sensor's force is read against.
pub const DENSETACT2_FORCE_ERROR_N: f64 = 0.41;

/// A violin per named split of per-image L1 (mm): density outline, quartile bar, median dot and
/// mean tick, with the ground truth's uncertainty as a dashed line, as in the paper's figure.
pub fn violin_svg(groups: &[(&str, Vec<f64>)]) -> Result<String> {
    violin_svg_on(groups, &ViolinAxis::depth())
}

/// [`violin_svg`] on another axis.
pub fn violin_svg_on(groups: &[(&str, Vec<f64>)], axis: &ViolinAxis) -> Result<String> {
    let all = groups.iter().flat_map(|g| g.1.iter().copied()).filter(|v| v.is_finite());
    let y_max = all.fold(axis.reference.0, f64::max) * 1.15;
    let n = groups.len().max(1) as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 440)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(axis.caption, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..n, 0.0..y_max)
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc(axis.y_desc)
            .y_label_formatter(&|v| format!("{v:.3}"))
            .draw()
            .map_err(err)?;
        for (g, (name, values)) in groups.iter().enumerate() {
            let cx = g as f64 + 0.5;
            let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
            v.sort_by(f64::total_cmp);
            let colour = PALETTE[g % PALETTE.len()];
            let (lx, ly) = chart.backend_coord(&(cx, 0.0));
            let label = format!("{name} (n = {})", v.len());
            let style = ("sans-serif", 14).into_font().into_text_style(&root).pos(Pos::new(HPos::Center, VPos::Top));
            root.draw(&Text::new(label, (lx, ly + 10), style)).map_err(err)?;
            if v.is_empty() {
                continue;
            }
            let half = 0.4;
            let dens = density(&v, y_max * 0.01, 80);
            let outline: Vec<(f64, f64)> = dens
                .iter()
                .map(|&(t, d)| (cx + half * d, t))
                .chain(dens.iter().rev().map(|&(t, d)| (cx - half * d, t)))
                .collect();
            chart.draw_series(std::iter::once(Polygon::new(outline.clone(), colour.mix(0.55)))).map_err(err)?;
            chart.draw_series(std::iter::once(PathElement::new(outline, colour.stroke_width(1)))).map_err(err)?;
            let s = Summary::of(v.iter().copied());
            chart
                .draw_series(std::iter::once(PathElement::new(vec![(cx, s.q1), (cx, s.q3)], BLACK.stroke_width(4))))
                .map_err(err)?;
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(cx - half * 0.5, s.mean), (cx + half * 0.5, s.mean)],
                    BLACK.stroke_width(1),
                )))
                .map_err(err)?;
            chart.draw_series(std::iter::once(Circle::new((cx, s.median), 4, WHITE.filled()))).map_err(err)?;
            chart.draw_series(std::iter::once(Circle::new((cx, s.median), 4, BLACK.stroke_width(1)))).map_err(err)?;
            chart
                .draw_series(std::iter::once(Text::new(
                    format!("mean {:.3}", s.mean),
                    (cx + half * 0.55, s.mean),
                    ("sans-serif", 13).into_font().into_text_style(&root).pos(Pos::new(HPos::Left, VPos::Center)),
                )))
                .map_err(err)?;
        }
        let u = axis.reference.0;
        chart
            .draw_series(DashedLineSeries::new(vec![(0.0, u), (n, u)], 6, 4, UNCERTAINTY.stroke_width(1)))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Text::new(
                axis.reference.1.clone(),
                (0.02, u),
                ("sans-serif", 13)
                    .into_font()
                    .into_text_style(&root)
                    .color(&UNCERTAINTY)
                    .pos(Pos::new(HPos::Left, VPos::Bottom)),
            )))
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(svg)
}

/// One measured configuration on the run-time-versus-error scatter.
#[derive(Clone, Debug)]
pub struct ScatterPoint {
    /// Legend group (a backend), one colour each.
    pub group: String,
    pub label: String,
    pub ms: f64,
    pub l1_mm: f64,
    /// Spread of the error over training seeds, drawn as a bar of +-1 sd (0: none).
    pub sd_mm: f64,
}

/// Run time (ms per frame, log axis) against error (mm, `y_desc` says which): the measured
/// points by group with their seed spread, the Pareto front joined by a line, and a reference
/// point (the paper's) marked apart where it measures the same error.
pub fn scatter_svg(
    points: &[ScatterPoint],
    front: &[usize],
    y_desc: &str,
    reference: Option<(&str, f64, f64)>,
) -> Result<String> {
    let xs = points.iter().map(|p| p.ms).chain(reference.map(|r| r.1)).filter(|v| v.is_finite() && *v > 0.0);
    let (x_lo, x_hi) = xs.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    let (x_lo, x_hi) = if x_hi > 0.0 { (x_lo / 2.0, x_hi * 2.0) } else { (0.1, 10.0) };
    let y_hi = points
        .iter()
        .map(|p| p.l1_mm + p.sd_mm.max(0.0))
        .chain(reference.map(|r| r.2))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        * 1.2;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Run time against test error (same training budget)", ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(64)
            .build_cartesian_2d((x_lo..x_hi).log_scale(), 0.0..y_hi.max(1e-3))
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("median ms per frame (log)")
            .y_desc(y_desc)
            .y_label_formatter(&|v| format!("{v:.2}"))
            .draw()
            .map_err(err)?;
        let mut groups: Vec<&str> = points.iter().map(|p| p.group.as_str()).collect();
        groups.sort();
        groups.dedup();
        for (g, name) in groups.iter().enumerate() {
            let colour = PALETTE[g % PALETTE.len()];
            let mine: Vec<&ScatterPoint> = points.iter().filter(|p| p.group == *name).collect();
            chart
                .draw_series(mine.iter().map(|p| Circle::new((p.ms, p.l1_mm), 5, colour.filled())))
                .map_err(err)?
                .label(name.to_string())
                .legend(move |(x, y)| Circle::new((x, y), 5, colour.filled()));
            chart.draw_series(mine.iter().map(|p| label_at(p, &root))).map_err(err)?;
            let bars = mine.iter().filter(|p| p.sd_mm > 0.0).map(|p| {
                PathElement::new(vec![(p.ms, p.l1_mm - p.sd_mm), (p.ms, p.l1_mm + p.sd_mm)], colour.stroke_width(2))
            });
            chart.draw_series(bars).map_err(err)?;
        }
        let mut line: Vec<(f64, f64)> = front.iter().map(|&i| (points[i].ms, points[i].l1_mm)).collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(std::iter::once(PathElement::new(line, BLACK.stroke_width(1))))
            .map_err(err)?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], BLACK.stroke_width(1)));
        if let Some((name, ms, l1)) = reference {
            chart
                .draw_series(std::iter::once(Cross::new((ms, l1), 7, UNCERTAINTY.stroke_width(2))))
                .map_err(err)?
                .label(name.to_string())
                .legend(|(x, y)| Cross::new((x, y), 5, UNCERTAINTY.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(svg)
}

fn label_at<'a, DB: DrawingBackend>(
    p: &'a ScatterPoint,
    root: &DrawingArea<DB, plotters::coord::Shift>,
) -> Text<'a, (f64, f64), String> {
    let style = ("sans-serif", 11).into_font().into_text_style(root).pos(Pos::new(HPos::Left, VPos::Bottom));
    Text::new(format!(" {}", p.label), (p.ms, p.l1_mm), style)
}

/// Indices of the (run time, error) points that no other point beats: no slower, and no worse
/// by more than `error_tol` (errors closer than that, a backend's rounding say, count as equal).
pub fn pareto_front(points: &[(f64, f64)], error_tol: f64) -> Vec<usize> {
    let beats =
        |(t2, e2): (f64, f64), (t, e): (f64, f64)| t2 <= t && e2 <= e + error_tol && (t2 < t || e2 < e - error_tol);
    (0..points.len())
        .filter(|&i| {
            let (t, e) = points[i];
            t.is_finite() && e.is_finite() && !points.iter().any(|&other| beats(other, (t, e)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn violin_draws_a_violin_per_split_and_the_uncertainty_line() {
        let svg = violin_svg(&[("train", vec![0.2, 0.25, 0.3]), ("test", vec![0.28, 0.31])]).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("train (n = 3)") && svg.contains("test (n = 2)"));
        assert!(svg.contains("ground-truth uncertainty"));
        assert_eq!(svg.matches("<polygon").count(), 2);
        // An empty split is labelled and drawn without a violin.
        let svg = violin_svg(&[("train", vec![]), ("test", vec![0.1])]).unwrap();
        assert!(svg.contains("train (n = 0)"));
        assert_eq!(svg.matches("<polygon").count(), 1);
    }

    #[test]
    fn density_peaks_at_the_data() {
        let d = density(&[1.0, 1.0, 1.0], 0.05, 40);
        let (at_peak, _) = d.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
        assert!((at_peak - 1.0).abs() < 0.01, "{at_peak}");
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        // (ms, mm): the second is slower and worse than the first; the last equals the third.
        let pts = [(10.0, 0.2), (20.0, 0.3), (5.0, 0.4), (40.0, 0.1), (5.0, 0.4), (f64::NAN, 0.0)];
        assert_eq!(pareto_front(&pts, 0.0), vec![0, 2, 3, 4]);
        // A slower twin a hair more accurate is beaten within the tolerance, not without it.
        let twins = [(10.0, 0.2), (90.0, 0.2 - 1e-6)];
        assert_eq!(pareto_front(&twins, 1e-4), vec![0]);
        assert_eq!(pareto_front(&twins, 0.0), vec![0, 1]);
    }

    #[test]
    fn scatter_has_every_point_the_front_and_the_reference() {
        let points: Vec<ScatterPoint> = [("flex", "a", 10.0, 0.2), ("flex", "b", 20.0, 0.3), ("wgpu", "a", 5.0, 0.25)]
            .iter()
            .map(|&(g, l, ms, l1)| ScatterPoint { group: g.into(), label: l.into(), ms, l1_mm: l1, sd_mm: 0.0 })
            .collect();
        let front = pareto_front(&points.iter().map(|p| (p.ms, p.l1_mm)).collect::<Vec<_>>(), 0.0);
        assert_eq!(front, vec![0, 2]);
        let svg = scatter_svg(&points, &front, "test L1 (mm)", Some(("paper (GPU)", 18.17, 0.281))).unwrap();
        assert_eq!(svg.matches("<circle").count(), 3 + 2, "three points and two legend marks");
        for text in ["Pareto front", "paper (GPU)", "flex", "wgpu", "test L1 (mm)"] {
            assert!(svg.contains(text), "{text}");
        }
        // A seed spread adds one bar per point that has one; no reference, no reference's legend.
        let lines = |svg: &str| svg.matches("<polyline").count();
        let mut spread = points.clone();
        spread[1].sd_mm = 0.02;
        let with_bar = scatter_svg(&spread, &front, "contact L1 (mm)", None).unwrap();
        let without = scatter_svg(&points, &front, "contact L1 (mm)", None).unwrap();
        assert_eq!(lines(&with_bar), lines(&without) + 1);
        assert!(!without.contains("paper (GPU)"));
    }
}
