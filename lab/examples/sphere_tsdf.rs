//! Fuses analytic depth maps of a sphere into a TSDF, extracts the mesh and prints its
//! chamfer distance to the sphere, with timings.
//!
//! ```text
//! cargo run --release -p lab --example sphere_tsdf -- [GRID] [VIEWS] [IMAGE] [SAMPLES]
//! ```
//! defaults: a 128^3 grid, 40 views of 192x192 pixels, 100000 chamfer samples per side.

use std::time::Instant;

use glam::Vec3;
use gtsr_eval::chamfer;
use gtsr_mesh::mesh::largest_component;
use gtsr_mesh::mesh::{component_sizes, icosphere, is_closed};
use gtsr_mesh::tsdf::TsdfVolume;

#[path = "../../tests/tests/common/mod.rs"]
mod common;
use common::{cameras_around, render_sphere};

fn main() -> anyhow::Result<()> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let arg = |k: usize, default: usize| args.get(k).copied().unwrap_or(default);
    let (grid, views, size, samples) =
        (arg(0, 128), arg(1, 40), arg(2, 192) as u32, arg(3, 100_000));
    let (centre, radius) = (Vec3::ZERO, 0.5f32);
    let half = 0.6f32;
    let voxel = 2.0 * half / (grid - 1) as f32;
    let trunc = gtsr_mesh::tsdf::DEFAULT_TRUNCATION_VOXELS * voxel;
    println!(
        "grid {grid}^3 (voxel {voxel:.5}), {views} views of {size}x{size}, rayon threads {}",
        rayon::current_num_threads()
    );

    let cams = cameras_around(centre, 2.0, views, 40f32.to_radians(), size);
    let renders: Vec<_> = cams
        .iter()
        .map(|c| render_sphere(c, centre, radius))
        .collect();

    let t = Instant::now();
    let mut vol = TsdfVolume::new(
        centre - Vec3::splat(half),
        centre + Vec3::splat(half),
        voxel,
        trunc,
    )?;
    for (cam, (depth, mask)) in cams.iter().zip(&renders) {
        vol.integrate(cam, depth, Some(mask))?;
    }
    let fuse_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mesh = vol.extract_mesh();
    let mc_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mesh = largest_component(&mesh);
    let lc_s = t.elapsed().as_secs_f64();
    println!(
        "fusion {fuse_s:.2} s, marching cubes {mc_s:.2} s, largest component {lc_s:.2} s: {} vertices, {} triangles, closed {}, components {}",
        mesh.positions.len(),
        mesh.triangles.len(),
        is_closed(&mesh),
        component_sizes(&mesh).len()
    );

    let reference = icosphere(centre, radius, 7);
    let t = Instant::now();
    let m = chamfer(&mesh, &reference, samples, voxel, 0)?;
    println!(
        "chamfer ({samples} samples per side, vs a {}-triangle icosphere) {:.2} s",
        reference.triangles.len(),
        t.elapsed().as_secs_f64()
    );
    println!(
        "chamfer {:.3e} ({:.3} voxel), accuracy {:.3e}, completeness {:.3e}, F-score@voxel {:.4}, normal consistency {:.5}",
        m.chamfer,
        m.chamfer / voxel as f64,
        m.accuracy,
        m.completeness,
        m.fscore,
        m.normal_consistency
    );
    Ok(())
}
