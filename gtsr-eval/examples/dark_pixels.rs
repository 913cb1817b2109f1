//! Whether the pixels the hollow search starts from lie over a concavity: flags the training
//! images' unexplained dark pixels (`gtsr_eval::scatter::unexplained_dark` on the masks'
//! mesh, below 0.3 of the scattering prediction, as `gtsr_eval::hollow` does before its own
//! edge and mask filters) and counts how many of them, and of all pixels, look at ground
//! truth more than 3 footprints behind the masks' mesh.
//!
//! ```text
//! cargo run --release -p gtsr-eval --example dark_pixels -- ../shared/data/amber_ingot
//! ```

use std::path::PathBuf;

use gtsr_eval::MeshRaycaster;
use gtsr_eval::shading::{ShadingImage, view_radiance};

mod common;

/// A pixel is over a concavity when the truth lies this many footprints behind the lid.
const BEHIND_FOOTPRINTS: f32 = 3.0;

fn main() -> anyhow::Result<()> {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: dark_pixels SCENE_DIR"))?
        .into();
    let common::DevScene { scene, hull, gt } = common::load(&dir)?;
    let radiance: Vec<Vec<f32>> = scene.train.iter().map(|v| view_radiance(v, None)).collect();
    let images: Vec<ShadingImage> = (scene.train.iter().zip(&radiance))
        .map(|(v, r)| ShadingImage {
            camera: &v.camera,
            radiance: r,
            mask: v.mask.as_deref(),
        })
        .collect();
    let (_, dark) = gtsr_eval::scatter::unexplained_dark(&hull, &images, 0.3)?;
    let truth = MeshRaycaster::new(&gt, "ground truth")?;
    let lid = MeshRaycaster::new(&hull, "masks' mesh")?;
    let (mut flagged, mut flagged_over, mut over) = (0usize, 0usize, 0usize);
    for (v, d) in scene.train.iter().zip(&dark) {
        let (t, l) = (truth.render(&v.camera), lid.render(&v.camera));
        for (p, is_dark) in d.iter().enumerate() {
            let footprint = l.depth[p] / l.focal;
            let behind = t.depth[p] > 0.0
                && l.depth[p] > 0.0
                && t.depth[p] - l.depth[p] > BEHIND_FOOTPRINTS * footprint;
            over += usize::from(behind);
            flagged += usize::from(*is_dark);
            flagged_over += usize::from(*is_dark && behind);
        }
    }
    println!(
        "{flagged} dark pixels, {flagged_over} of them over a concavity (truth more than \
         {BEHIND_FOOTPRINTS} footprints behind the masks' mesh); {over} pixels over one in all"
    );
    Ok(())
}
