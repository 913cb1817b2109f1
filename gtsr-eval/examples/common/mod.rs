//! What the diagnostic examples share: a development scene at its own resolution, its masks'
//! mesh and its ground truth.

use std::path::Path;

use gtsr_data::ply::TriMesh;
use gtsr_data::{Camera, Downscale, LoadOptions, Scene, load_scene};

/// A development scene loaded at the dataset's resolution, with the masks' mesh (sub-voxel,
/// `gtsr_eval::masks_mesh`) and the ground truth (`mesh.ply`).
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
    let hull = gtsr_eval::masks_mesh(&masks(&scene)?, None)?
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
