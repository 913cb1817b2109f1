//! Whether path-tracing a candidate mesh with the scene's translucent material reproduces the
//! images over a concavity the masks cannot see (a diagnosis: it reads the ground truth and
//! the material the dataset's README states, so only on development scenes).
//!
//! The scattering proxies of `gtsr_eval::scatter` and `gtsr_eval::subsurface` predict
//! amber_ingot's trench about twice too bright even on its true shape. This example asks the
//! full light transport instead: `gtsr_data`'s random-walk path tracer renders, at a sample of
//! pixels of every training view, the ground truth, the masks' mesh and any candidate meshes
//! given (e.g. the carvings `cargo xtask fusion-ceiling --carve` writes), each scaled by one
//! gain fitted on flush pixels (the truth within half a footprint of the masks' mesh). Over
//! the concave pixels (the truth more than 3 footprints behind the masks' mesh) and the dark
//! ones (`gtsr_eval::scatter::unexplained_dark` at 0.3, no truth), the mesh whose render is
//! nearest the images is the one the shading prefers.
//!
//! ```text
//! cargo run --release -p gtsr-eval --example trench_synthesis -- ../shared/data/amber_ingot \
//!     [--spp N] [--mfp-scale S] [CANDIDATE.ply ...]
//! ```

use std::path::PathBuf;
use std::time::Instant;

use glam::{Vec2, Vec3};
use gtsr_data::synthetic::material::Material;
use gtsr_data::synthetic::rng::Rng;
use gtsr_data::synthetic::tracer::{Lighting, Tracer};
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::scatter::unexplained_dark;
use gtsr_eval::shading::{ShadingImage, view_radiance};
use gtsr_eval::{MeshRaycaster, masks_mesh};
use rayon::prelude::*;

/// amber_ingot's material as its README states it (Blender's random walk: radius (0.5, 0.35,
/// 0.1) as the mean free path, base colour (0.95, 0.65, 0.2) turned into a single-scattering
/// albedo by Cycles' inversion, roughness 0.2, i.e. GGX alpha 0.04, IOR 1.45, isotropic).
fn amber_material(mfp_scale: f32) -> Material {
    let albedo = [0.95f32, 0.65, 0.2].map(|a| {
        let r = 4.09712 + 4.20863 * a - (9.59217 + 41.6808 * a + 17.7126 * a * a).sqrt();
        1.0 - r * r
    });
    Material::from_mfp_albedo(
        [0.5, 0.35, 0.1].map(|m| m * mfp_scale),
        albedo,
        0.0,
        1.45,
        0.04,
    )
}

/// A pixel to render: view, pixel index, image radiance, class bits.
#[derive(Clone, Copy)]
struct Sample {
    view: usize,
    pixel: usize,
    image: f32,
    calibration: bool,
    concave: bool,
    dark: bool,
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let dir: PathBuf = args
        .next()
        .ok_or_else(|| {
            anyhow::anyhow!(
                "usage: trench_synthesis SCENE_DIR [--spp N] [--mfp-scale S] [MESH.ply ...]"
            )
        })?
        .into();
    let (mut spp, mut mfp_scale, mut candidates) = (64u32, 1.0f32, Vec::<PathBuf>::new());
    while let Some(a) = args.next() {
        let mut value = |name: &str| {
            args.next()
                .ok_or_else(|| anyhow::anyhow!("{name} needs a value"))
        };
        match a.as_str() {
            "--spp" => spp = value("--spp")?.parse()?,
            "--mfp-scale" => mfp_scale = value("--mfp-scale")?.parse()?,
            _ => candidates.push(a.into()),
        }
    }
    let opts = LoadOptions {
        downscale: Downscale::None,
        ..LoadOptions::default()
    };
    let scene = load_scene(&dir, &opts)?;
    let masks: Vec<_> = scene
        .train
        .iter()
        .map(|v| {
            v.mask
                .as_deref()
                .map(|m| (v.camera, m))
                .ok_or_else(|| anyhow::anyhow!("view {} has no mask", v.name))
        })
        .collect::<anyhow::Result<_>>()?;
    let hull = masks_mesh(&masks, None)?.ok_or_else(|| anyhow::anyhow!("empty masks"))?;
    let gt_path = scene
        .mesh_path
        .clone()
        .ok_or_else(|| anyhow::anyhow!("{}: no mesh.ply", dir.display()))?;
    let gt = gtsr_data::ply::read_ply(&gt_path)?;
    let truth = MeshRaycaster::new(&gt, "ground truth")?;
    let lid = MeshRaycaster::new(&hull, "masks' mesh")?;

    let radiance: Vec<Vec<f32>> = scene.train.iter().map(|v| view_radiance(v, None)).collect();
    let images: Vec<ShadingImage> = scene
        .train
        .iter()
        .zip(&radiance)
        .map(|(v, r)| ShadingImage {
            camera: &v.camera,
            radiance: r,
            mask: v.mask.as_deref(),
        })
        .collect();
    let (_, dark) = unexplained_dark(&hull, &images, 0.3)?;

    // The pixels: every concave or dark one, and every 97th flush one for the gain.
    let mut samples = Vec::new();
    for (k, v) in scene.train.iter().enumerate() {
        let (dt, dl) = (truth.render(&v.camera), lid.render(&v.camera));
        let edges = dl.occluding_edges(gtsr_eval::depth::EDGE_FOOTPRINTS);
        let mask = v.mask.as_deref().unwrap_or_default();
        for p in 0..dt.depth.len() {
            let (zt, zl) = (dt.depth[p], dl.depth[p]);
            if zt <= 0.0 || zl <= 0.0 || edges[p] || mask[p] < 0.99 {
                continue;
            }
            let behind = (zt - zl) / (zl / dt.focal);
            let s = Sample {
                view: k,
                pixel: p,
                image: radiance[k][p],
                calibration: behind.abs() < 0.5 && (k * 7919 + p) % 97 == 0,
                concave: behind > 3.0,
                dark: dark[k][p],
            };
            if s.calibration || s.concave || s.dark {
                samples.push(s);
            }
        }
    }
    let count = |f: fn(&Sample) -> bool| samples.iter().filter(|s| f(s)).count();
    println!(
        "{} pixels: {} flush (the gain), {} concave, {} dark (below 0.3 of the scattering model); {spp} samples each; mean free path x{mfp_scale}",
        samples.len(),
        count(|s| s.calibration),
        count(|s| s.concave),
        count(|s| s.dark),
    );
    println!();
    println!(
        "| mesh | gain | flush: image / render median | flush: L1 % | concave: median | concave: L1 % | dark: median | dark: L1 % | render s |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");

    let material = amber_material(mfp_scale);
    let lighting = Lighting {
        point_intensity: 1.0,
        environment: 0.0,
    };
    let mut meshes: Vec<(String, gtsr_data::ply::TriMesh)> = vec![
        ("ground truth".into(), gt.clone()),
        ("masks' mesh".into(), hull.clone()),
    ];
    for c in &candidates {
        meshes.push((c.display().to_string(), gtsr_data::ply::read_ply(c)?));
    }
    for (label, mesh) in &meshes {
        let t0 = Instant::now();
        let tracer = Tracer::new(mesh, material);
        let rendered: Vec<f32> = samples
            .par_iter()
            .map(|s| {
                let cam = &scene.train[s.view].camera;
                let c2w = cam.camera_to_world();
                let origin = Vec3::from(c2w.translation);
                let w = cam.width as usize;
                let (i, j) = ((s.pixel % w) as f32, (s.pixel / w) as f32);
                let mut rng = Rng::new(7, s.view as u64, s.pixel as u64, 0);
                let shift = Vec2::new(rng.next_f32(), rng.next_f32());
                let mut sum = Vec3::ZERO;
                for n in 0..spp {
                    let o = (shift + Vec2::new(0.754_877_7, 0.569_840_3) * n as f32).fract();
                    let d = c2w
                        .transform_vector3(cam.camera_direction(i + o.x, j + o.y))
                        .normalize();
                    sum += tracer.sample_path(origin, d, origin, lighting, &mut rng).0;
                }
                (sum.x + sum.y + sum.z) / (3.0 * spp as f32)
            })
            .collect();
        let secs = t0.elapsed().as_secs_f64();
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (s, r) in samples.iter().zip(&rendered) {
            if s.calibration {
                num += f64::from(s.image) * f64::from(*r);
                den += f64::from(*r) * f64::from(*r);
            }
        }
        let gain = (num / den.max(f64::MIN_POSITIVE)) as f32;
        let stats = |f: fn(&Sample) -> bool| {
            let mut ratios = Vec::new();
            let (mut err, mut sum) = (0.0f64, 0.0f64);
            for (s, r) in samples.iter().zip(&rendered) {
                if f(s) {
                    let r = gain * r;
                    if r > 0.0 {
                        ratios.push(s.image / r);
                    }
                    err += f64::from((s.image - r).abs());
                    sum += f64::from(s.image);
                }
            }
            ratios.sort_by(f32::total_cmp);
            let median = ratios.get(ratios.len() / 2).copied().unwrap_or(f32::NAN);
            (median, 100.0 * err / sum.max(f64::MIN_POSITIVE))
        };
        let (flush, flush_l1) = stats(|s| s.calibration);
        let (concave, concave_l1) = stats(|s| s.concave);
        let (darkm, dark_l1) = stats(|s| s.dark);
        println!(
            "| {label} | {gain:.4} | {flush:.3} | {flush_l1:.1} | {concave:.3} | {concave_l1:.1} | {darkm:.3} | {dark_l1:.1} | {secs:.0} |"
        );
    }
    Ok(())
}
