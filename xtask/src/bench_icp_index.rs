//! ICP's nearest-neighbour index (`infer::kdtree::KdTree`, our own) against kiddo's immutable
//! k-d tree, the maintained crate issue 46 asked us to consider, on the clouds the pinch example
//! writes: the tree over the 100,000-point ball, then one query per seen point at ICP's first
//! pose (the guess) and at its last (converged), with the example's correspondence radius.
//! Both sides in one process, one thread, median of `--reps`; every answer compared.

use std::path::PathBuf;

use anyhow::{Context, Result};
use infer::cloud::read_ply;
use infer::kdtree::KdTree;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix4, Point3};

use crate::timing::time;

#[derive(clap::Args)]
pub struct Args {
    /// The folder `cargo run --release -p infer --example pinch -- --out DIR` wrote.
    #[arg(long)]
    pinch: PathBuf,
    #[arg(long, default_value_t = 21)]
    reps: usize,
}

/// A nearest point strictly within the radius: (index, squared distance).
type Found = Option<(usize, f64)>;

pub fn run(args: Args) -> Result<()> {
    let points = |name: &str| -> Result<Vec<Point3<f64>>> {
        let cloud = read_ply(&args.pinch.join(name))?;
        Ok(cloud.points_mm.iter().map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect())
    };
    let (source, target) = (points("source.ply")?, points("target.ply")?);
    let json_path = args.pinch.join("icp.json");
    let text = std::fs::read_to_string(&json_path).with_context(|| json_path.display().to_string())?;
    let json: serde_json::Value = serde_json::from_str(&text).with_context(|| json_path.display().to_string())?;
    let radius_mm = json["max_correspondence_distance_mm"].as_f64().context("icp.json: no radius")?;
    let pose = |key: &str| -> Result<Matrix4<f64>> {
        let rows: Vec<Vec<f64>> =
            serde_json::from_value(json[key].clone()).with_context(|| format!("icp.json: {key}"))?;
        anyhow::ensure!(rows.len() == 4 && rows.iter().all(|r| r.len() == 4), "icp.json: {key} is not 4x4");
        Ok(Matrix4::from_fn(|r, c| rows[r][c]))
    };
    println!(
        "{} target points, {} queries per pose, radius {radius_mm} mm, median of {} runs, one thread",
        target.len(),
        source.len(),
        args.reps
    );

    let coords: Vec<[f64; 3]> = target.iter().map(|p| [p.x, p.y, p.z]).collect();
    let (ours_build_s, ours) = time(args.reps, || KdTree::new(&target));
    let (kiddo_build_s, theirs) = time(args.reps, || ImmutableKdTree::<f64, 3>::new_from_slice(&coords).unwrap());
    println!("| step | ours | kiddo 6.3 | same answers |");
    println!("|---|---:|---:|---:|");
    println!("| build | {:.2} ms | {:.2} ms | |", ours_build_s * 1e3, kiddo_build_s * 1e3);
    for key in ["init", "transform"] {
        let m = pose(key)?;
        let queries: Vec<Point3<f64>> =
            source.iter().map(|p| Point3::from_homogeneous(m * p.to_homogeneous()).unwrap()).collect();
        let (ours_s, a) =
            time(args.reps, || queries.iter().map(|q| ours.nearest_within(q, radius_mm)).collect::<Vec<Found>>());
        let (kiddo_s, b) = time(args.reps, || {
            queries
                .iter()
                .map(|q| {
                    let n = theirs.query(&[q.x, q.y, q.z]).nearest_one::<SquaredEuclidean<f64>>().execute();
                    (n.distance < radius_mm * radius_mm).then_some((n.item as usize, n.distance))
                })
                .collect::<Vec<Found>>()
        });
        // The same squared distance is the same answer; the index may differ only on a tie.
        let same = a.iter().zip(&b).filter(|(x, y)| x.map(|v| v.1) == y.map(|v| v.1)).count();
        let pose_name = if key == "init" { "first pose" } else { "last pose" };
        println!(
            "| queries at ICP's {pose_name} ({} within) | {:.3} ms | {:.3} ms | {same}/{} |",
            a.iter().flatten().count(),
            ours_s * 1e3,
            kiddo_s * 1e3,
            a.len()
        );
    }
    Ok(())
}
