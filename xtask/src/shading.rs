//! `shading-stereo`: normals from the images' shading under the light at the camera
//! (photometric stereo whose light moves with each view), and how far they refine the masks'
//! mesh ([`crate::refine`]).
//!
//! With a point light at the camera, a Lambertian surface point `x` of normal `n` and albedo
//! `rho` seen from the eye `e` has the linear radiance `I = rho L (n . w) / r^2`, with
//! `w = (e - x) / r` and `r = |e - x|`. So `I r^2 = b . w` with `b = rho L n`: every view that
//! sees a face gives one linear equation in `b`, and the light directions of the views that see
//! it span a cone wide enough to solve for `b` by least squares. The normal is `b / |b|`; the
//! albedo drops out. A face whose centroid lies off the true surface (a lid of the masks' mesh
//! over a dent) reads, in each view, the shading of the surface point its pixel shows; those
//! points differ a little from view to view (the parallax of the lid's height), so the normal
//! it gets is the truth's blurred over that parallax. After a refinement the faces lie closer
//! to the surface, and the normals are observed again on the refined mesh (`--rounds`).
//!
//! Translucency breaks the model: light scattered under the surface leaves it away from where
//! it entered, which blurs the shading and adds light that does not follow `n . w`. The images
//! are the only input; the ground truth only scores the result and, with it, each round prints
//! how far the shading normals lie from the truth's and how they lean towards the eyes that
//! see each face.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::{Mat3, Mat4, Vec3, Vec4};
use gtsr_data::Camera;
use gtsr_data::image_io::srgb_to_linear;
use gtsr_data::ply::TriMesh;
use gtsr_eval::mesh::{face_centroid, face_normal_scaled};
use gtsr_eval::tsdf::median_pixel_footprint;

use crate::refine::{FaceNormals, NormalView, RefineSettings, observed_normals, visible_faces};

/// Options of `shading-stereo`.
#[derive(Args, Debug)]
pub struct ShadingStereoArgs {
    /// The scene (Blender/NeRF with masks; with `mesh.ply` the rows are scored against it).
    #[arg(long)]
    pub data: PathBuf,
    /// The refinement's anchor lengths (scene units): one row each.
    #[arg(long, num_args = 1.., default_values_t = vec![0.02])]
    pub anchors: Vec<f32>,
    /// Observe-and-refine rounds per anchor (the normals of round `k` are observed on the mesh
    /// of round `k - 1`).
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// The smallest cosine between a face's normal and its direction to a camera for that view
    /// to count.
    #[arg(long, default_value_t = 0.3)]
    pub min_cos: f32,
    /// The fewest views that must see a face for its normal to be solved.
    #[arg(long, default_value_t = 6)]
    pub min_views: usize,
    /// The farthest a vertex may move inward, in scene units.
    #[arg(long, default_value_t = 0.2)]
    pub max_depth: f32,
    /// Conjugate-gradient iterations per solve of the refinement.
    #[arg(long, default_value_t = 400)]
    pub cg_iterations: usize,
    /// Trust a face's shading normal only where it departs from the face's own normal by
    /// more than this many degrees; elsewhere the face keeps its own (0: everywhere).
    #[arg(long, default_value_t = 0.0)]
    pub depart_deg: f32,
    /// Fit a constant beside the Lambertian term (`ShadingSettings::ambient`).
    #[arg(long)]
    pub ambient: bool,
    /// With `--depart-deg`: the anchor is this many times stronger at the vertices farther
    /// than `--free-radius` from every face whose shading normal departs (1: uniform).
    #[arg(long, default_value_t = 1.0)]
    pub pin: f32,
    /// With `--pin`: the distance (scene units) around the departing faces within which the
    /// anchor keeps its weight.
    #[arg(long, default_value_t = 0.1)]
    pub free_radius: f32,
    /// Remove a scene-wide tilt of the shading normals towards the eyes, proportional to how
    /// lopsided the eyes that see each face are, fitted on the faces where the shading normals
    /// and the mesh's own agree within 10 degrees (the images and the masks alone, no ground
    /// truth).
    #[arg(long)]
    pub debias: bool,
    /// Refine with the truth's normals instead (the ceiling of the refinement; needs
    /// `mesh.ply`).
    #[arg(long)]
    pub truth_normals: bool,
    /// Write the last refined mesh of the first anchor here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// One view for [`shading_normals`].
pub struct ShadingView<'a> {
    /// The camera; the light sits at its centre.
    pub camera: &'a Camera,
    /// Linear radiance, one value per pixel (the mean of the channels), row-major.
    pub radiance: &'a [f32],
    /// Object mask per pixel (`None`: every pixel counts).
    pub mask: Option<&'a [f32]>,
    /// The mesh's own z-depth through each pixel centre (`0` on a miss), for visibility.
    pub mesh_depth: &'a [f32],
}

/// Settings of [`shading_normals`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingSettings {
    /// The smallest cosine between a face's normal and its direction to the camera.
    pub min_cos: f32,
    /// The fewest views that must see a face.
    pub min_views: usize,
    /// The least mask value of a pixel that counts (pixels on the silhouette mix background).
    pub min_mask: f32,
    /// Ridge weight, relative to the mean eigenvalue of the normal equations, pulling the
    /// solution towards the face's own normal at the albedo that fits it best: it keeps the
    /// solve stable where the views' directions span a narrow cone.
    pub ridge: f32,
    /// Fit `I r^2 = b . w + a` instead: the constant `a` takes the light that comes out of the
    /// face whatever its angle to the light (scattered under the surface from around it).
    pub ambient: bool,
}

impl Default for ShadingSettings {
    fn default() -> Self {
        ShadingSettings {
            min_cos: 0.3,
            min_views: 6,
            min_mask: 0.99,
            ridge: 0.05,
            ambient: false,
        }
    }
}

/// What [`shading_normals`] solves.
pub struct ShadingFit {
    /// Per face, the normal that the shading explains, weight 1 where solved, else 0.
    pub normals: FaceNormals,
    /// Per face, the mean unit direction to the eyes of the views that see it (zero where none
    /// does).
    pub eyes: Vec<Vec3>,
}

/// Per face of `mesh`, the normal that the shading of the views explains best (module
/// documentation), with weight 1 where at least `min_views` views see the face and the solved
/// normal faces outward (towards the face's own normal), else 0; and the mean direction to
/// the eyes that see it. Visibility as in [`crate::refine::observed_normals`].
pub fn shading_normals(
    mesh: &TriMesh,
    views: &[ShadingView<'_>],
    settings: &ShadingSettings,
) -> Result<ShadingFit> {
    let nf = mesh.triangles.len();
    for v in views {
        let n = v.camera.width as usize * v.camera.height as usize;
        if v.radiance.len() != n || v.mesh_depth.len() != n || v.mask.is_some_and(|m| m.len() != n)
        {
            bail!(
                "shading view: expected {n} radiances, depths and mask values, got {}, {} and {:?}",
                v.radiance.len(),
                v.mesh_depth.len(),
                v.mask.map(<[f32]>::len)
            );
        }
    }
    let own = own_normals(mesh).normal;
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_centroid(mesh, *t))
        .collect();
    // Normal equations per face: sum w w^T, sum (I r^2) w, and for the ridge's albedo
    // sum (n0 . w)^2 and sum (I r^2)(n0 . w).
    let mut ata = vec![Mat4::ZERO; nf];
    let mut atb = vec![Vec4::ZERO; nf];
    let mut c2 = vec![0.0f32; nf];
    let mut cy = vec![0.0f32; nf];
    let mut count = vec![0usize; nf];
    let mut eyes = vec![Vec3::ZERO; nf];
    for v in views {
        let eye = v.camera.centre();
        for (f, p, _) in visible_faces(mesh, v.camera, v.mesh_depth, settings.min_cos) {
            let d = eye - centroids[f];
            let r2 = d.length_squared();
            let w = d / r2.sqrt();
            eyes[f] += w;
            if v.mask.is_some_and(|m| m[p] < settings.min_mask) {
                continue;
            }
            let i = v.radiance[p];
            if !i.is_finite() {
                continue;
            }
            let y = i * r2;
            let a = w.extend(1.0);
            ata[f] += Mat4::from_cols(a * a.x, a * a.y, a * a.z, a * a.w);
            atb[f] += y * a;
            let c = own[f].dot(w);
            c2[f] += c * c;
            cy[f] += c * y;
            count[f] += 1;
        }
    }
    let mut out = FaceNormals {
        normal: vec![Vec3::ZERO; nf],
        weight: vec![0.0; nf],
    };
    for f in 0..nf {
        if count[f] < settings.min_views.max(3) || c2[f] <= 0.0 {
            continue;
        }
        let n0 = own[f];
        let albedo = cy[f] / c2[f];
        let lambda = settings.ridge * (ata[f].x_axis.x + ata[f].y_axis.y + ata[f].z_axis.z) / 3.0;
        let b = if settings.ambient {
            // The constant gets a ridge towards 0 as well.
            let m = ata[f] + Mat4::from_diagonal(Vec4::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(4).max(f32::MIN_POSITIVE) {
                continue;
            }
            (m.inverse() * (atb[f] + lambda * albedo * n0.extend(0.0))).truncate()
        } else {
            let m3 = Mat3::from_mat4(ata[f]);
            let m = m3 + Mat3::from_diagonal(Vec3::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(3).max(f32::MIN_POSITIVE) {
                continue;
            }
            m.inverse() * (atb[f].truncate() + lambda * albedo * n0)
        };
        let n = b.normalize_or_zero();
        if n.dot(n0) > 0.0 && n.is_finite() {
            out.normal[f] = n;
            out.weight[f] = 1.0;
        }
    }
    Ok(ShadingFit {
        normals: out,
        eyes: eyes.into_iter().map(Vec3::normalize_or_zero).collect(),
    })
}

/// Per vertex of `mesh`: 1 within `radius` (along the edges) of a face marked in `free`,
/// `pin` elsewhere.
fn pin_scale(mesh: &TriMesh, free: &[bool], radius: f32, pin: f32) -> Vec<f32> {
    let nv = mesh.positions.len();
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for t in &mesh.triangles {
        for k in 0..3 {
            adj[t[k] as usize].push(t[(k + 1) % 3]);
            adj[t[(k + 1) % 3] as usize].push(t[k]);
        }
    }
    // Dijkstra from the free faces' vertices, up to `radius` (non-negative distances order
    // as their bit patterns).
    let mut dist = vec![f32::INFINITY; nv];
    let mut heap = std::collections::BinaryHeap::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if free[f] {
            for &i in t {
                if dist[i as usize] > 0.0 {
                    dist[i as usize] = 0.0;
                    heap.push((std::cmp::Reverse(0u32), i));
                }
            }
        }
    }
    while let Some((std::cmp::Reverse(dbits), i)) = heap.pop() {
        let d = f32::from_bits(dbits);
        if d > dist[i as usize] {
            continue;
        }
        for &j in &adj[i as usize] {
            let nd = d + (mesh.positions[i as usize] - mesh.positions[j as usize]).length();
            if nd < dist[j as usize] && nd <= radius {
                dist[j as usize] = nd;
                heap.push((std::cmp::Reverse(nd.to_bits()), j));
            }
        }
    }
    dist.iter()
        .map(|d| if d.is_finite() { 1.0 } else { pin })
        .collect()
}

/// Fits a scene-wide tilt of `shading` from `own` proportional to the lopsidedness of the
/// eyes that see each face: `s_t = k m_t`, with `m_t` the part of `eyes` (per face, the mean
/// unit direction to the eyes that see it) tangent to the face, by least squares over the
/// faces where the two normals agree within 10 degrees; then removes `k m_t` from every solved
/// shading normal. Returns `k`.
fn debias(shading: &mut FaceNormals, own: &FaceNormals, eyes: &[Vec3]) -> f32 {
    let agree = 10f32.to_radians().cos();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (f, e) in eyes.iter().enumerate() {
        let (s, n) = (shading.normal[f], own.normal[f]);
        if shading.weight[f] <= 0.0 || s.dot(n) < agree {
            continue;
        }
        let m = *e - e.dot(n) * n;
        num += f64::from(s.dot(m));
        den += f64::from(m.length_squared());
    }
    if den <= 0.0 {
        return 0.0;
    }
    let k = (num / den) as f32;
    for (f, e) in eyes.iter().enumerate() {
        if shading.weight[f] > 0.0 {
            let s = shading.normal[f];
            let m = *e - e.dot(s) * s;
            shading.normal[f] = (s - k * m).normalize_or_zero();
        }
    }
    k
}

/// The mesh's own face normals, weight 1.
fn own_normals(mesh: &TriMesh) -> FaceNormals {
    let normal: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_normal_scaled(mesh, *t).normalize_or_zero())
        .collect();
    FaceNormals {
        weight: vec![1.0; normal.len()],
        normal,
    }
}

/// The mean of the linear channels of an RGB image (sRGB-decoded when `srgb`).
fn radiance(rgb: &[f32], srgb: bool) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|c| {
            let lin = |x: f32| if srgb { srgb_to_linear(x) } else { x };
            (lin(c[0]) + lin(c[1]) + lin(c[2])) / 3.0
        })
        .collect()
}

/// Per face where both have a normal, the angle between two sets of face normals (degrees,
/// median / mean; NaN where none).
fn face_error(x: &FaceNormals, truth: &FaceNormals) -> (f32, f64) {
    crate::concavity::median_mean(&mut crate::refine::face_angles(x, truth))
}

/// Runs `shading-stereo`.
pub fn run(args: &ShadingStereoArgs) -> Result<()> {
    if args.rounds == 0 || args.anchors.iter().any(|a| !(a.is_finite() && *a > 0.0)) {
        bail!("--rounds must be at least 1 and every --anchors value positive");
    }
    let valid = (0.0..1.0).contains(&args.min_cos)
        && (0.0..180.0).contains(&args.depart_deg)
        && args.pin.is_finite()
        && args.pin > 0.0
        && args.free_radius.is_finite()
        && args.free_radius >= 0.0
        && args.max_depth.is_finite()
        && args.max_depth > 0.0;
    if !valid {
        bail!(
            "--min-cos must be in [0, 1), --depart-deg in [0, 180), --pin and --max-depth \
             positive, --free-radius non-negative"
        );
    }
    let t0 = std::time::Instant::now();
    let (scene, hull) = crate::bench_recon::native_masks_mesh(&args.data)?;
    let gt = crate::bench_recon::ground_truth(&scene, &args.data).ok();
    let cameras: Vec<Camera> = scene.train.iter().map(|v| v.camera).collect();
    let footprint = median_pixel_footprint(cameras.iter(), Vec3::ZERO);
    let radiances: Vec<Vec<f32>> = scene
        .train
        .iter()
        .map(|v| radiance(&v.rgb, v.encoding == gtsr_data::Encoding::Srgb))
        .collect();
    println!(
        "{}: {} training views at {}x{}, masks' mesh {} faces, footprint {footprint:.4} ({:.1} s)",
        args.data.display(),
        cameras.len(),
        cameras[0].width,
        cameras[0].height,
        hull.triangles.len(),
        t0.elapsed().as_secs_f64()
    );
    let settings = ShadingSettings {
        min_cos: args.min_cos,
        min_views: args.min_views,
        ambient: args.ambient,
        ..ShadingSettings::default()
    };
    let score = |mesh: &TriMesh| -> Result<String> {
        let Some(gt) = &gt else {
            return Ok("- | - | - | -".into());
        };
        crate::refine::score_cells(mesh, gt, &cameras, &hull)
    };
    // The truth's normal maps (camera space, 3 per pixel) of the training views: they do not
    // depend on the mesh being refined.
    let truth_maps: Option<Vec<Vec<f32>>> = match &gt {
        Some(gt) => {
            let gt_caster = gtsr_eval::MeshRaycaster::new(gt, "ground-truth mesh")?;
            Some(
                cameras
                    .iter()
                    .map(|c| {
                        gt_caster
                            .render(c)
                            .normal
                            .iter()
                            .flat_map(|n| n.to_array())
                            .collect()
                    })
                    .collect(),
            )
        }
        None => None,
    };
    // The shading fit and (with the truth) the truth's normals, observed on `mesh`'s faces.
    let observe = |mesh: &TriMesh| -> Result<(ShadingFit, Option<FaceNormals>)> {
        let caster = gtsr_eval::MeshRaycaster::new(mesh, "the refined mesh")?;
        let depths: Vec<Vec<f32>> = cameras.iter().map(|c| caster.render(c).depth).collect();
        let views: Vec<ShadingView<'_>> = scene
            .train
            .iter()
            .zip(&radiances)
            .zip(&depths)
            .map(|((v, r), d)| ShadingView {
                camera: &v.camera,
                radiance: r,
                mask: v.mask.as_deref(),
                mesh_depth: d,
            })
            .collect();
        let fit = shading_normals(mesh, &views, &settings)?;
        let truth = match &truth_maps {
            Some(normals) => {
                let nv: Vec<NormalView<'_>> = cameras
                    .iter()
                    .zip(normals)
                    .zip(&depths)
                    .map(|((c, n), d)| NormalView {
                        camera: c,
                        normal: n,
                        mesh_depth: d,
                    })
                    .collect();
                Some(observed_normals(mesh, &nv, 1, settings.min_cos)?)
            }
            None => None,
        };
        Ok((fit, truth))
    };
    println!(
        "\n| anchor | round | chamfer | accuracy | completeness | hull-blind | solved faces | \
         shading normals vs truth (deg) | moves mean / most |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    println!("| - | masks alone | {} | - | - | - |", score(&hull)?);
    for (k, &anchor) in args.anchors.iter().enumerate() {
        let refine_settings = RefineSettings {
            anchor,
            max_depth: args.max_depth,
            max_outward: 0.25 * footprint,
            iterations: args.cg_iterations,
            ..RefineSettings::default()
        };
        let mut mesh = hull.clone();
        for round in 1..=args.rounds {
            let t = std::time::Instant::now();
            let (
                ShadingFit {
                    normals: mut shading,
                    eyes,
                },
                truth,
            ) = observe(&mesh)?;
            let own = own_normals(&mesh);
            if args.debias {
                let beta = debias(&mut shading, &own, &eyes);
                println!("debias: removed a tilt of {beta:+.3} times the lopsidedness of the eyes");
            }
            let solved = shading.weight.iter().filter(|w| **w > 0.0).count();
            let (em, ea) = truth
                .as_ref()
                .map_or((f32::NAN, f64::NAN), |t| face_error(&shading, t));
            if let Some(t) = &truth {
                // Where the mesh's own normals are more than 10 degrees off the truth's.
                let off: Vec<bool> = (0..own.normal.len())
                    .map(|f| {
                        t.weight[f] > 0.0
                            && own.normal[f].dot(t.normal[f]) < 10f32.to_radians().cos()
                    })
                    .collect();
                let only = |x: &FaceNormals| {
                    let mut y = x.clone();
                    for (f, o) in off.iter().enumerate() {
                        if !o {
                            y.weight[f] = 0.0;
                        }
                    }
                    y
                };
                let (om, oa) = face_error(&own, t);
                let (sm, sa) = face_error(&only(&shading), t);
                let (xm, xa) = face_error(&only(&own), t);
                println!(
                    "own normals vs truth {om:.1} / {oa:.1}; on the {} faces whose own normal is > 10 deg off: own {xm:.1} / {xa:.1}, shading {sm:.1} / {sa:.1}",
                    off.iter().filter(|o| **o).count()
                );
                // Elsewhere (the flush surface): the shading normal's tilt from the truth's,
                // split into its part towards the mean direction of the eyes that see the face
                // and the part across it.
                let (mut along, mut across) = (Vec::new(), Vec::new());
                for f in 0..own.normal.len() {
                    let tn = t.normal[f];
                    let m = eyes[f] - eyes[f].dot(tn) * tn;
                    if off[f] || t.weight[f] <= 0.0 || shading.weight[f] <= 0.0 || m.length() < 1e-3
                    {
                        continue;
                    }
                    let m = m.normalize();
                    let e = shading.normal[f] - shading.normal[f].dot(tn) * tn;
                    along.push(e.dot(m).clamp(-1.0, 1.0).asin().to_degrees());
                    across.push(e.dot(tn.cross(m)).abs().clamp(0.0, 1.0).asin().to_degrees());
                }
                let mean =
                    |v: &[f32]| v.iter().map(|x| *x as f64).sum::<f64>() / v.len().max(1) as f64;
                println!(
                    "flush surface ({} faces): shading tilt towards the eyes' mean direction {:+.2} deg (mean), across it {:.2} deg (mean |.|)",
                    along.len(),
                    mean(&along),
                    mean(&across)
                );
            }
            let mut departs = vec![false; shading.normal.len()];
            let departing = if args.depart_deg > 0.0 {
                let cos = args.depart_deg.to_radians().cos();
                let mut x = shading.clone();
                for (f, dep) in departs.iter_mut().enumerate() {
                    if x.weight[f] > 0.0 && x.normal[f].dot(own.normal[f]) >= cos {
                        x.normal[f] = own.normal[f];
                    } else if x.weight[f] > 0.0 {
                        *dep = true;
                    }
                }
                x
            } else {
                shading.clone()
            };
            let scale = (args.pin != 1.0 && args.depart_deg > 0.0)
                .then(|| pin_scale(&hull, &departs, args.free_radius, args.pin));
            let targets = match (&truth, args.truth_normals) {
                (Some(t), true) => t,
                (None, true) => bail!("--truth-normals needs the scene's mesh.ply"),
                _ => &departing,
            };
            let (refined, d) = crate::refine::refine_anchored(
                &hull,
                targets,
                None,
                &refine_settings,
                scale.as_deref(),
            )?;
            let mean = d.iter().map(|v| *v as f64).sum::<f64>() / d.len().max(1) as f64;
            let most = d.iter().fold(0.0f32, |a, v| a.min(*v));
            mesh = refined;
            println!(
                "| {anchor} | {round} | {} | {solved} of {} | {em:.1} / {ea:.1} | {mean:.4} / {most:.4} | ({:.0} s)",
                score(&mesh)?,
                shading.weight.len(),
                t.elapsed().as_secs_f64()
            );
        }
        if let (0, Some(out)) = (k, &args.out) {
            gtsr_data::ply::write_ply(out, &mesh)
                .with_context(|| format!("writing {}", out.display()))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat square facing +z, seen by cameras around it, shaded by the Lambertian law with
    /// a tilted normal: the solve recovers the tilt.
    #[test]
    fn recovers_a_tilted_lambertian_normal_from_views_with_the_light_at_the_camera() {
        let mesh = TriMesh {
            positions: vec![
                Vec3::new(-0.1, -0.1, 0.0),
                Vec3::new(0.1, -0.1, 0.0),
                Vec3::new(0.1, 0.1, 0.0),
                Vec3::new(-0.1, 0.1, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let truth = Vec3::new(0.3, -0.2, 1.0).normalize();
        let cams: Vec<Camera> = (0..12)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 12.0;
                let eye = Vec3::new(1.5 * a.cos(), 1.5 * a.sin(), 3.0) * (1.0 + 0.05 * k as f32);
                Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 0.3, 64, 64)
            })
            .collect();
        let (w, h) = (64usize, 64usize);
        let mut rads = Vec::new();
        let mut depths = Vec::new();
        for c in &cams {
            let eye = c.centre();
            let mut rad = vec![0.0f32; w * h];
            let mut dep = vec![0.0f32; w * h];
            for j in 0..h {
                for i in 0..w {
                    let (o, d) = c.pixel_ray(i as u32, j as u32);
                    let t = -o.z / d.z;
                    let x = o + d * t;
                    if t > 0.0 && x.x.abs() < 0.1 && x.y.abs() < 0.1 {
                        let to = eye - x;
                        let r2 = to.length_squared();
                        rad[j * w + i] = 0.7 * truth.dot(to / r2.sqrt()).max(0.0) / r2;
                        dep[j * w + i] = c.world_to_camera.transform_point3(x).z;
                    }
                }
            }
            rads.push(rad);
            depths.push(dep);
        }
        let views: Vec<ShadingView<'_>> = cams
            .iter()
            .zip(&rads)
            .zip(&depths)
            .map(|((c, r), d)| ShadingView {
                camera: c,
                radiance: r,
                mask: None,
                mesh_depth: d,
            })
            .collect();
        let got = shading_normals(
            &mesh,
            &views,
            &ShadingSettings {
                ridge: 1e-4,
                ..ShadingSettings::default()
            },
        )
        .unwrap()
        .normals;
        for f in 0..2 {
            assert_eq!(got.weight[f], 1.0);
            let angle = got.normal[f]
                .dot(truth)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!(angle < 0.5, "face {f}: {angle} degrees off");
        }
    }
}
