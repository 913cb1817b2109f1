//! `cargo lab fusion-ceiling`: what the TSDF fusion of gtsr-train makes of *perfect* depth.
//!
//! The ground-truth mesh is ray cast through every training pixel (at the training
//! resolution) and its depth maps go through the fusion gtsr-train uses (the same depth
//! preparation and recipe, `gtsr_mesh::prepare_depth` and `gtsr_mesh::extract_mesh`: box,
//! voxel, masks, silhouette carving, default truncation, grazing and depth-edge cuts) at
//! several truncations. The
//! chamfer of those meshes is the best any rendered depth can give through this fusion at
//! this resolution: when it does not beat the masks alone, no method can beat the visual hull
//! by its depth maps, however good they are. `--biases` shifts the true depth behind (or in
//! front of) the surface, to see how near it rendered depth must come to add anything.
//! With `--carve`, each carving row is preceded by the extraction's own log lines (the
//! concavity gate's count, the culled faces, the silhouette check).

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::subsurface::{
    DarkDepthSettings, SURFACE_WIDTHS_FP, dark_depths, fit_surface_scatter, median_depth,
    surface_views,
};
use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::score_against_ground_truth;
use gtsr_mesh::pixels::median_pixel_footprint;
use gtsr_mesh::raycast::MeshRaycaster;
use gtsr_mesh::scatter::{DARK_MIN_COS, unexplained_dark};
use gtsr_mesh::shading::{ShadingImage, view_radiance};
use gtsr_mesh::tsdf::default_voxel;
use gtsr_mesh::tsdf::{DEPTH_ONLY_TRUNCATION_FOOTPRINTS, default_truncation};
use gtsr_mesh::{
    DepthGeometry, Fusion, FusionInputs, FusionView, MasksAlone, MeshConfig, extract_mesh,
};

use gtsr_eval::{ground_truth, scene_name};

/// Options of `fusion-ceiling`.
#[derive(Args, Debug)]
pub struct FusionCeilingArgs {
    /// Scene folders (Blender/NeRF with `mesh.ply` and masks).
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Where the meshes and the table go.
    #[arg(long, default_value = "fusion-ceiling")]
    pub out: PathBuf,
    /// Longest image side (the training resolution of the runs to compare with).
    #[arg(long, default_value_t = 64)]
    pub resolution: u32,
    /// Short truncations to try with silhouette carving, in training-pixel footprints.
    #[arg(long, num_args = 1.., default_values_t = [1.0f32, 2.0, 4.0])]
    pub footprints: Vec<f32>,
    /// Depth errors to add (scene units, positive: behind the surface), each fused at the
    /// longest of `--footprints`: how near the surface rendered depth must come to add to
    /// the masks.
    #[arg(long, num_args = 0.., allow_negative_numbers = true)]
    pub biases: Vec<f32>,
    /// Leave out the fusion of the depth alone (no carving).
    #[arg(long)]
    pub no_depth_alone: bool,
    /// Leave out the masks-only and default-truncation fusions.
    #[arg(long)]
    pub no_default: bool,
    /// Keep the depth edges gtsr-train drops (`gtsr_mesh::tsdf::drop_depth_edges`): pixels
    /// whose 4-neighbour leaves their plane by more than two footprints, which on rendered
    /// depth blend two surfaces at an occlusion boundary.
    #[arg(long)]
    pub keep_edges: bool,
    /// With carving, keep the hull field's own distance inside the hull where no depth was
    /// fused (the mesh setting `hull_inside_distance`).
    #[arg(long)]
    pub hull_inside_distance: bool,
    /// Also carve the masks at the dataset's resolution with the true depth (gtsr-train's
    /// default extraction without its last step, the shading refinement; `gtsr_mesh::carve`;
    /// with each of `--biases` too), beside the masks alone.
    #[arg(long)]
    pub carve: bool,
    /// Carving: agreeing views (gtsr-train's `--carve-views`).
    #[arg(long, default_value_t = gtsr_mesh::DEFAULT_CARVE_VIEWS as usize)]
    pub carve_views: usize,
    /// Carving: margin in footprints (gtsr-train's `--carve-margin`).
    #[arg(long, default_value_t = gtsr_mesh::DEFAULT_CARVE_MARGIN)]
    pub carve_margin: f32,
    /// Carving: least free share (gtsr-train's `--carve-free-ratio`).
    #[arg(long, default_value_t = 0.5)]
    pub carve_free_ratio: f32,
    /// Carving: depth steps to the steepest neighbour added to the margin (the mesh setting
    /// `carve_slope`; 0: off).
    #[arg(long, default_value_t = 0.0)]
    pub carve_slope: f32,
    /// Carving: read the depth bilinearly at each point's projection (the mesh setting
    /// `carve_bilinear`).
    #[arg(long)]
    pub carve_bilinear: bool,
    /// Carving: a view votes free only where its depth lies this many footprints behind the
    /// masks' own depth at that pixel (the mesh setting `carve_concavity_gate`; 0: off).
    #[arg(long, default_value_t = gtsr_mesh::DEFAULT_CONCAVITY_GATE)]
    pub carve_concavity_gate: f32,
    /// Carving: the concavity gate's window radius in pixels (`carve_gate_radius`).
    #[arg(long, default_value_t = 0)]
    pub carve_gate_radius: usize,
    /// Carving: leave out the carved walls no depth map observes within this many
    /// footprints (the mesh setting `cull_unobserved`; 0: off).
    #[arg(long, default_value_t = gtsr_mesh::DEFAULT_CULL_UNOBSERVED)]
    pub cull_unobserved: f32,
    /// Leave out the TSDF fusions (with `--carve`: only the carving rows).
    #[arg(long)]
    pub no_tsdf: bool,
    /// With `--carve`, also carve with depth maps that keep the masks' own depth except at
    /// the *dark* pixels: those whose image is below this share of the scattering model's
    /// prediction from the masks' mesh (`gtsr_mesh::scatter::unexplained_dark`), which take
    /// the true depth. What the images' unexplained darkness would give the mesh with a
    /// perfect depth where it points (0: off; needs `--resolution` at the dataset's own).
    #[arg(long, default_value_t = 0.0)]
    pub dark_below: f32,
    /// With `--dark-below`: also carve with the dark pixels' depth put this many footprints
    /// behind the masks' own instead of the truth's (one row each).
    #[arg(long, num_args = 0..)]
    pub dark_depth_footprints: Vec<f32>,
    /// With `--dark-below`: also carve with the dark pixels' depth read from their darkness
    /// by the surface-space scattering model (`crate::subsurface::dark_depths`, the model
    /// fitted on the masks' mesh off the dark pixels).
    #[arg(long)]
    pub dark_surface_model: bool,
    /// With `--dark-surface-model`: the light travels only through the medium
    /// (`crate::subsurface::SurfaceMap::gather_through`).
    #[arg(long)]
    pub dark_medium: bool,
    /// With `--carve`: also carve with the masks' own depth and gtsr-train's hollow search
    /// (`gtsr_mesh::hollow`, the mesh setting `hollow_search`), which reads from the images
    /// how deep the dark pixels' hollow runs (needs `--resolution` at the dataset's own).
    #[arg(long)]
    pub hollow_search: bool,
}

/// How near (in pixel footprints) a ground-truth face's centroid must lie to the first hit at
/// its pixel for that pixel to show it.
const PIXEL_VISIBLE_FOOTPRINTS: f32 = 0.5;

/// One fusion: the label, whether the masks carve, whether depth is fused, the truncation,
/// the depth error added.
struct Variant {
    label: String,
    carving: bool,
    depth: bool,
    truncation: f32,
    bias: f32,
}

/// One fused mesh's numbers.
struct Row {
    label: String,
    /// Chamfer against the seen ground truth.
    chamfer: f64,
    /// Chamfer against all of it.
    chamfer_whole: f64,
    fscore: f64,
    /// Mean distance on the ground truth the masks miss (with `--carve`).
    blind: Option<f64>,
    seconds: f64,
}

/// The rows of one scene.
fn scene_rows(scene_dir: &Path, name: &str, args: &FusionCeilingArgs) -> Result<Vec<Row>> {
    let opts = LoadOptions {
        downscale: Downscale::MaxSide(args.resolution),
        ..LoadOptions::default()
    };
    let scene = load_scene(scene_dir, &opts)?;
    if scene.normalisation_applied {
        bail!(
            "{}: expected a Blender scene in file units",
            scene_dir.display()
        );
    }
    let masked: Vec<(gtsr_data::Camera, &[f32])> = scene
        .train
        .iter()
        .filter_map(|v| v.mask.as_deref().map(|m| (v.camera, m)))
        .collect();
    if masked.len() != scene.train.len() || masked.is_empty() {
        bail!("{}: every training view needs a mask", scene_dir.display());
    }
    let gt = ground_truth(&scene, scene_dir)?;
    let caster = MeshRaycaster::new(&gt, "ground truth")?;
    let (lo, hi) = gtsr_mesh::hull::hull_box(&masked)?
        .with_context(|| format!("{}: nothing is inside every mask", scene_dir.display()))?;
    let radius = 0.5 * (hi - lo).max_element();
    let footprint = median_pixel_footprint(scene.train.iter().map(|v| &v.camera), 0.5 * (lo + hi));
    let voxel = default_voxel(radius, footprint);
    let long = default_truncation(radius, footprint, true);
    println!(
        "{}: box radius {radius:.3}, voxel {voxel:.5}, footprint {footprint:.4}, \
         default truncation {long:.3}",
        scene_dir.display()
    );

    // The ground truth's depth per training view, prepared as gtsr-train prepares rendered
    // depth (masked, without grazing pixels and without depth edges).
    let depths = prepared_depths(&scene, &caster, args.keep_edges)?;

    let mut variants = Vec::new();
    if !args.no_default {
        variants.push(Variant {
            label: "masks only (no depth), default truncation".into(),
            carving: true,
            depth: false,
            truncation: long,
            bias: 0.0,
        });
        variants.push(Variant {
            label: format!("true depth + masks, default truncation ({long:.3})"),
            carving: true,
            depth: true,
            truncation: long,
            bias: 0.0,
        });
    }
    for &k in &args.footprints {
        variants.push(Variant {
            label: format!(
                "true depth + masks, truncation {k} footprints ({:.3})",
                k * footprint
            ),
            carving: true,
            depth: true,
            truncation: (k * footprint).max(voxel),
            bias: 0.0,
        });
    }
    if let Some(k) = args.footprints.iter().copied().reduce(f32::max) {
        for &b in &args.biases {
            variants.push(Variant {
                label: format!(
                    "true depth {b:+} + masks, truncation {k} footprints ({:.3})",
                    k * footprint
                ),
                carving: true,
                depth: true,
                truncation: (k * footprint).max(voxel),
                bias: b,
            });
        }
    }
    if !args.no_depth_alone {
        variants.push(Variant {
            label: format!(
                "true depth alone, truncation {DEPTH_ONLY_TRUNCATION_FOOTPRINTS} footprints ({:.3})",
                DEPTH_ONLY_TRUNCATION_FOOTPRINTS * footprint
            ),
            carving: false,
            depth: true,
            truncation: (DEPTH_ONLY_TRUNCATION_FOOTPRINTS * footprint).max(voxel),
            bias: 0.0,
        });
    }

    let eyes: Vec<gtsr_data::Camera> = scene.train.iter().map(|v| v.camera).collect();
    let dir = args.out.join(name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut rows = Vec::new();
    if args.carve {
        rows.extend(carve_rows(scene_dir, &scene, &depths, &gt, &eyes, args)?);
    }
    if args.no_tsdf {
        variants.clear();
    }
    for (n, var) in variants.iter().enumerate() {
        let t0 = Instant::now();
        // Depth 0 is no measurement and stays so; the rest move by the bias.
        let biased = biased_depths(&depths, var.bias);
        let views: Vec<FusionView> = scene
            .train
            .iter()
            .zip(&biased)
            .map(|(v, depth)| FusionView {
                camera: &v.camera,
                depth,
                mask: v.mask.as_deref().expect("checked above"),
                normal: &[],
            })
            .collect();
        let config = MeshConfig {
            fusion: Fusion::Tsdf,
            voxel: Some(voxel),
            truncation: Some(var.truncation),
            silhouette_carving: var.carving,
            fuse_depth: var.depth,
            hull_inside_distance: var.carving && args.hull_inside_distance,
            ..MeshConfig::default()
        };
        let inputs = FusionInputs {
            views: &views,
            masked: true,
            masks: None,
            footprint_cameras: &eyes,
            bounds: (lo, hi),
            coarse: false,
        };
        let (mesh, _) = extract_mesh(&config, &inputs)?;
        if mesh.triangles.is_empty() {
            bail!("{name}: {}: empty mesh", var.label);
        }
        let (seen, whole) = score_against_ground_truth(&mesh, &gt, &eyes, None)?;
        let secs = t0.elapsed().as_secs_f64();
        println!(
            "  {}: chamfer x1e3 {:.2} (whole GT {:.2}), F-score {:.3}, {secs:.0} s",
            var.label,
            1e3 * seen.chamfer,
            1e3 * whole.chamfer,
            seen.fscore
        );
        gtsr_data::ply::write_ply(&dir.join(format!("mesh-{n}.ply")), &mesh)?;
        rows.push(Row {
            label: var.label.clone(),
            chamfer: seen.chamfer,
            chamfer_whole: whole.chamfer,
            fscore: seen.fscore,
            blind: None,
            seconds: secs,
        });
    }
    Ok(rows)
}

/// The masks alone at the dataset's resolution, and carved by the true depth (plus each bias).
fn carve_rows(
    scene_dir: &Path,
    scene: &gtsr_data::Scene,
    depths: &[Vec<f32>],
    gt: &gtsr_data::ply::TriMesh,
    eyes: &[gtsr_data::Camera],
    args: &FusionCeilingArgs,
) -> Result<Vec<Row>> {
    let native = load_scene(
        scene_dir,
        &LoadOptions {
            downscale: Downscale::None,
            ..LoadOptions::default()
        },
    )?;
    let masks: Vec<(gtsr_data::Camera, &[f32])> = native
        .train
        .iter()
        .filter_map(|v| v.mask.as_deref().map(|m| (v.camera, m)))
        .collect();
    let (lo, hi) = gtsr_mesh::hull::hull_box(&masks)?.context("empty masks")?;
    let t0 = Instant::now();
    // Bounded by the hull of the masks' edges, as gtsr-train's default; scored against the
    // masks alone. With the images' radiance, for the carving's shading check.
    let radiance: Vec<Vec<f32>> = (native.train.iter())
        .map(|v| view_radiance(v, None))
        .collect();
    let alone = MasksAlone::new(masks.iter().map(|(c, m)| (*c, m.to_vec())).collect())?
        .context("empty masks")?
        .with_edge_distance()?
        .with_radiance(radiance.clone())?;
    let hull = alone.mesh.clone();
    let mut rows = Vec::new();
    let dir = args.out.join(scene_name(scene_dir));
    let mut written = 0usize;
    let mut score = |label: String, mesh: &gtsr_data::ply::TriMesh, secs: f64| -> Result<()> {
        let (seen, whole) = score_against_ground_truth(mesh, gt, eyes, Some(&hull))?;
        // Each carving row's mesh, numbered in the table's order.
        let path = dir.join(format!("carve-{written}.ply"));
        gtsr_data::ply::write_ply(&path, mesh)?;
        written += 1;
        let blind = seen.hull_blind.map(|b| b.blind);
        println!(
            "  {label}: chamfer x1e3 {:.2} (accuracy {:.2}, completeness {:.2}; whole GT {:.2}), \
             hull-blind {:.2}, {secs:.0} s ({})",
            1e3 * seen.chamfer,
            1e3 * seen.accuracy,
            1e3 * seen.completeness,
            1e3 * whole.chamfer,
            1e3 * blind.unwrap_or(f64::NAN),
            path.display()
        );
        rows.push(Row {
            label,
            chamfer: seen.chamfer,
            chamfer_whole: whole.chamfer,
            fscore: seen.fscore,
            blind,
            seconds: secs,
        });
        Ok(())
    };
    score(
        format!(
            "masks alone ({}x{} masks, sub-voxel)",
            masks[0].0.width, masks[0].0.height
        ),
        &hull,
        t0.elapsed().as_secs_f64(),
    )?;
    // What the cameras can see of the ground truth: its outer surface (openings narrower
    // than a training pixel's footprint sealed), and the faces the training pixels show.
    // Scored as a reconstruction, each is a floor of any mesh made from these images.
    let footprint = median_pixel_footprint(eyes.iter(), 0.5 * (lo + hi));
    let area = gtsr_mesh::mesh::surface_area(gt);
    let t0 = Instant::now();
    let outer = gtsr_mesh::visible::outer_surface(gt, gtsr_mesh::visible::OUTER_GRID, footprint)?;
    score(
        format!(
            "floor: the ground truth's outer surface ({:.1} % of its area inside or sealed)",
            100.0 * (1.0 - gtsr_mesh::mesh::surface_area(&outer) / area)
        ),
        &outer,
        t0.elapsed().as_secs_f64(),
    )?;
    let t0 = Instant::now();
    let native_cameras: Vec<gtsr_data::Camera> = masks.iter().map(|(c, _)| *c).collect();
    let shown =
        gtsr_mesh::visible::pixel_visible_faces(gt, &native_cameras, PIXEL_VISIBLE_FOOTPRINTS)?;
    score(
        format!(
            "floor: the ground-truth faces the training pixels show ({:.1} % of its area shown by none)",
            100.0 * (1.0 - gtsr_mesh::mesh::surface_area(&shown) / area)
        ),
        &shown,
        t0.elapsed().as_secs_f64(),
    )?;
    let config = MeshConfig {
        fusion: Fusion::Carve,
        carve_views: args.carve_views as u64,
        carve_margin: args.carve_margin,
        carve_free_ratio: args.carve_free_ratio,
        carve_slope: args.carve_slope,
        carve_bilinear: args.carve_bilinear,
        carve_concavity_gate: args.carve_concavity_gate,
        carve_gate_radius: args.carve_gate_radius,
        cull_unobserved: args.cull_unobserved,
        // The carving alone (with its shading check): the shading refinement that follows it
        // in gtsr-train reads the images, not the depth (`shading-stereo` measures it).
        shading_anchor: 0.0,
        hollow_search: false,
        ..MeshConfig::default()
    };
    // Each carving's label and depth maps: the true depth with each bias, then the masks' own
    // depth with the true (or a guessed) depth at the dark pixels only.
    let mut runs: Vec<(String, Vec<Vec<f32>>)> = std::iter::once(0.0)
        .chain(args.biases.iter().copied())
        .map(|bias| {
            (
                format!(
                    "masks carved by the true depth {bias:+} (gtsr-train's default extraction)"
                ),
                biased_depths(depths, bias),
            )
        })
        .collect();
    if args.dark_below > 0.0 {
        if scene.train[0].camera.width != native.train[0].camera.width {
            bail!(
                "{}: --dark-below reads the images at their own {} px: give --resolution {}",
                scene_dir.display(),
                native.train[0]
                    .camera
                    .width
                    .max(native.train[0].camera.height),
                native.train[0]
                    .camera
                    .width
                    .max(native.train[0].camera.height)
            );
        }
        let images: Vec<ShadingImage> = (native.train.iter().zip(&radiance))
            .map(|(v, r)| ShadingImage {
                camera: &v.camera,
                radiance: r,
                mask: v.mask.as_deref(),
            })
            .collect();
        let (model, dark) = unexplained_dark(&hull, &images, args.dark_below)?;
        let lid = MeshRaycaster::new(&hull, "masks' mesh")?;
        let lid_depths = prepared_depths(scene, &lid, args.keep_edges)?;
        // How many dark pixels there are, and how many lie over a concavity (the truth more
        // than the concavity gate behind the masks' own depth) or on the flush surface.
        let (mut n, mut concave, mut flush) = (0usize, 0usize, 0usize);
        for ((d, t), l) in dark.iter().zip(depths).zip(&lid_depths) {
            for p in 0..d.len() {
                if !d[p] {
                    continue;
                }
                n += 1;
                let fp = l[p] / scene.train[0].camera.fx;
                if t[p] > 0.0 && l[p] > 0.0 {
                    concave += usize::from(t[p] - l[p] > args.carve_concavity_gate * fp);
                    flush += usize::from((t[p] - l[p]).abs() < 0.5 * fp);
                }
            }
        }
        println!(
            "  dark pixels (image below {} of the model's prediction from the masks' mesh; \
             a {:.3}, b {:.3}, blur {:.1} px, pixel filter {:.1} px): {n} over {} views, \
             {concave} over a concavity (truth > {} fp behind), {flush} on the flush surface",
            args.dark_below,
            model.sharp,
            model.blurred,
            model.sigma,
            model.pixel,
            dark.iter().filter(|d| d.iter().any(|x| *x)).count(),
            args.carve_concavity_gate
        );
        let at_dark = |f: &dyn Fn(usize, usize) -> f32| -> Vec<Vec<f32>> {
            (lid_depths.iter().enumerate())
                .map(|(k, l)| {
                    (0..l.len())
                        .map(|p| if dark[k][p] { f(k, p) } else { l[p] })
                        .collect()
                })
                .collect()
        };
        runs.push((
            format!(
                "masks carved by their own depth, the true depth at the dark pixels (image < {} x prediction)",
                args.dark_below
            ),
            at_dark(&|k, p| depths[k][p]),
        ));
        for &f in &args.dark_depth_footprints {
            let fx = scene.train[0].camera.fx;
            runs.push((
                format!(
                    "masks carved by their own depth, the dark pixels' {f} fp behind it (image < {} x prediction)",
                    args.dark_below
                ),
                at_dark(&|k, p| {
                    let l = lid_depths[k][p];
                    if l > 0.0 { l * (1.0 + f / fx) } else { 0.0 }
                }),
            ));
        }
        if args.dark_surface_model {
            let t0 = Instant::now();
            let views = surface_views(&hull, &images, model.pixel)?;
            let fp = median_depth(&views) / scene.train[0].camera.fx;
            let widths: Vec<f32> = SURFACE_WIDTHS_FP.iter().map(|w| w * fp).collect();
            let fit = fit_surface_scatter(
                &views,
                Some(&dark),
                &widths,
                model.pixel,
                DARK_MIN_COS,
                2,
                args.dark_medium,
            )?;
            println!(
                "  surface-space scattering on the masks' mesh off the dark pixels: a {:.3}, \
                 b {:?} at widths {:?} fp, residual {:.4} over {} pixels ({:.1} s)",
                fit.sharp,
                fit.weights,
                SURFACE_WIDTHS_FP,
                fit.residual,
                fit.samples,
                t0.elapsed().as_secs_f64()
            );
            // The pixels the surface model cannot explain as dark as they are, per share.
            for r in [0.3f32, 0.4, 0.5, 0.6, 0.7] {
                let (mut n, mut concave, mut flush) = (0usize, 0usize, 0usize);
                for (k, v) in views.iter().enumerate() {
                    for p in 0..v.radiance.len() {
                        let z = v.map.depth()[p];
                        if z <= 0.0
                            || v.cosine[p] < DARK_MIN_COS
                            || v.mask.is_some_and(|m| m[p] < 0.99)
                        {
                            continue;
                        }
                        let pred = fit.predict(&v.map, p, v.map.point(p), v.sharp_lambert[p]);
                        if v.radiance[p].is_nan() || v.radiance[p] >= r * pred {
                            continue;
                        }
                        n += 1;
                        let (l, t) = (lid_depths[k][p], depths[k][p]);
                        let fp = l / scene.train[0].camera.fx;
                        if t > 0.0 && l > 0.0 {
                            concave += usize::from(t - l > args.carve_concavity_gate * fp);
                            flush += usize::from((t - l).abs() < 0.5 * fp);
                        }
                    }
                }
                println!(
                    "    below {r} of the surface model's prediction: {n} pixels, {concave} over a concavity, {flush} flush"
                );
            }
            // Diagnosis: the surface model on the truth's own shape, at the dark pixels over a
            // concavity and the flush ones (fitted there, and the masks' fit applied).
            {
                let tviews = surface_views(gt, &images, model.pixel)?;
                let tfit = fit_surface_scatter(
                    &tviews,
                    Some(&dark),
                    &widths,
                    model.pixel,
                    DARK_MIN_COS,
                    2,
                    args.dark_medium,
                )?;
                println!(
                    "    on the truth: a {:.3}, b {:?}, residual {:.4}",
                    tfit.sharp, tfit.weights, tfit.residual
                );
                for (name, f) in [("masks' fit", &fit), ("truth's fit", &tfit)] {
                    let (mut rc, mut nc, mut rf, mut nf, mut rl) =
                        (Vec::new(), 0, Vec::new(), 0, Vec::new());
                    for (k, v) in tviews.iter().enumerate() {
                        for p in 0..v.radiance.len() {
                            let (l, t) = (lid_depths[k][p], depths[k][p]);
                            if !dark[k][p] || l <= 0.0 || t <= 0.0 || v.map.depth()[p] <= 0.0 {
                                continue;
                            }
                            let fp = l / scene.train[0].camera.fx;
                            let pred = f.predict(&v.map, p, v.map.point(p), v.sharp_lambert[p]);
                            let lidp = fit.predict(
                                &views[k].map,
                                p,
                                views[k].map.point(p),
                                views[k].sharp_lambert[p],
                            );
                            if t - l > args.carve_concavity_gate * fp {
                                nc += 1;
                                rc.push(v.radiance[p] / pred.max(1e-12));
                                rl.push(v.radiance[p] / lidp.max(1e-12));
                            } else if (t - l).abs() < 0.5 * fp {
                                nf += 1;
                                rf.push(v.radiance[p] / pred.max(1e-12));
                            }
                        }
                    }
                    println!(
                        "    {name} on the truth's shape: image / prediction median {:.3} over {nc} concave dark pixels (lid {:.3}), {:.3} over {nf} flush dark ones",
                        median(&mut rc),
                        median(&mut rl),
                        median(&mut rf)
                    );
                }
            }
            // How dark depth alone can make the dark pixels: every dark pixel of a view moved
            // the deepest offset back, against the lid.
            {
                let deepest = DarkDepthSettings::default().max_footprints;
                let fx = scene.train[0].camera.fx;
                let mut share: Vec<f32> = Vec::new();
                let mut image: Vec<f32> = Vec::new();
                for (v, d) in views.iter().zip(&dark) {
                    let moved: Vec<f32> = (v.map.depth().iter().zip(d))
                        .map(|(z, k)| if *k { z * (1.0 + deepest / fx) } else { *z })
                        .collect();
                    let mut map = v.map.clone();
                    map.set_depth(&moved)?;
                    for p in (0..moved.len()).filter(|p| d[*p] && moved[*p] > 0.0) {
                        let lid = fit.predict(&v.map, p, v.map.point(p), v.sharp_lambert[p]);
                        let deep = fit.predict(&map, p, map.point(p), v.sharp_lambert[p]);
                        share.push(deep / lid.max(1e-12));
                        image.push(v.radiance[p] / lid.max(1e-12));
                    }
                }
                println!(
                    "    every dark pixel {deepest} fp deeper: the model's radiance falls to {:.3} of the lid's (median), the image is {:.3} of it",
                    median(&mut share),
                    median(&mut image)
                );
            }
            let t0 = Instant::now();
            let offsets = dark_depths(&fit, &views, &dark, &DarkDepthSettings::default())?;
            // The offsets read against the truth's, at the dark pixels with both depths.
            let fx = scene.train[0].camera.fx;
            let mut pairs: Vec<(f32, f32)> = Vec::new();
            for k in 0..dark.len() {
                for p in 0..dark[k].len() {
                    let (l, t) = (lid_depths[k][p], depths[k][p]);
                    if dark[k][p] && l > 0.0 && t > 0.0 {
                        pairs.push((offsets[k][p], (t - l) * fx / l));
                    }
                }
            }
            let n = pairs.len().max(1) as f32;
            let mean = |f: &dyn Fn(&(f32, f32)) -> f32| pairs.iter().map(f).sum::<f32>() / n;
            println!(
                "  dark pixels' offsets from the surface model ({:.1} s): mean {:.1} fp (truth \
                 {:.1}), mean |error| {:.1} fp over {} pixels",
                t0.elapsed().as_secs_f64(),
                mean(&|x| x.0),
                mean(&|x| x.1),
                mean(&|x| (x.0 - x.1).abs()),
                pairs.len()
            );
            for (lo, hi) in [
                (-1e9, 3.0),
                (3.0, 10.0),
                (10.0, 20.0),
                (20.0, 30.0),
                (30.0, 45.0),
                (45.0, 1e9),
            ] {
                let bin: Vec<f32> = (pairs.iter())
                    .filter(|x| x.1 >= lo && x.1 < hi)
                    .map(|x| x.0)
                    .collect();
                if !bin.is_empty() {
                    println!(
                        "    truth {lo:.0}..{hi:.0} fp: {} pixels, model's mean {:.1} fp",
                        bin.len(),
                        bin.iter().sum::<f32>() / bin.len() as f32
                    );
                }
            }
            runs.push((
                format!(
                    "masks carved by their own depth, the dark pixels at the surface model's depth (image < {} x prediction)",
                    args.dark_below
                ),
                at_dark(&|k, p| {
                    let l = lid_depths[k][p];
                    if l > 0.0 { l * (1.0 + offsets[k][p] / fx) } else { 0.0 }
                }),
            ));
        }
    }
    let mut hollow_runs = Vec::new();
    if args.hollow_search {
        let lid = MeshRaycaster::new(&hull, "masks' mesh")?;
        hollow_runs.push((
            "masks carved by their own depth, the hollow search's depth at the dark pixels (gtsr_mesh::hollow)".to_string(),
            prepared_depths(scene, &lid, args.keep_edges)?,
        ));
    }
    let hollow_config = MeshConfig {
        hollow_search: true,
        ..config.clone()
    };
    let all = (runs.into_iter().map(|r| (r, &config)))
        .chain(hollow_runs.into_iter().map(|r| (r, &hollow_config)));
    for ((label, biased), config) in all {
        let t0 = Instant::now();
        let views: Vec<FusionView> = scene
            .train
            .iter()
            .zip(&biased)
            .map(|(v, depth)| FusionView {
                camera: &v.camera,
                depth,
                mask: v.mask.as_deref().expect("checked by the caller"),
                normal: &[],
            })
            .collect();
        let inputs = FusionInputs {
            views: &views,
            masked: true,
            masks: Some(&alone),
            footprint_cameras: eyes,
            bounds: (lo, hi),
            coarse: false,
        };
        let (mesh, notes) = extract_mesh(config, &inputs)?;
        for note in &notes {
            println!("  {note}");
        }
        score(label, &mesh, t0.elapsed().as_secs_f64())?;
    }
    Ok(rows)
}

/// `caster`'s depth per training view of `scene`, prepared as gtsr-train prepares rendered
/// depth (masked, without grazing pixels and, unless `keep_edges`, without depth edges).
fn prepared_depths(
    scene: &gtsr_data::Scene,
    caster: &MeshRaycaster,
    keep_edges: bool,
) -> Result<Vec<Vec<f32>>> {
    scene
        .train
        .iter()
        .map(|v| {
            let c = &v.camera;
            let md = caster.render(c);
            let mask = v
                .mask
                .as_deref()
                .context("every training view needs a mask")?;
            let rays: Vec<Vec3> = (0..md.depth.len())
                .map(|p| {
                    let (i, j) = ((p % md.width) as f32, (p / md.width) as f32);
                    c.camera_direction(i + 0.5, j + 0.5)
                })
                .collect();
            let plane: Vec<f32> = (0..md.depth.len())
                .map(|p| md.depth[p] * -md.normal[p].dot(rays[p]))
                .collect();
            let flat = |v: &[Vec3]| v.iter().flat_map(|x| x.to_array()).collect::<Vec<f32>>();
            let (normal, rays) = (flat(&md.normal), flat(&rays));
            let mut depth = md.depth.clone();
            let geometry = DepthGeometry {
                normal: &normal,
                plane: &plane,
                rays: &rays,
                coverage: None,
            };
            gtsr_mesh::prepare_depth(c, &mut depth, &geometry, mask, !keep_edges)?;
            Ok(depth)
        })
        .collect()
}

/// The depth maps moved by `bias` along the view (0, no measurement, stays 0).
fn biased_depths(depths: &[Vec<f32>], bias: f32) -> Vec<Vec<f32>> {
    depths
        .iter()
        .map(|d| {
            d.iter()
                .map(|&z| if z > 0.0 { (z + bias).max(0.0) } else { 0.0 })
                .collect()
        })
        .collect()
}

/// Runs the experiment and writes `out/fusion-ceiling.md`.
pub fn run(args: &FusionCeilingArgs) -> Result<()> {
    let mut md = String::from(
        "| scene | fusion of the ground truth's depth maps | chamfer x1e3 | whole GT | hull-blind x1e3 | F-score | time (s) |\n\
         |---|---|---:|---:|---:|---:|---:|\n",
    );
    for scene_dir in &args.data {
        let name = scene_name(scene_dir);
        for r in scene_rows(scene_dir, &name, args)? {
            md += &format!(
                "| {name} | {} | {:.2} | {:.2} | {} | {:.3} | {:.0} |\n",
                r.label,
                1e3 * r.chamfer,
                1e3 * r.chamfer_whole,
                r.blind.map_or("-".into(), |b| format!("{:.2}", 1e3 * b)),
                r.fscore,
                r.seconds
            );
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let path = args.out.join("fusion-ceiling.md");
    std::fs::write(&path, &md).with_context(|| format!("writing {}", path.display()))?;
    println!("{md}\ntable {}", path.display());
    Ok(())
}

/// The median of `v` (sorted in place), NaN when empty.
fn median(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    crate::concavity::percentile(v, 0.5)
}
