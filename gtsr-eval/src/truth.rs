//! A development scene's references for scoring: its ground-truth mesh and its masks alone at
//! the dataset's own resolution (the baseline every mesh is held to).

use std::path::Path;

use gtsr_data::ply::TriMesh;
use gtsr_data::{Downscale, LoadOptions, Scene, load_scene};
use gtsr_mesh::MeshError;
use gtsr_mesh::hull::masks_mesh;

use crate::error::Result;

/// A scene folder's name, as tables and output folders use it (`"scene"` for a bare root).
pub fn scene_name(scene_dir: &Path) -> String {
    scene_dir
        .file_name()
        .map_or_else(|| "scene".to_string(), |s| s.to_string_lossy().into_owned())
}

/// The scene's ground-truth `mesh.ply`; an error naming the folder when it has none.
pub fn ground_truth(scene: &Scene, scene_dir: &Path) -> Result<TriMesh> {
    let gt_path = scene.mesh_path.clone().ok_or_else(|| {
        MeshError::InvalidArgument(format!("{}: no mesh.ply", scene_dir.display()))
    })?;
    Ok(gtsr_data::ply::read_ply(&gt_path)?)
}

/// The scene at its own resolution and its masks' mesh ([`masks_mesh`]); errors unless every
/// training view has a mask and something lies inside all of them.
pub fn native_masks_mesh(scene_dir: &Path) -> Result<(Scene, TriMesh)> {
    let opts = LoadOptions {
        downscale: Downscale::None,
        ..LoadOptions::default()
    };
    let scene = load_scene(scene_dir, &opts)?;
    let views: Vec<_> = scene
        .train
        .iter()
        .filter_map(|v| v.mask.as_ref().map(|m| (v.camera, m.as_slice())))
        .collect();
    if views.is_empty() || views.len() != scene.train.len() {
        return Err(MeshError::InvalidArgument(format!(
            "{}: the masks alone need a mask on every training view",
            scene_dir.display()
        ))
        .into());
    }
    let mesh = masks_mesh(&views, None)?.ok_or_else(|| {
        MeshError::InvalidArgument(format!("{}: the masks are empty", scene_dir.display()))
    })?;
    Ok((scene, mesh))
}
