//! How many training images show the ground truth that the masks miss: samples 20,000 points
//! on a scene's `mesh.ply`, splits them by their distance to the masks alone (hull-blind:
//! farther than 0.01), and counts for each in how many training views at the dataset's
//! resolution the ground truth's own first hit at the sample's pixel lies within 0.011 of it.
//!
//! ```text
//! cargo run --release -p lab --example hull_blind_visibility -- ../shared/data/amber_ingot [BLIND.csv]
//! ```
//!
//! With a second argument it also writes the hull-blind samples some view shows there, one
//! `x,y,z,distance,views` line each.

use std::path::PathBuf;

use gtsr_mesh::mesh::sample_surface;
use gtsr_mesh::raycast::SignedDistance;

mod common;

/// Lower bounds of the view-count bins.
const BINS: [usize; 6] = [0, 1, 2, 3, 5, 10];

fn main() -> anyhow::Result<()> {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: hull_blind_visibility SCENE_DIR [BLIND.csv]"))?
        .into();
    let common::DevScene { scene, hull, gt } = common::load(&dir)?;
    let to_hull = SignedDistance::new(&hull, "masks' mesh")?;
    let maps = common::truth_maps(&scene, &gt)?;
    let samples = sample_surface(&gt, 20_000, 1, "ground truth")?;
    // Optionally, the hull-blind samples some view shows, as `x,y,z,distance,views` lines.
    let mut dump = match std::env::args().nth(2) {
        Some(path) => Some(std::io::BufWriter::new(std::fs::File::create(&path)?)),
        None => None,
    };
    let (mut blind, mut rest) = ([0usize; BINS.len()], [0usize; BINS.len()]);
    let mut blind_dist = [0f64; BINS.len()];
    for p in &samples.points {
        let d = to_hull.query(*p).0.abs();
        let views = common::views_showing(&scene, &maps, *p);
        let b = BINS.iter().rposition(|t| views >= *t).unwrap_or(0);
        if d > 0.01 {
            if let (Some(f), true) = (dump.as_mut(), views > 0) {
                use std::io::Write;
                writeln!(f, "{},{},{},{d},{views}", p.x, p.y, p.z)?;
            }
            blind[b] += 1;
            blind_dist[b] += d as f64;
        } else {
            rest[b] += 1;
        }
    }
    println!("ground-truth samples by the number of training images that show them");
    println!("| views | hull-blind | mean distance to the masks | the rest |");
    println!("|---|---:|---:|---:|");
    for (k, lo) in BINS.iter().enumerate() {
        let label = match BINS.get(k + 1) {
            Some(hi) if hi - lo == 1 => format!("{lo}"),
            Some(hi) => format!("{lo}-{}", hi - 1),
            None => format!(">= {lo}"),
        };
        let mean = if blind[k] > 0 {
            format!("{:.3}", blind_dist[k] / blind[k] as f64)
        } else {
            "-".into()
        };
        println!("| {label} | {} | {mean} | {} |", blind[k], rest[k]);
    }
    Ok(())
}
