//! `shading-stereo --depth-search`: does the images' shading say how deep a lid of the masks'
//! mesh lies over the surface?
//!
//! Under the light at the camera a Lambertian point reads `I r^2 = b . w` in every view that
//! sees it (`b` its albedo times its normal, `w` the unit direction to the eye, `r` the
//! distance). A face of the masks' mesh that lies over a concavity reads, through each view's
//! pixel, a different point of the surface behind it, whose normals differ: no single `b`
//! fits those readings. Read at the point where the views' rays meet the surface, they fit
//! one. So each face whose slack on the masks' hull reaches `--depth-search-min-slack`
//! footprints is searched along its inward normal, in half-footprint steps up to its slack (at
//! most `--depth-search` footprints): at each depth the views that see the face read the
//! radiance where that point projects, and the depth whose readings one `b` fits best (the
//! least residual, relative to the readings' mean) is the face's depth. With the ground truth,
//! the table compares it with the truth's depth along the same normal.

use glam::{Mat3, Vec3};
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use gtsr_mesh::mesh::face_centroid;
use gtsr_mesh::pixels::bilinear;
use gtsr_mesh::shading::own_normals;
use rayon::prelude::*;

/// One training view's inputs.
pub struct SearchView<'a> {
    pub camera: &'a Camera,
    /// Linear radiance per pixel.
    pub radiance: &'a [f32],
    pub mask: Option<&'a [f32]>,
    /// The masks' mesh's z-depth per pixel (0 on a miss), for visibility.
    pub mesh_depth: &'a [f32],
}

/// Settings of [`search`].
pub struct SearchSettings {
    /// Footprints.
    pub max_depth: f32,
    /// Footprints.
    pub min_slack: f32,
    pub min_cos: f32,
    pub min_views: usize,
    /// Scene units.
    pub footprint: f32,
}

/// The relative residual of the Lambertian fit `y = b . w` (`None` below 3 readings or for a
/// singular system).
fn misfit(readings: &[(Vec3, f32)]) -> Option<f32> {
    if readings.len() < 3 {
        return None;
    }
    let mut ata = Mat3::ZERO;
    let mut atb = Vec3::ZERO;
    let mut mean = 0.0;
    for (w, y) in readings {
        ata += Mat3::from_cols(*w * w.x, *w * w.y, *w * w.z);
        atb += *y * *w;
        mean += y;
    }
    mean /= readings.len() as f32;
    if ata.determinant().abs() < 1e-9 || mean <= 0.0 {
        return None;
    }
    let b = ata.inverse() * atb;
    let ss: f32 = readings.iter().map(|(w, y)| (y - b.dot(*w)).powi(2)).sum();
    Some((ss / readings.len() as f32).sqrt() / mean)
}

/// Per searched face: its index, the depth found and the residual there and at the face
/// itself (footprints; relative residuals).
pub struct Found {
    pub face: usize,
    pub depth: f32,
    pub misfit: f32,
    pub misfit_at_face: f32,
}

/// The depth search of the module docs over the faces of `mesh` whose slack (footprints,
/// per face) reaches the setting.
pub fn search(
    mesh: &TriMesh,
    views: &[SearchView<'_>],
    face_slack: &[f32],
    settings: &SearchSettings,
) -> Vec<Found> {
    let own = own_normals(mesh).normal;
    let eyes: Vec<Vec3> = views.iter().map(|v| v.camera.centre()).collect();
    (0..mesh.triangles.len())
        .into_par_iter()
        .filter(|f| face_slack[*f] >= settings.min_slack)
        .filter_map(|f| {
            let c = face_centroid(mesh, mesh.triangles[f]);
            let n = own[f];
            // The views that see the face: facing it and first to meet it.
            let seeing: Vec<(&SearchView<'_>, Vec3)> = (views.iter().zip(eyes.iter().copied()))
                .filter(|(v, eye)| {
                    if n.dot((*eye - c).normalize()) < settings.min_cos {
                        return false;
                    }
                    let Some((uv, z)) = v.camera.project(c) else {
                        return false;
                    };
                    let (w, h) = (v.camera.width as usize, v.camera.height as usize);
                    if !(uv.x >= 0.0 && uv.y >= 0.0 && (uv.x as usize) < w && (uv.y as usize) < h) {
                        return false;
                    }
                    let d = v.mesh_depth[uv.y as usize * w + uv.x as usize];
                    d > 0.0 && (d - z).abs() <= 2.0 * z / v.camera.fx
                })
                .collect();
            if seeing.len() < settings.min_views {
                return None;
            }
            let steps = (2.0 * face_slack[f].min(settings.max_depth)).floor() as usize;
            let mut best: Option<(f32, f32)> = None;
            let mut at_face = f32::NAN;
            for k in 0..=steps {
                let depth = 0.5 * k as f32;
                let p = c - n * (depth * settings.footprint);
                let readings: Vec<(Vec3, f32)> = (seeing.iter())
                    .filter_map(|(v, eye)| {
                        let (uv, _) = v.camera.project(p)?;
                        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
                        if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x < w as f32 && uv.y < h as f32) {
                            return None;
                        }
                        if v.mask.is_some_and(|m| bilinear(m, w, h, uv.x, uv.y) < 0.99) {
                            return None;
                        }
                        let d = *eye - p;
                        let r2 = d.length_squared();
                        let i = bilinear(v.radiance, w, h, uv.x, uv.y);
                        i.is_finite().then(|| (d / r2.sqrt(), i * r2))
                    })
                    .collect();
                if readings.len() < settings.min_views {
                    continue;
                }
                let Some(m) = misfit(&readings) else {
                    continue;
                };
                if k == 0 {
                    at_face = m;
                }
                if best.is_none_or(|(_, b)| m < b) {
                    best = Some((depth, m));
                }
            }
            let (depth, misfit) = best?;
            Some(Found {
                face: f,
                depth,
                misfit,
                misfit_at_face: at_face,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings of one Lambertian point fit one `b` exactly; readings of points whose normals
    /// differ (a lid over a bowl) do not.
    #[test]
    fn one_normal_fits_one_point_and_not_a_spread_of_them() {
        let eyes: Vec<Vec3> = (0..12)
            .map(|k| {
                let a = k as f32 * 0.5;
                Vec3::new(0.6 * a.cos(), 0.6 * a.sin(), 1.0).normalize()
            })
            .collect();
        let n = Vec3::Z;
        let one: Vec<(Vec3, f32)> = eyes.iter().map(|w| (*w, 0.8 * n.dot(*w))).collect();
        assert!(misfit(&one).unwrap() < 1e-5);
        // Each view reads a point tilted towards or away from it.
        let spread: Vec<(Vec3, f32)> = (eyes.iter().enumerate())
            .map(|(k, w)| {
                let tilt = if k % 2 == 0 { 0.4 } else { -0.4 };
                let m = (n + tilt * Vec3::new(w.x, w.y, 0.0)).normalize();
                (*w, 0.8 * m.dot(*w))
            })
            .collect();
        assert!(misfit(&spread).unwrap() > 0.02);
        assert!(misfit(&one[..2]).is_none());
    }
}
