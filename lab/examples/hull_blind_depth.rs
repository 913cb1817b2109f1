//! Where in the masks' blind spot each mesh's error lies: samples 100,000 points on a
//! scene's `mesh.ply`, keeps the hull-blind ones (farther than 0.01 from the masks alone)
//! that some training view shows (the ground truth's own first hit at the sample's pixel
//! within 0.011 of it), bins them by their distance to the masks' mesh, and prints for each
//! mesh given the mean distance to it per bin and each bin's share of the hull-blind mean.
//!
//! ```text
//! cargo run --release -p lab --example hull_blind_depth -- ../shared/data/amber_ingot RUN_A/mesh.ply RUN_B/mesh.ply
//! ```
//!
//! The visibility test is this example's own (per pixel, as `hull_blind_visibility`'s), not
//! the seen filter of `gtsr_eval::chamfer_seen`, so its hull-blind means differ from the
//! runs' reports; the bins compare meshes against each other.

use std::path::PathBuf;

use gtsr_mesh::mesh::sample_surface;
use gtsr_mesh::raycast::SignedDistance;

mod common;

/// Bin edges: distance of a ground-truth sample to the masks' mesh.
const EDGES: [f32; 6] = [0.01, 0.02, 0.04, 0.08, 0.16, f32::INFINITY];

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: hull_blind_depth SCENE_DIR MESH.ply [MESH.ply ...]";
    let (dir, paths) = args
        .split_first()
        .filter(|(_, rest)| !rest.is_empty())
        .ok_or_else(|| anyhow::anyhow!(usage))?;
    let common::DevScene { scene, hull, gt } = common::load(&PathBuf::from(dir))?;
    let meshes = paths
        .iter()
        .map(|p| {
            gtsr_data::ply::read_ply(std::path::Path::new(p))
                .map_err(|e| anyhow::anyhow!("{p}: {e}"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let to_mesh = (meshes.iter().zip(paths))
        .map(|(m, p)| SignedDistance::new(m, p).map_err(anyhow::Error::from))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let to_hull = SignedDistance::new(&hull, "masks' mesh")?;
    let maps = common::truth_maps(&scene, &gt)?;
    let samples = sample_surface(&gt, 100_000, 1, "ground truth")?;
    let bins = EDGES.len() - 1;
    let (mut count, mut to_hull_sum) = (vec![0usize; bins], vec![0f64; bins]);
    let mut sums = vec![vec![0f64; bins]; meshes.len()];
    for p in &samples.points {
        let d = to_hull.query(*p).0.abs();
        if d <= EDGES[0] || common::views_showing(&scene, &maps, *p) == 0 {
            continue;
        }
        let b = EDGES.windows(2).position(|w| d <= w[1]).unwrap_or(bins - 1);
        count[b] += 1;
        to_hull_sum[b] += f64::from(d);
        for (sum, sd) in sums.iter_mut().zip(&to_mesh) {
            sum[b] += f64::from(sd.query(*p).0.abs());
        }
    }
    let total = count.iter().sum::<usize>().max(1) as f64;
    let row = |name: &str, s: &[f64]| {
        let cells: Vec<String> = (s.iter().zip(&count))
            .map(|(s, c)| {
                format!(
                    "{:.1} ({:.2})",
                    1e3 * s / (*c).max(1) as f64,
                    1e3 * s / total
                )
            })
            .collect();
        let mean = 1e3 * s.iter().sum::<f64>() / total;
        println!("| {name} | {} | {mean:.2} |", cells.join(" | "));
    };
    println!(
        "hull-blind samples some view shows, by distance to the masks' mesh (x1e3: mean in the \
         bin, its share of the mean in brackets)"
    );
    let heads: Vec<String> = (EDGES.windows(2).zip(&count))
        .map(|(w, c)| format!("{:.0}-{:.0} ({c})", 1e3 * w[0], 1e3 * w[1]))
        .collect();
    println!("| mesh | {} | hull-blind mean |", heads.join(" | "));
    println!("|---|{}---:|", "---:|".repeat(bins));
    row("masks alone", &to_hull_sum);
    for (path, s) in paths.iter().zip(&sums) {
        row(path, s);
    }
    Ok(())
}
