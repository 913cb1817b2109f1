//! What the diagnostic examples share: a development scene at its own resolution, its masks'
//! mesh and its ground truth.

use std::path::Path;

use glam::Vec3;
use gtsr_data::ply::TriMesh;
use gtsr_data::{Camera, Downscale, LoadOptions, Scene, load_scene};
use gtsr_mesh::raycast::MeshDepth;

/// A development scene loaded at the dataset's resolution, with the masks' mesh (sub-voxel,
/// `gtsr_mesh::hull::masks_mesh`) and the ground truth (`mesh.ply`).
pub struct DevScene {
    pub scene: Scene,
    pub hull: TriMesh,
    pub gt: TriMesh,
}

/// Loads `dir`. Errors name the view without a mask, empty masks or a missing `mesh.ply`.
pub fn load(dir: &Path) -> anyhow::Result<DevScene> {
    let opts = LoadOptions {
        downscale: Downscale::None,
        ..LoadOptions::default()
    };
    let scene = load_scene(dir, &opts)?;
    let hull = gtsr_mesh::hull::masks_mesh(&masks(&scene)?, None)?
        .ok_or_else(|| anyhow::anyhow!("{}: empty masks", dir.display()))?;
    let gt_path = scene
        .mesh_path
        .clone()
        .ok_or_else(|| anyhow::anyhow!("{}: no mesh.ply", dir.display()))?;
    let gt = gtsr_data::ply::read_ply(&gt_path)?;
    Ok(DevScene { scene, hull, gt })
}

/// Every training view's camera and mask; an error names a view without one.
pub fn masks(scene: &Scene) -> anyhow::Result<Vec<(Camera, &[f32])>> {
    scene
        .train
        .iter()
        .map(|v| {
            v.mask
                .as_deref()
                .map(|m| (v.camera, m))
                .ok_or_else(|| anyhow::anyhow!("view {} has no mask", v.name))
        })
        .collect()
}

/// The ground truth ray cast from every training view at the dataset's resolution.
#[allow(dead_code)] // Each example compiles this module; not all of them ask for these maps.
pub fn truth_maps(scene: &Scene, gt: &TriMesh) -> anyhow::Result<Vec<MeshDepth>> {
    let caster = gtsr_mesh::raycast::MeshRaycaster::new(gt, "ground truth")?;
    Ok(scene
        .train
        .iter()
        .map(|v| caster.render(&v.camera))
        .collect())
}

/// In how many training views the ground truth's own first hit (`maps`, the ground truth ray
/// cast from each view at the dataset's resolution) at `p`'s pixel lies within 0.011 of `p`.
#[allow(dead_code)] // Each example compiles this module; not all of them ask for visibility.
pub fn views_showing(scene: &Scene, maps: &[MeshDepth], p: Vec3) -> usize {
    (scene.train.iter().zip(maps))
        .filter(|(v, m)| {
            v.camera.project(p).is_some_and(|(uv, z)| {
                let (i, j) = (uv.x.floor(), uv.y.floor());
                i >= 0.0 && j >= 0.0 && (i as usize) < m.width && (j as usize) < m.height && {
                    let hit = m.depth[j as usize * m.width + i as usize];
                    hit > 0.0 && (hit - z).abs() < 0.011
                }
            })
        })
        .count()
}
