//! Whether path-tracing a candidate mesh with the scene's translucent material reproduces the
//! images over a concavity the masks cannot see (a diagnosis: it reads the ground truth and
//! the material the dataset's README states, so only on development scenes).
//!
//! The scattering proxies of `gtsr_mesh::scatter` and `lab::subsurface::` predict
//! amber_ingot's trench about twice too bright even on its true shape. This example asks the
//! full light transport instead: `gtsr_data`'s random-walk path tracer renders, at a sample of
//! pixels of every training view, the ground truth, the masks' mesh and any candidate meshes
//! given (e.g. the carvings `cargo lab fusion-ceiling --carve` writes), all scaled by the
//! gain that fits the masks' mesh's render on flush pixels (the truth within half a footprint of the masks' mesh). Over
//! the concave pixels (the truth more than 3 footprints behind the masks' mesh) and the dark
//! ones (`gtsr_mesh::scatter::unexplained_dark` at 0.3, `--dark-below`; no truth), the mesh whose render is
//! nearest the images is the one the shading prefers.
//!
//! ```text
//! cargo run --release -p lab --example trench_synthesis -- ../shared/data/amber_ingot \
//!     [--spp N] [--mfp-scale S,..] [--grey-material COLOUR,MFP | --fit-material] [--dark-below R] [--band PX] [--hollow-depths D,.. --hollow-radii R,..] [CANDIDATE.ply ...]
//! ```
//!
//! `--mfp-scale` takes a list: every mesh is rendered under each scale of the mean free path.
//! `--band PX` adds the pixels within PX pixels of a dark one (no truth): how fast the
//! radiance falls towards the gap, which tells the gap's width; the example then prints the
//! (scale, radius, depth) of least error over the band, the dark pixels, and both.
//!
//! `--grey-material` replaces the README's material by a grey one (base colour and mean free
//! path in world units, the same in every channel), which needs no knowledge of the material;
//! `--fit-material` picks a base colour and a mean free path per channel on the flush pixels
//! (and, like `--l1-gain`, scales the renders by the gain of least absolute error).
//! `--hollow-depths` / `--hollow-radii` add candidates made without the truth: the masks'
//! mesh with the inside removed within R footprints of the dark pixels' rays, from R + 1 to D
//! footprints behind it (`--hollow-open`: from the lid itself), each printed with its chamfer
//! as extracted and without its walls no training pixel shows. It then prints the depth at
//! which the dark pixels' median image / render crosses 1, over the candidates whose flush L1
//! stays within one point of the masks' mesh's.

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use gtsr_data::transport::material::Material;
use gtsr_data::transport::tracer::{Lighting, Tracer};
use gtsr_mesh::carve::DepthMap;
use gtsr_mesh::hollow::{hollow_mesh, l1_gain, near_dark, random_walk_material as material};
use gtsr_mesh::raycast::MeshRaycaster;
use gtsr_mesh::scatter::unexplained_dark;
use gtsr_mesh::shading::{ShadingImage, view_radiance};
use rayon::prelude::*;

mod common;

/// amber_ingot's material as its README states it (Blender's random walk: radius (0.5, 0.35,
/// 0.1) as the mean free path, base colour (0.95, 0.65, 0.2) turned into a single-scattering
/// albedo by Cycles' inversion, roughness 0.2, i.e. GGX alpha 0.04, IOR 1.45, isotropic).
fn amber_material(mfp_scale: f32) -> Material {
    material([0.95, 0.65, 0.2], [0.5, 0.35, 0.1].map(|m| m * mfp_scale))
}

/// How many points of flush L1 (%) a hollow may add to the masks' mesh's before the depth
/// criterion leaves it out: a candidate that changes the flush surface has cut through it.
const FLUSH_GUARD: f64 = 1.0;

/// A hollow's (mean free path scale, radius, depth, band L1 %, dark L1 %).
type Fit = (f32, f32, f32, f64, f64);

/// A pixel to render: view, pixel index, image radiance, class bits.
#[derive(Clone, Copy)]
struct Sample {
    view: usize,
    pixel: usize,
    image: f32,
    rgb: Vec3,
    calibration: bool,
    concave: bool,
    dark: bool,
    /// Not dark, but within `--band` pixels of a dark pixel of its view (no truth): how fast
    /// the radiance falls towards the gap, which the mean free path sets.
    band: bool,
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
    let (mut spp, mut mfp_scales, mut candidates) = (64u32, vec![1.0f32], Vec::<PathBuf>::new());
    let mut band_px = 0usize;
    // Hollows: (depth, radius) in footprints, the capsules along the dark pixels' rays.
    let (mut depths, mut radii) = (Vec::<f32>::new(), Vec::<f32>::new());
    let mut open = false;
    let mut below = 0.3f32;
    let mut grey: Option<(f32, f32)> = None;
    let mut fit = false;
    let mut l1 = false;
    let list = |v: String| -> anyhow::Result<Vec<f32>> {
        v.split(',')
            .map(|x| x.parse::<f32>().map_err(|e| anyhow::anyhow!("'{x}': {e}")))
            .collect()
    };
    while let Some(a) = args.next() {
        let mut value = |name: &str| {
            args.next()
                .ok_or_else(|| anyhow::anyhow!("{name} needs a value"))
        };
        match a.as_str() {
            "--spp" => spp = value("--spp")?.parse()?,
            "--mfp-scale" => mfp_scales = list(value("--mfp-scale")?)?,
            "--band" => band_px = value("--band")?.parse()?,
            "--hollow-depths" => depths = list(value("--hollow-depths")?)?,
            "--hollow-radii" => radii = list(value("--hollow-radii")?)?,
            "--hollow-open" => open = true,
            "--dark-below" => below = value("--dark-below")?.parse()?,
            "--fit-material" => fit = true,
            "--l1-gain" => l1 = true,
            "--grey-material" => {
                let v = list(value("--grey-material")?)?;
                anyhow::ensure!(v.len() == 2, "--grey-material takes COLOUR,MFP");
                grey = Some((v[0], v[1]));
            }
            _ => candidates.push(a.into()),
        }
    }
    let common::DevScene { scene, hull, gt } = common::load(&dir)?;
    let masks = common::masks(&scene)?;
    let truth = MeshRaycaster::new(&gt, "ground truth")?;
    let lid = MeshRaycaster::new(&hull, "masks' mesh")?;

    let radiance: Vec<Vec<f32>> = scene.train.iter().map(|v| view_radiance(v, None)).collect();
    let channels: Vec<[Vec<f32>; 3]> = scene
        .train
        .iter()
        .map(|v| [0, 1, 2].map(|c| view_radiance(v, Some(c))))
        .collect();
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
    let (_, dark) = unexplained_dark(&hull, &images, below)?;
    let band: Vec<Vec<bool>> = (scene.train.iter().zip(&dark))
        .map(|(v, d)| {
            near_dark(
                d,
                v.camera.width as usize,
                v.camera.height as usize,
                band_px,
            )
        })
        .collect();

    // The pixels: every concave or dark one, and every 97th flush one for the gain.
    let mut samples = Vec::new();
    for (k, v) in scene.train.iter().enumerate() {
        let (dt, dl) = (truth.render(&v.camera), lid.render(&v.camera));
        let edges = dl.occluding_edges(gtsr_mesh::raycast::EDGE_FOOTPRINTS);
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
                rgb: Vec3::new(channels[k][0][p], channels[k][1][p], channels[k][2][p]),
                calibration: behind.abs() < 0.5 && (k * 7919 + p) % 97 == 0,
                concave: behind > 3.0,
                dark: dark[k][p],
                band: band[k][p],
            };
            if s.calibration || s.concave || s.dark || s.band {
                samples.push(s);
            }
        }
    }
    let count = |f: fn(&Sample) -> bool| samples.iter().filter(|s| f(s)).count();
    println!(
        "{} pixels: {} flush (the gain), {} concave, {} dark (below {below} of the scattering model), {} within {band_px} px of a dark one; {spp} samples each; mean free path x{mfp_scales:?}",
        samples.len(),
        count(|s| s.calibration),
        count(|s| s.concave),
        count(|s| s.dark),
        count(|s| s.band),
    );
    let lighting = Lighting {
        point_intensity: 1.0,
        environment: 0.0,
    };
    let fitted = fit.then(|| {
        let (colour, mfp) = fit_material(&hull, &scene, &samples, spp, lighting);
        println!("fitted per channel: base colour {colour:?}, mean free path {mfp:?}");
        (colour, mfp)
    });
    let material_at = |scale: f32| match (grey, fitted) {
        (_, Some((colour, mfp))) => material(colour, mfp.map(|m| m * scale)),
        (Some((c, m)), None) => material([c; 3], [m * scale; 3]),
        (None, None) => amber_material(scale),
    };
    let mut meshes: Vec<(String, gtsr_data::ply::TriMesh)> = vec![
        ("ground truth".into(), gt.clone()),
        ("masks' mesh".into(), hull.clone()),
    ];
    for c in &candidates {
        meshes.push((c.display().to_string(), gtsr_data::ply::read_ply(c)?));
    }
    // Per mesh, the (radius, depth) of a hollow candidate.
    let mut hollow_of: Vec<Option<(f32, f32)>> = vec![None; meshes.len()];
    if !depths.is_empty() {
        let eyes: Vec<gtsr_data::Camera> = scene.train.iter().map(|v| v.camera).collect();
        let (lo, hi) =
            gtsr_mesh::hull::hull_box(&masks)?.ok_or_else(|| anyhow::anyhow!("empty masks"))?;
        let voxel = gtsr_mesh::hull::masks_voxel(&masks, lo, hi);
        let base = gtsr_mesh::hull::masks_grid(&masks, lo, hi, voxel)?;
        let lid_depths: Vec<_> = scene.train.iter().map(|v| lid.render(&v.camera)).collect();
        let to_hull = gtsr_mesh::raycast::SignedDistance::new(&hull, "masks' mesh")?;
        let cameras: Vec<&gtsr_data::Camera> = eyes.iter().collect();
        for &r in &radii {
            for &d in &depths {
                let skin = if open { 0.0 } else { r + 1.0 };
                let mesh = hollow_mesh(&base, &cameras, &dark, &lid_depths, r, (skin, d));
                let label = format!("hollow: capsules of {r} fp from {skin} to {d} fp");
                // As extracted, and without the faces no training pixel shows that are off
                // the masks' mesh (the walls of the hollow no view sees).
                let caster = MeshRaycaster::new(&mesh, "hollow")?;
                let maps: Vec<_> = eyes.iter().map(|c| caster.render(c)).collect();
                let own: Vec<DepthMap> = eyes
                    .iter()
                    .zip(&maps)
                    .map(|(camera, m)| DepthMap {
                        camera,
                        depth: &m.depth,
                        hull_depth: None,
                    })
                    .collect();
                let shown = gtsr_mesh::visible::faces_observed(&mesh, &own, 3.0)?;
                let on_hull = |t: &[u32; 3]| {
                    let c = t.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / 3.0;
                    to_hull.query(c).0.abs() < 0.5 * base.voxel
                };
                let mut culled = mesh.clone();
                culled.triangles = (mesh.triangles.iter().zip(&shown))
                    .filter(|(t, s)| **s || on_hull(t))
                    .map(|(t, _)| *t)
                    .collect();
                for (what, m) in [("as extracted", &mesh), ("unseen walls culled", &culled)] {
                    let (seen, _) =
                        gtsr_eval::score_against_ground_truth(m, &gt, &eyes, Some(&hull))?;
                    println!(
                        "{label}, {what}: chamfer x1e3 {:.2} (accuracy {:.2}, completeness {:.2}), hull-blind {:.2}",
                        1e3 * seen.chamfer,
                        1e3 * seen.accuracy,
                        1e3 * seen.completeness,
                        1e3 * seen.hull_blind.map(|b| b.blind).unwrap_or(f64::NAN)
                    );
                }
                meshes.push((label, mesh));
                hollow_of.push(Some((r, d)));
            }
        }
    }
    // The lid first, so its gain is the one every mesh is scaled by.
    meshes.swap(0, 1);
    let tracers: Vec<Tracer> = meshes
        .iter()
        .map(|(_, m)| Tracer::new(m, material_at(1.0)))
        .collect();
    // Per mean free path: (scale, radius, depth, band L1 %, dark L1 %) of each hollow kept.
    let mut fits: Vec<Fit> = Vec::new();
    for &mfp_scale in &mfp_scales {
        println!();
        println!("mean free path x{mfp_scale}:");
        println!(
            "| mesh | gain | flush: image / render median | flush: L1 % | concave: median | concave: L1 % | dark: median | dark: L1 % | band: median | band: L1 % | render s |"
        );
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        // (radius, depth, the dark pixels' median image / render) of each hollow that keeps the
        // flush surface: its flush L1 at most FLUSH_GUARD points above the masks' mesh's.
        let mut crossings: Vec<(f32, f32, f32)> = Vec::new();
        let mut lid_flush_l1: Option<f64> = None;
        let mut lid_gain: Option<f32> = None;
        for (((label, _), of), base) in meshes.iter().zip(&hollow_of).zip(&tracers) {
            let t0 = Instant::now();
            let tracer = base.with_material(material_at(mfp_scale));
            let rendered: Vec<f32> = render(&tracer, &scene, &samples, spp, lighting)
                .into_iter()
                .map(|c| (c.x + c.y + c.z) / 3.0)
                .collect();
            let secs = t0.elapsed().as_secs_f64();
            // One gain for every mesh: the masks' mesh's (the flush surface is the same in all);
            // least squares, or with `--l1-gain` (and `--fit-material`) least absolute error.
            let gain = *lid_gain.get_or_insert_with(|| {
                let pairs: Vec<(f32, f32)> = (samples.iter().zip(&rendered))
                    .filter(|(s, _)| s.calibration)
                    .map(|(s, r)| (s.image, *r))
                    .collect();
                if l1 || fit {
                    l1_gain(pairs.iter().copied())
                } else {
                    let num: f64 = pairs
                        .iter()
                        .map(|(i, r)| f64::from(*i) * f64::from(*r))
                        .sum();
                    let den: f64 = pairs
                        .iter()
                        .map(|(_, r)| f64::from(*r) * f64::from(*r))
                        .sum();
                    (num / den.max(f64::MIN_POSITIVE)) as f32
                }
            });
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
            let (bandm, band_l1) = stats(|s| s.band);
            println!(
                "| {label} | {gain:.4} | {flush:.3} | {flush_l1:.1} | {concave:.3} | {concave_l1:.1} | {darkm:.3} | {dark_l1:.1} | {bandm:.3} | {band_l1:.1} | {secs:.0} |"
            );
            let reference = *lid_flush_l1.get_or_insert(flush_l1);
            if let Some((r, d)) = of {
                if flush_l1 <= reference + FLUSH_GUARD {
                    crossings.push((*r, *d, darkm));
                    fits.push((mfp_scale, *r, *d, band_l1, dark_l1));
                } else {
                    println!(
                        "  (left out of the crossing: its flush L1 {flush_l1:.1} % exceeds the masks' mesh's {reference:.1} % by more than {FLUSH_GUARD})"
                    );
                }
            }
        }
        // Per radius, the depth at which the hollow renders the dark pixels as bright as the
        // images (their median image / render crosses 1, linear between the depths tried).
        for &r in &radii {
            let mut row: Vec<_> = crossings.iter().filter(|c| c.0 == r).collect();
            row.sort_by(|a, b| a.1.total_cmp(&b.1));
            let at = row.windows(2).find_map(|w| {
                let ((_, d0, m0), (_, d1, m1)) = (w[0], w[1]);
                ((m0 - 1.0) * (m1 - 1.0) <= 0.0 && m0 != m1)
                    .then(|| d0 + (d1 - d0) * (1.0 - m0) / (m1 - m0))
            });
            match at {
                Some(d) => println!(
                    "capsules of {r} fp: the dark pixels' median image / render crosses 1 at {d:.1} fp"
                ),
                None => println!(
                    "capsules of {r} fp: the dark pixels' median image / render does not cross 1 over the depths tried"
                ),
            }
        }
    }
    // The (mean free path, radius, depth) of least L1 over the dark pixels and their band
    // together (pixel-weighted), and over the band alone.
    if band_px > 0 {
        let (nb, nd) = (count(|s| s.band) as f64, count(|s| s.dark) as f64);
        let joint = |f: &Fit| (nb * f.3 + nd * f.4) / (nb + nd).max(1.0);
        let best = |key: &dyn Fn(&Fit) -> f64| {
            fits.iter()
                .min_by(|a, b| key(a).total_cmp(&key(b)))
                .copied()
        };
        for (what, pick) in [
            ("band and dark pixels", best(&joint)),
            ("band alone", best(&|f| f.3)),
            ("dark pixels alone", best(&|f| f.4)),
        ] {
            if let Some((m, r, d, b, k)) = pick {
                println!(
                    "least L1 over the {what}: mean free path x{m}, capsules of {r} fp to {d} fp (band {b:.1} %, dark {k:.1} %)"
                );
            }
        }
    }
    Ok(())
}

/// Each sample's mean linear RGB over `spp` jittered paths through its pixel.
fn render(
    tracer: &Tracer,
    scene: &gtsr_data::Scene,
    samples: &[Sample],
    spp: u32,
    lighting: Lighting,
) -> Vec<Vec3> {
    samples
        .par_iter()
        .map(|s| {
            let cam = &scene.train[s.view].camera;
            let w = cam.width as usize;
            let (sum, _) = tracer.pixel_sum(
                cam,
                s.pixel % w,
                s.pixel / w,
                lighting,
                spp,
                7,
                s.view as u64,
            );
            sum / spp.max(1) as f32
        })
        .collect()
}

/// Per channel, the grey material of least L1 over the flush samples (each channel with its
/// own gain): the grid's base colours and mean free paths, on the masks' mesh. Channels do
/// not interact in the tracer, so one grey render serves all three.
fn fit_material(
    hull: &gtsr_data::ply::TriMesh,
    scene: &gtsr_data::Scene,
    samples: &[Sample],
    spp: u32,
    lighting: Lighting,
) -> ([f32; 3], [f32; 3]) {
    let flush: Vec<Sample> = samples.iter().filter(|s| s.calibration).copied().collect();
    let images: Vec<Vec3> = flush.iter().map(|s| s.rgb).collect();
    let base = Tracer::new(hull, material([0.5; 3], [0.1; 3]));
    let mut best = [(f64::INFINITY, 0.0f32, 0.0f32); 3];
    for colour in [0.5f32, 0.7, 0.85, 0.95, 0.99] {
        for mfp in [0.02f32, 0.05, 0.1, 0.2, 0.35, 0.5, 0.8] {
            let tracer = base.with_material(material([colour; 3], [mfp; 3]));
            let rendered = render(&tracer, scene, &flush, spp, lighting);
            let mut row = Vec::new();
            for c in 0..3 {
                let pairs: Vec<(f32, f32)> = images
                    .iter()
                    .zip(&rendered)
                    .map(|(i, r)| (i[c], r[c]))
                    .collect();
                let sum: f64 = pairs.iter().map(|p| f64::from(p.0)).sum();
                let gain = f64::from(l1_gain(pairs.iter().copied()));
                let l1: f64 = images
                    .iter()
                    .zip(&rendered)
                    .map(|(i, r)| (f64::from(i[c]) - gain * f64::from(r[c])).abs())
                    .sum::<f64>()
                    / sum.max(f64::MIN_POSITIVE);
                row.push(format!("{:.1}", 100.0 * l1));
                if l1 < best[c].0 {
                    best[c] = (l1, colour, mfp);
                }
            }
            println!(
                "material fit: colour {colour}, mean free path {mfp}: flush L1 % R/G/B {}",
                row.join(" / ")
            );
        }
    }
    (best.map(|b| b.1), best.map(|b| b.2))
}
