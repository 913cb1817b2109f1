//! Everything written to `--out`: JSON and text files (atomically), the splats, the render
//! strips, and the final evaluation's outputs.

use std::path::Path;

use crate::evaluation::{AREA_RAYS, Snapshot, evaluate};
use crate::mesh::{MeshSettings, extract_mesh};
use anyhow::{Context, Result};
use gtsr_data::Scene;
use gtsr_data::ply::{TriMesh, write_ply};
use gtsr_eval::{MeshMetrics, Timeline};
use gtsr_model::checkpoint::write_atomic;
use gtsr_model::export::write_splat_ply;
use gtsr_model::gaussians::host_vec;
use gtsr_model::trainer::Trainer;
use gtsr_model::views::ViewTensors;
use serde::Serialize;

/// Writes `value` as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).context("serialising JSON")?;
    write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

/// Writes `text` to `path`, atomically.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

/// The map from the trained (normalised) frame back to the dataset's own coordinates.
pub fn dataset_frame(scene: &Scene) -> gtsr_data::Normalisation {
    if scene.normalisation_applied {
        scene.normalisation
    } else {
        gtsr_data::Normalisation::IDENTITY
    }
}

/// `gaussians.ply`, in the dataset's frame.
pub fn write_splats(trainer: &Trainer, scene: &Scene, out: &Path) -> Result<usize> {
    let path = out.join("gaussians.ply");
    write_splat_ply(trainer.model(), &path, &dataset_frame(scene))
        .with_context(|| format!("writing {}", path.display()))
}

pub(crate) fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// PNG strips per test view: ground truth | C_SH | C_PBR | normal | depth.
pub(crate) fn write_strips(
    at: &Snapshot,
    tests: &[ViewTensors],
    scene: &Scene,
    dir: &Path,
) -> Result<usize> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let model = &at.model;
    let opts = gtsr_model::model::RenderOptions {
        geometry: true,
        ..at.options
    };
    for (k, (v, data)) in tests.iter().zip(&scene.test).enumerate() {
        let (w, h) = v.size();
        let r = model.render(&v.camera, &v.rays, opts)?;
        let geo = match r.geometry.clone() {
            Some(g) => g,
            None => model.render_depth(&v.camera, &v.rays)?,
        };
        let sh = host_vec(r.c_sh);
        let pbr = r.c_pbr.map(host_vec);
        let normal = host_vec(geo.normal);
        let depth = host_vec(geo.depth);
        let cov = host_vec(geo.coverage);
        let covered: Vec<f32> = depth
            .iter()
            .zip(&cov)
            .filter(|(d, c)| **c > 0.5 && d.is_finite())
            .map(|(d, _)| *d)
            .collect();
        let (dmin, dmax) = covered
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), d| {
                (a.min(*d), b.max(*d))
            });
        let mut img = image::RgbImage::new((5 * w) as u32, h as u32);
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let rgb = |v: &[f32]| [to_u8(v[3 * p]), to_u8(v[3 * p + 1]), to_u8(v[3 * p + 2])];
                let panels = [
                    rgb(&data.rgb),
                    rgb(&sh),
                    pbr.as_ref().map_or([0, 0, 0], |b| rgb(b)),
                    {
                        let c = cov[p].max(1e-3);
                        let n: [f32; 3] = std::array::from_fn(|i| normal[3 * p + i] / c);
                        if cov[p] > 0.5 {
                            n.map(|v| to_u8(0.5 - 0.5 * v))
                        } else {
                            [0, 0, 0]
                        }
                    },
                    if cov[p] > 0.5 && dmax > dmin {
                        let g = to_u8(1.0 - (depth[p] - dmin) / (dmax - dmin) * 0.8);
                        [g, g, g]
                    } else {
                        [0, 0, 0]
                    },
                ];
                for (i, c) in panels.iter().enumerate() {
                    img.put_pixel((i * w + x) as u32, y as u32, image::Rgb(*c));
                }
            }
        }
        let path = dir.join(format!("test_{k:03}.png"));
        let tmp = dir.join(format!(".test_{k:03}.png.tmp"));
        img.save_with_format(&tmp, image::ImageFormat::Png)
            .with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(tests.len())
}

/// A signed mean over a subset of the pixels x1e3 for the log (`-` when the subset is empty,
/// e.g. [`DepthMetrics::depth_mean_signed_off_edges`] when every pixel lies on an edge).
pub(crate) fn signed_x1e3(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{:+.2}", v * 1e3))
}

/// Final outputs: mesh, splats, renders, metrics, error-against-time plot.
#[allow(clippy::too_many_arguments)]
pub fn finish(
    trainer: &Trainer,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: Option<&TriMesh>,
    settings: &MeshSettings,
    timeline: &Timeline,
    train_seconds: f64,
    out: &Path,
) -> Result<()> {
    println!("final evaluation and mesh extraction...");
    let at = Snapshot::of(trainer);
    let e = evaluate(&at, tests, scene, gt, settings, false)?;
    let mesh = match e.extracted.clone() {
        Some(m) => m,
        None => extract_mesh(&at, scene, settings, false)?,
    };
    let mesh_path = out.join("mesh.ply");
    // Metrics are taken in the trained frame (above); the file is in the dataset's.
    let frame = dataset_frame(scene);
    let world = TriMesh {
        positions: mesh.positions.iter().map(|p| frame.to_world(*p)).collect(),
        ..mesh.clone()
    };
    write_ply(&mesh_path, &world).with_context(|| format!("writing {}", mesh_path.display()))?;
    let n_splats = write_splats(trainer, scene, out)?;
    let n_strips = write_strips(&at, tests, scene, &out.join("renders"))?;
    let (ns, ni) = trainer.model().counts();
    let masks_alone = settings.masks_alone;
    let metrics = gtsr_eval::RunMetrics {
        iterations: trainer.steps_done(),
        train_seconds,
        surface_gaussians: ns,
        interior_gaussians: ni,
        skipped_steps: trainer.counters().skipped_steps,
        raster_passes: trainer.counters().passes,
        tile_splats: trainer.counters().tile_splats,
        tile_splats_per_pass: trainer.counters().tile_splats as f64
            / trainer.counters().passes.max(1) as f64,
        trimmed_surface: trainer.counters().trimmed,
        demoted_surface: trainer.counters().demoted,
        test_psnr: e.psnr,
        test_ssim: e.ssim,
        test_psnr_masked: e.psnr_masked,
        test_psnr_pbr: e.psnr_pbr,
        mesh: e.mesh,
        mesh_whole_gt: e.mesh_whole_gt,
        masks_alone,
        mesh_depth_only: e.depth_only,
        test_depth: e.depth,
        test_depth_area: e.depth_area,
        mesh_vertices: mesh.positions.len(),
        mesh_triangles: mesh.triangles.len(),
    };
    let path = out.join("metrics.json");
    metrics
        .write(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    // The curve's last point is the mesh as written (the evaluations during training take
    // the quicker extraction).
    let mut timeline = timeline.clone();
    timeline.set_final(e.timeline_point(&at, train_seconds, gtsr_eval::FINAL_LABEL));
    let csv = out.join("error_vs_time.csv");
    timeline
        .write_csv(&csv)
        .with_context(|| format!("writing {}", csv.display()))?;
    let plot = out.join("error_vs_time.png");
    gtsr_eval::plot_png(&plot, &[("gtsr", &timeline)])
        .with_context(|| format!("writing {}", plot.display()))?;
    println!("outputs in {}:", out.display());
    println!(
        "  mesh.ply            {} vertices, {} triangles",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    println!("  gaussians.ply       {n_splats} splats ({ns} surface, {ni} interior)");
    println!(
        "  renders/            {n_strips} strips: ground truth | C_SH | C_PBR | normal | depth"
    );
    println!(
        "  metrics.json, config.json, error_vs_time.csv, error_vs_time.png, checkpoint.safetensors"
    );
    println!(
        "final: {} steps in {:.0} s training; test PSNR {:.2} dB, SSIM {:.4}{}{}",
        trainer.steps_done(),
        train_seconds,
        e.psnr,
        e.ssim,
        e.psnr_pbr
            .map_or(String::new(), |p| format!(", C_PBR PSNR {p:.2} dB")),
        e.mesh.as_ref().map_or(String::new(), |m| format!(
            "; chamfer {:.5} (x1e3 {:.2}; {:.1} % of the ground truth seen{}), F-score {:.3} at \
             {:.4}, normal consistency {:.3}",
            m.chamfer,
            m.chamfer * 1e3,
            100.0 * m.gt_seen,
            e.mesh_whole_gt.as_ref().map_or(String::new(), |w| format!(
                "; x1e3 {:.2} against all of it",
                w.chamfer * 1e3
            )),
            m.fscore,
            m.threshold,
            m.normal_consistency
        ))
    );
    let blind = |m: &MeshMetrics| {
        m.hull_blind.map_or(String::new(), |b| {
            format!(
                "; on the {:.1} % the masks miss by > {:.3}: {:.2} x1e3 (elsewhere {:.2})",
                100.0 * b.fraction,
                b.threshold,
                b.blind * 1e3,
                b.rest * 1e3
            )
        })
    };
    if let Some(m) = &e.mesh {
        println!("mesh: chamfer x1e3 {:.2}{}", m.chamfer * 1e3, blind(m));
    }
    if let Some(m) = &masks_alone {
        println!(
            "masks alone ({} px masks): chamfer x1e3 {:.2}{}",
            settings.masks.as_ref().map_or(0, |n| n.views[0].0.width),
            m.chamfer * 1e3,
            blind(m)
        );
    }
    if let Some(m) = &e.depth_only {
        println!(
            "the rendered depth alone (TSDF, no masks): chamfer x1e3 {:.2}{}",
            m.chamfer * 1e3,
            blind(m)
        );
    }
    if let Some(d) = &e.depth {
        println!(
            "test-view geometry against the ground truth ({} px, {:.1} % covered): depth error \
             x1e3 median {:.2}, mean {:.2}, mean signed {:+.2} (+: behind the surface); normal \
             error median {:.1} deg, mean {:.1} deg",
            d.pixels,
            100.0 * d.coverage,
            d.depth_median_abs * 1e3,
            d.depth_mean_abs * 1e3,
            d.depth_mean_signed * 1e3,
            d.normal_median_deg,
            d.normal_mean_deg
        );
        let q = d.depth_signed_quantiles.map(|v| format!("{:+.2}", v * 1e3));
        println!(
            "  signed depth error x1e3 at 5/25/50/75/95 %: {}; mean signed within 5-95 %: {:+.2}; \
             {:.1} % of the pixels on the truth's occluding edges, mean signed off them {}; \
             {:.1} % just behind one, mean signed there {}",
            q.join(" / "),
            d.depth_mean_signed_inner * 1e3,
            100.0 * d.edge_share,
            signed_x1e3(d.depth_mean_signed_off_edges),
            100.0 * d.far_side_share,
            signed_x1e3(d.depth_mean_signed_far_side)
        );
        if let Some(c) = d.depth_mean_signed_concave_fp {
            println!(
                "  {:.1} % of the pixels look into a concavity the masks cannot see (the truth \
                 more than {} footprints behind the masks' mesh): mean signed depth error there \
                 {c:+.2} footprints",
                100.0 * d.concave_share,
                gtsr_eval::CONCAVE_GAP_FOOTPRINTS
            );
        }
    }
    if let Some(d) = &e.depth_area {
        println!(
            "  against the truth averaged over each pixel ({AREA_RAYS}x{AREA_RAYS} rays): depth \
             error x1e3 median {:.2}, mean {:.2}, mean signed {:+.2}; off the occluding edges {}",
            d.depth_median_abs * 1e3,
            d.depth_mean_abs * 1e3,
            d.depth_mean_signed * 1e3,
            signed_x1e3(d.depth_mean_signed_off_edges)
        );
    }
    Ok(())
}
