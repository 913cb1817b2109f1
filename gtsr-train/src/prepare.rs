//! What a run prepares before training: the built-in scene, the compute device, the
//! masks at the dataset's resolution, the fusion views, the bound's depth for the hull-depth
//! term and the surface set's starting points from a mesh.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use gtsr_data::synthetic::{SceneConfig, ShapeKind, generate_scene};
use gtsr_data::transport::MaterialPreset;
use gtsr_data::{Downscale, LoadOptions, Scene, load_scene};
use gtsr_model::views::{ViewTensors, data_camera};
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::Backend;

/// The least departure of a view's exposure from the views' mean, in stops, that a run takes
/// out of the images: above what [`gtsr_data::light::read_views`] reads on views of one
/// exposure (at most 0.28 stops on the development scenes, from shading its model of the
/// light does not explain).
pub const EXPOSURE_MIN_SPREAD: f32 = 0.5;

/// Each view's exposure, read from the images once and taken out of them on every load of
/// the dataset (training, test, coarse, fusion and full-size views alike); empty when the
/// views are left as they are.
#[derive(Clone, Debug, Default)]
pub(crate) struct Exposure {
    train: Vec<f32>,
    test: Vec<f32>,
}

impl Exposure {
    /// Reads the exposures of `scene`'s training and test views together
    /// ([`gtsr_data::light::read_views`]) and keeps them where a view departs from the mean by
    /// more than [`EXPOSURE_MIN_SPREAD`]; says what it found.
    pub(crate) fn read(scene: &Scene) -> Exposure {
        let views: Vec<&gtsr_data::View> = scene.train.iter().chain(&scene.test).collect();
        if views.iter().any(|v| v.mask.is_none()) {
            return Exposure::default();
        }
        let settings = gtsr_data::light::LightSettings::default();
        let Some(reading) = gtsr_data::light::read_views(&views, &settings) else {
            println!(
                "exposure: cannot be read from the images (too little of the masks' hull seen)"
            );
            return Exposure::default();
        };
        let spread = reading.exposure_spread();
        if spread <= EXPOSURE_MIN_SPREAD {
            println!(
                "exposure: the views agree (read within {spread:.2} stops of their mean, at most \
                 {EXPOSURE_MIN_SPREAD}); images left as they are"
            );
            return Exposure::default();
        }
        let mut stops = reading.exposure_stops;
        let test = stops.split_off(scene.train.len());
        println!(
            "exposure: the views differ by up to {spread:.2} stops from their mean (read from the \
             images); each view's image is brought to the mean"
        );
        Exposure { train: stops, test }
    }

    /// Whether the views' exposures are taken out.
    pub(crate) fn applies(&self) -> bool {
        !self.train.is_empty()
    }

    /// The stops of the training views, then the test views.
    pub(crate) fn stops(&self) -> (&[f32], &[f32]) {
        (&self.train, &self.test)
    }

    /// Takes the exposures out of `scene`'s views (the same views at any size).
    pub(crate) fn apply(&self, scene: &mut Scene) {
        if self.applies() {
            gtsr_data::light::normalise_exposure(&mut scene.train, &self.train);
            gtsr_data::light::normalise_exposure(&mut scene.test, &self.test);
        }
    }
}

/// Loads the dataset with `opts` and takes `exposure` out of its images.
pub(crate) fn load_exposed(
    data_dir: &Path,
    opts: &LoadOptions,
    exposure: &Exposure,
) -> Result<Scene> {
    let mut scene = load_scene(data_dir, opts)?;
    exposure.apply(&mut scene);
    Ok(scene)
}

/// The built-in scene: a wax teddy bear, 64x64, 60 training and 8 test views.
pub(crate) fn default_scene_config() -> SceneConfig {
    let mut c = SceneConfig::new(ShapeKind::Bear, MaterialPreset::Wax);
    c.resolution = 64;
    c.n_train = 60;
    c.n_test = 8;
    c.spp = 32;
    c.seed = 0;
    c
}

pub(crate) fn ensure_default_scene(dir: &Path) -> Result<PathBuf> {
    let ready = [
        "transforms_train.json",
        "transforms_test.json",
        "mesh.ply",
        "meta.json",
    ]
    .iter()
    .all(|f| dir.join(f).is_file());
    if ready {
        println!("built-in scene: reusing {}", dir.display());
        return Ok(dir.to_path_buf());
    }
    let cfg = default_scene_config();
    let tmp = dir.with_extension("partial");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    let total = (cfg.n_train + cfg.n_test) as u64;
    println!(
        "built-in scene: path-tracing a wax bear ({}x{}, {} views, {} spp) into {}",
        cfg.resolution,
        cfg.resolution,
        total,
        cfg.spp,
        dir.display()
    );
    let bar = ProgressBar::new(total).with_style(
        ProgressStyle::with_template("  {bar:40} {pos}/{len} views  {elapsed_precise}")
            .expect("template"),
    );
    generate_scene(&tmp, &cfg, |_| bar.inc(1))
        .with_context(|| format!("generating {}", tmp.display()))?;
    bar.finish_and_clear();
    if let Some(parent) = dir.parent() {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .with_context(|| format!("removing stale {}", dir.display()))?;
    }
    std::fs::rename(&tmp, dir).with_context(|| format!("moving the scene to {}", dir.display()))?;
    Ok(dir.to_path_buf())
}

/// The training views at `--mesh-resolution`, loaded again when that is larger than what was
/// trained on; empty when it is not (the trained views are fused as they are). The default is
/// the training size: depth rendered above the size the model was trained at is no better.
pub(crate) fn fusion_views(
    mesh_resolution: Option<u32>,
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
    exposure: &Exposure,
) -> Result<Vec<gtsr_data::View>> {
    let trained = scene.train[0].width().max(scene.train[0].height());
    let wanted = mesh_resolution.unwrap_or(trained);
    if wanted <= trained {
        return Ok(Vec::new());
    }
    let fusion = load_exposed(
        data_dir,
        &LoadOptions {
            downscale: Downscale::MaxSide(wanted),
            ..opts.clone()
        },
        exposure,
    )
    .with_context(|| format!("loading {} for mesh fusion", data_dir.display()))?;
    if fusion.train.len() != scene.train.len()
        || fusion.train[0].width().max(fusion.train[0].height()) <= trained
    {
        return Ok(Vec::new());
    }
    println!(
        "mesh fusion at {}x{} (trained at {}x{})",
        fusion.train[0].width(),
        fusion.train[0].height(),
        scene.train[0].width(),
        scene.train[0].height()
    );
    Ok(fusion.train)
}

/// Each view's [`ViewTensors::hull_depth`]: `caster`'s mesh (the masks' bound) ray cast from
/// the view's camera at the view's own size,
/// without the pixels on its occluding edges at `edges` footprints (0: all kept;
/// [`gtsr_mesh::raycast::MeshDepth::occluding_edges`]), and with `occluders` > 0 each view's
/// [`ViewTensors::hull_occluders`] at that many footprints
/// ([`gtsr_mesh::raycast::MeshDepth::occluders`]).
pub(crate) fn attach_hull_depth(
    views: &mut [ViewTensors],
    caster: &gtsr_mesh::raycast::MeshRaycaster,
    edges: f32,
    occluders: f32,
) {
    for v in views.iter_mut() {
        let k = &v.camera;
        let camera = data_camera(k);
        let md = caster.render(&camera);
        let shape = [k.height as usize, k.width as usize];
        let device = v.rays.device();
        let map = |values: Vec<f32>| {
            burn::tensor::Tensor::from_data(burn::tensor::TensorData::new(values, shape), &device)
        };
        v.hull_occluders = (occluders > 0.0).then(|| map(md.occluders(occluders)));
        let cut = if edges > 0.0 {
            md.occluding_edges(edges)
        } else {
            Vec::new()
        };
        let mut depth = md.depth;
        for (d, _) in depth.iter_mut().zip(cut).filter(|(_, e)| *e) {
            *d = 0.0;
        }
        v.hull_depth = Some(map(depth));
    }
}

/// With a mask on every training view: the masks at the dataset's own resolution (loaded again
/// when training downscales), their mesh and, with `shading`, the views' linear radiance at
/// that size (for the shading refinement), and with `edge_hull` the hull of their edges that
/// bounds the extraction, read with `profile` or, without one, the measured profile
/// ([`gtsr_mesh::MasksAlone::with_edge_profile`]); `None` otherwise.
pub(crate) fn native_masks(
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
    shading: bool,
    edge_hull: bool,
    profile: Option<gtsr_mesh::hull::EdgeProfile>,
    exposure: &Exposure,
) -> Result<Option<gtsr_mesh::MasksAlone>> {
    if scene.train.iter().any(|v| v.mask.is_none()) {
        return Ok(None);
    }
    let t0 = Instant::now();
    let native;
    let views = if matches!(opts.downscale, Downscale::None) {
        &scene.train
    } else {
        native = load_exposed(
            data_dir,
            &LoadOptions {
                downscale: Downscale::None,
                ..opts.clone()
            },
            exposure,
        )
        .with_context(|| format!("loading the masks of {} at full size", data_dir.display()))?;
        if native.train.len() != scene.train.len() || native.train.iter().any(|v| v.mask.is_none())
        {
            bail!(
                "{}: the full-size training views differ",
                data_dir.display()
            );
        }
        &native.train
    };
    let radiance: Option<Vec<Vec<f32>>> = shading.then(|| {
        views
            .iter()
            .map(|v| gtsr_mesh::shading::view_radiance(v, None))
            .collect()
    });
    let views = views
        .iter()
        .map(|v| {
            v.mask
                .clone()
                .map(|m| (v.camera, m))
                .with_context(|| format!("view {} has no mask", v.name))
        })
        .collect::<Result<Vec<_>>>()?;
    let masks = match (gtsr_mesh::MasksAlone::new(views)?, radiance) {
        (Some(m), Some(r)) => Some(
            m.with_radiance(r)
                .with_context(|| format!("the images of {}", data_dir.display()))?,
        ),
        (m, _) => m,
    };
    let Some(mut masks) = masks else {
        return Ok(None);
    };
    println!(
        "masks alone at {}x{}: {} triangles, voxel {:.4} ({:.1} s)",
        masks.views[0].0.width,
        masks.views[0].0.height,
        masks.mesh.triangles.len(),
        masks.voxel,
        t0.elapsed().as_secs_f64()
    );
    if edge_hull {
        let t0 = Instant::now();
        masks = masks
            .with_edge_profile(profile)
            .with_context(|| format!("the masks' edges of {}", data_dir.display()))?;
        if let Some(e) = &masks.edge_hull {
            println!(
                "hull of the masks' edges (edge width {:.4} px, read as {}): {} triangles \
                 ({:.1} s)",
                e.width,
                e.profile,
                e.mesh.triangles.len(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
    Ok(Some(masks))
}

/// 3DGS's scene extent: 1.1 times the largest distance of a camera centre from their mean.
pub(crate) fn camera_extent(views: &[ViewTensors]) -> f64 {
    let n = views.len() as f64;
    let centres: Vec<[f64; 3]> = views.iter().map(|v| v.camera.centre()).collect();
    let mean: [f64; 3] = std::array::from_fn(|k| centres.iter().map(|c| c[k]).sum::<f64>() / n);
    let r = centres
        .iter()
        .map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    (1.1 * r).max(1e-3)
}

/// The Burn device of a backend choice (wgpu: the default adapter, a GPU where there is one).
pub(crate) fn compute_device(backend: Backend) -> Device {
    match backend {
        #[cfg(feature = "wgpu")]
        Backend::Wgpu => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice),
        _ => Device::ndarray(),
    }
}

/// `n` points sampled uniformly by area on the mesh at `path` (the dataset's own frame),
/// moved into the trained frame, for `--init-mesh`.
pub(crate) fn points_on_mesh(
    path: &Path,
    n: usize,
    seed: u64,
    scene: &Scene,
) -> Result<Vec<[f32; 3]>> {
    let mesh = gtsr_data::ply::read_ply(path)
        .with_context(|| format!("--init-mesh: reading {}", path.display()))?;
    let what = format!("--init-mesh {}", path.display());
    let samples = gtsr_mesh::mesh::sample_surface(&mesh, n, seed, &what)?;
    println!(
        "initialisation: {n} surface points on {} ({} triangles)",
        path.display(),
        mesh.triangles.len()
    );
    Ok((samples.points.iter())
        .map(|&p| {
            let p = if scene.normalisation_applied {
                scene.normalisation.to_normalised(p)
            } else {
                p
            };
            p.to_array()
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A marble sphere lit from the camera, 40 px, 24 training and 4 test views.
    fn sphere_scene(dir: &Path) -> Scene {
        let mut c = SceneConfig::new(ShapeKind::Sphere, MaterialPreset::Marble);
        c.resolution = 40;
        c.n_train = 24;
        c.n_test = 4;
        c.spp = 8;
        generate_scene(dir, &c, |_| {}).unwrap();
        load_scene(dir, &LoadOptions::default()).unwrap()
    }

    #[test]
    fn views_that_differ_in_exposure_are_brought_to_their_mean() {
        let dir = tempfile::tempdir().unwrap();
        let mut scene = sphere_scene(dir.path());
        assert!(!Exposure::read(&scene).applies(), "one exposure");
        // Up to a stop either way, as a phone's auto exposure.
        let n = scene.train.len() + scene.test.len();
        let set: Vec<f32> = (0..n).map(|k| ((k * 5) % 9) as f32 / 4.0 - 1.0).collect();
        let brighten: Vec<f32> = set.iter().map(|s| -s).collect();
        gtsr_data::light::normalise_exposure(
            scene.train.iter_mut().chain(scene.test.iter_mut()),
            &brighten,
        );
        let exposure = Exposure::read(&scene);
        assert!(exposure.applies());
        let (train, test) = exposure.stops();
        let mean = set.iter().sum::<f32>() / n as f32;
        for (k, read) in train.iter().chain(test).enumerate() {
            assert!(
                (read - (set[k] - mean)).abs() < 0.25,
                "view {k}: {read} for {}",
                set[k] - mean
            );
        }
        exposure.apply(&mut scene);
        assert!(!Exposure::read(&scene).applies(), "taken out");
    }
}
