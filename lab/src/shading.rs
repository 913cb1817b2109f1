//! `shading-stereo`: how far the normals of the images' shading ([`gtsr_mesh::shading`])
//! refine the masks' mesh ([`gtsr_mesh::refine`]), with the diagnostics of where they go wrong.
//!
//! The images are the only input; the ground truth only scores the result and, with it, each
//! round prints how far the shading normals lie from the truth's and how they lean towards the
//! eyes that see each face, overall and by how open each face is to the rest of the object.
//! Beside the library's model, alternatives measured here: a scene-wide tilt removed
//! (`--debias`), a bias by direction removed (`--orient-debias`), the long-range variation
//! replaced by the masks' (`--low-pass`), gates by openness and by departure from the masks'
//! normals, and several observe-and-refine rounds (the normals of round `k` observed on the
//! mesh of round `k - 1`).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use gtsr_mesh::mesh::face_centroid;
use gtsr_mesh::pixels::median_pixel_footprint;
use gtsr_mesh::refine::{FaceNormals, NormalView, RefineSettings, observed_normals};
use gtsr_mesh::shading::{
    ShadingFit, ShadingImage, ShadingSettings, ShadingView, Surroundings, own_normals,
    shading_normals, surroundings, view_radiance,
};

use crate::face_filters::{debias, face_error, low_pass, orient_debias, pin_scale};

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
    /// The farthest a vertex may move outward, in training pixel footprints.
    #[arg(long, default_value_t = 0.25)]
    pub max_outward: f32,
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
    /// The image channel whose shading is read.
    #[arg(long, value_enum, default_value_t = Channel::Mean)]
    pub channel: Channel,
    /// Fit the scene's response to the angle on this many knots instead of Lambert's cosine
    /// (`ShadingSettings::response`; 0: Lambert).
    #[arg(long, default_value_t = 0)]
    pub response: usize,
    /// Keep only the shading normals' detail shorter than this length (scene units): their
    /// variation over longer lengths is replaced by the masks' mesh's own, as in Nehab et
    /// al. 2005's combination of positions and normals (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub low_pass: f32,
    /// Remove the shading normals' bias as a function of their direction (degrees of the
    /// kernel over directions): per direction, the rotation that takes the mean shading normal
    /// of the faces pointing that way to their mean own normal (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub orient_debias: f32,
    /// Model the light the rest of the object sends each face
    /// (`ShadingSettings::interreflection`).
    #[arg(long)]
    pub interreflection: bool,
    /// With `--interreflection`: hold its constant `c` at this value instead of calibrating it.
    #[arg(long)]
    pub interreflection_c: Option<f32>,
    /// Shrink each face's normal towards its own by its uncertainty
    /// (`ShadingSettings::shrink`).
    #[arg(long)]
    pub shrink: bool,
    /// Keep the shading normal only on faces at least this open to the outside (the fraction
    /// of their hemisphere no other part of the object faces); the others keep their own
    /// (0: everywhere).
    #[arg(long, default_value_t = 0.0)]
    pub min_openness: f32,
    /// Scale each vertex's anchor by its slack on the masks' hull (`gtsr_mesh::hull::hull_slack`):
    /// the anchor length is `--anchors` times `min(1, slack / --slack-ref)` to this power
    /// (0: the same anchor everywhere; the slack's quantiles are printed either way).
    #[arg(long, default_value_t = 0.0)]
    pub slack_power: f32,
    /// With `--slack-power`: the slack (training pixel footprints) from which a vertex gets
    /// the whole anchor.
    #[arg(long, default_value_t = 16.0)]
    pub slack_ref: f32,
    /// Refine with the truth's normals instead (the ceiling of the refinement; needs
    /// `mesh.ply`).
    #[arg(long)]
    pub truth_normals: bool,
    /// Write the last refined mesh of the first anchor here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Instead of refining: search each face whose slack reaches
    /// `--depth-search-min-slack` along its inward normal, up to this many footprints, for
    /// the depth whose readings one Lambertian normal fits best, and compare it with the
    /// truth's (`crate::shading_depth`; 0: off).
    #[arg(long, default_value_t = 0.0)]
    pub depth_search: f32,
    /// With `--depth-search`: the least slack (footprints) of a searched face.
    #[arg(long, default_value_t = 2.0)]
    pub depth_search_min_slack: f32,
    /// The largest tilt of a shading normal from its face that the refinement trusts
    /// (degrees; `RefineSettings::max_tilt`).
    #[arg(long, default_value_t = 30.0)]
    pub max_tilt_deg: f32,
    /// Trust tilts up to this many degrees on the faces whose slack on the masks' hull
    /// reaches twice `--steep-slack`, ramping from `--max-tilt-deg` at `--steep-slack` (0:
    /// `--max-tilt-deg` everywhere).
    #[arg(long, default_value_t = 0.0)]
    pub steep_tilt: f32,
    /// With `--steep-tilt`: the slack (footprints; a face's least vertex slack) from which
    /// the trusted tilt ramps up, reaching `--steep-tilt` at twice it
    /// (`gtsr_mesh::shading::slack_tilt_limits`).
    #[arg(long, default_value_t = 4.0)]
    pub steep_slack: f32,
    /// Fit the light scattered under the surface as a blur of the Lambertian shading on the
    /// faces the masks' hull holds, and invert it in the images before the shading fit
    /// (`gtsr_mesh::scatter::unscatter`).
    #[arg(long)]
    pub unscatter: bool,
}

/// Which of an image's channels [`shading_normals`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Channel {
    /// The mean of the three.
    Mean,
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
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
        && args.max_depth > 0.0
        && args.max_outward.is_finite()
        && args.max_outward >= 0.0
        && args.low_pass.is_finite()
        && args.low_pass >= 0.0
        && args.response != 1
        && args.slack_power.is_finite()
        && args.slack_power >= 0.0
        && args.slack_ref.is_finite()
        && args.slack_ref > 0.0
        && args.orient_debias.is_finite()
        && args.orient_debias >= 0.0
        && (0.0..=1.0).contains(&args.min_openness)
        && args
            .interreflection_c
            .is_none_or(|c| c.is_finite() && c >= 0.0);
    if !valid {
        bail!(
            "--min-cos must be in [0, 1), --depart-deg in [0, 180), --pin and --max-depth \
             positive, --max-outward, --free-radius, --low-pass, --orient-debias and --slack-power non-negative, --slack-ref positive, --response 0 or at least 2, --min-openness in [0, 1], --interreflection-c non-negative"
        );
    }
    let channel = match args.channel {
        Channel::Mean => None,
        Channel::R => Some(0),
        Channel::G => Some(1),
        Channel::B => Some(2),
    };
    let t0 = std::time::Instant::now();
    let (scene, hull) = gtsr_eval::native_masks_mesh(&args.data)?;
    let gt = gtsr_eval::ground_truth(&scene, &args.data).ok();
    let cameras: Vec<Camera> = scene.train.iter().map(|v| v.camera).collect();
    let footprint = median_pixel_footprint(cameras.iter(), Vec3::ZERO);
    let mut radiances: Vec<Vec<f32>> = scene
        .train
        .iter()
        .map(|v| view_radiance(v, channel))
        .collect();
    let mask_views: Vec<(Camera, &[f32])> = scene
        .train
        .iter()
        .filter_map(|v| v.mask.as_deref().map(|m| (v.camera, m)))
        .collect();
    if args.unscatter {
        // As `gtsr_mesh::shading::refine_by_shading` does: the model fitted on the faces the
        // hull holds within a quarter of the slack's reference.
        let t = std::time::Instant::now();
        let reference = args.slack_ref * footprint;
        let vslack = gtsr_mesh::hull::hull_slack(
            &mask_views,
            &hull.positions,
            reference / 32.0,
            2.0 * reference,
        )?;
        let held = gtsr_mesh::shading::scatter_held_faces(&hull, &vslack, reference);
        let images: Vec<ShadingImage<'_>> = (scene.train.iter().zip(&radiances))
            .map(|(v, r)| ShadingImage {
                camera: &v.camera,
                radiance: r,
                mask: v.mask.as_deref(),
            })
            .collect();
        let u = gtsr_mesh::scatter::unscatter(&hull, Some(&held), &images, args.min_cos)?;
        drop(images);
        let row: Vec<String> = (u.fits.iter())
            .map(|f| {
                format!(
                    "P {} G {}: {:.3}/{:.3} {:.5}",
                    f.pixel, f.sigma, f.sharp, f.blurred, f.residual
                )
            })
            .collect();
        println!(
            "unscatter fits on {} held faces (a/b residual): {}",
            held.iter().filter(|h| **h).count(),
            row.join("; ")
        );
        let m = u.model;
        println!(
            "unscatter: pixel filter {} px, scattering {} px, a {:.4}, b {:.4}, amplification \
             {:.2} ({:.1} s)",
            m.pixel,
            m.sigma,
            m.sharp,
            m.blurred,
            m.amplification(),
            t.elapsed().as_secs_f64()
        );
        radiances = u.radiance;
    }
    // Pixels of the object with a channel at the top of its range: their shading is clipped.
    let (mut object, mut clipped) = (0usize, 0usize);
    for v in &scene.train {
        for (p, c) in v.rgb.chunks_exact(3).enumerate() {
            if v.mask.as_ref().is_none_or(|m| m[p] >= 0.99) {
                object += 1;
                clipped += usize::from(c.iter().any(|x| *x >= 254.5 / 255.0));
            }
        }
    }
    println!(
        "{}: {} training views at {}x{}, masks' mesh {} faces, footprint {footprint:.4}, \
         clipped object pixels {:.3} % ({:.1} s)",
        args.data.display(),
        cameras.len(),
        cameras[0].width,
        cameras[0].height,
        hull.triangles.len(),
        100.0 * clipped as f64 / object.max(1) as f64,
        t0.elapsed().as_secs_f64()
    );
    let settings = ShadingSettings {
        min_cos: args.min_cos,
        min_views: args.min_views,
        ambient: args.ambient,
        response: args.response,
        interreflection: args.interreflection,
        interreflection_c: args.interreflection_c,
        shrink: args.shrink,
        ..ShadingSettings::default()
    };
    // The masks' mesh's surroundings: for the openness (the diagnostics, `--min-openness`) and
    // the first round's interreflection.
    let hull_around = if gt.is_some() || args.min_openness > 0.0 || args.interreflection {
        Some(surroundings(&hull, 32)?)
    } else {
        None
    };
    let open = hull_around
        .as_ref()
        .map_or_else(|| vec![1.0; hull.triangles.len()], Surroundings::openness);
    let score = |mesh: &TriMesh| -> Result<String> {
        let Some(gt) = &gt else {
            return Ok("- | - | - | -".into());
        };
        crate::concavity::score_cells(mesh, gt, &cameras, &hull)
    };
    // The truth's normal maps (camera space, 3 per pixel) of the training views: they do not
    // depend on the mesh being refined.
    let truth_maps: Option<Vec<Vec<f32>>> = match &gt {
        Some(gt) => {
            let gt_caster = gtsr_mesh::raycast::MeshRaycaster::new(gt, "ground-truth mesh")?;
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
    let observe = |mesh: &TriMesh, round: usize| -> Result<(ShadingFit, Option<FaceNormals>)> {
        let caster = gtsr_mesh::raycast::MeshRaycaster::new(mesh, "the refined mesh")?;
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
        let cast;
        let around = match (args.interreflection, round) {
            (false, _) => None,
            (true, 1) => hull_around.as_ref(),
            (true, _) => {
                cast = surroundings(mesh, 32)?;
                Some(&cast)
            }
        };
        let fit = shading_normals(mesh, &views, around, &settings)?;
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
    // The hull's slack per vertex, in footprints.
    let t_slack = std::time::Instant::now();
    let slack: Vec<f32> = gtsr_mesh::hull::hull_slack(
        &mask_views,
        &hull.positions,
        0.25 * footprint,
        64.0 * footprint,
    )?
    .iter()
    .map(|s| s / footprint)
    .collect();
    let quantiles = |v: &[f32]| -> String {
        let mut v = v.to_vec();
        v.sort_by(f32::total_cmp);
        let q = |p: f64| {
            v.get(((v.len().max(1) - 1) as f64 * p) as usize)
                .copied()
                .unwrap_or(f32::NAN)
        };
        format!(
            "{} vertices: 0.1/0.5/0.9/0.99 {:.2}/{:.2}/{:.2}/{:.2}",
            v.len(),
            q(0.1),
            q(0.5),
            q(0.9),
            q(0.99)
        )
    };
    println!(
        "hull slack (footprints), all {} ({:.1} s)",
        quantiles(&slack),
        t_slack.elapsed().as_secs_f64()
    );
    if let Some(gt) = &gt {
        let sd = gtsr_mesh::raycast::SignedDistance::new(gt, "ground-truth mesh")?;
        let depth: Vec<f32> = hull
            .positions
            .iter()
            .map(|p| sd.query(*p).0.abs())
            .collect();
        for (lo, hi) in [(0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 1e9)] {
            let sel: Vec<f32> = slack
                .iter()
                .zip(&depth)
                .filter(|(_, d)| (lo..hi).contains(&(**d / footprint)))
                .map(|(s, _)| *s)
                .collect();
            println!(
                "  slack where the hull lies {lo}-{hi} footprints from the truth: {}",
                quantiles(&sel)
            );
        }
    }
    if args.depth_search > 0.0 {
        return depth_search(args, &scene, &hull, gt.as_ref(), &radiances, footprint);
    }
    let slack_scale: Option<Vec<f32>> = (args.slack_power > 0.0)
        .then(|| gtsr_mesh::shading::slack_anchor_scale(&slack, args.slack_ref, args.slack_power));
    println!(
        "\n| anchor | round | chamfer | accuracy | completeness | hull-blind | solved faces | \
         shading normals vs truth (deg) | moves mean / most |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    println!("| - | masks alone | {} | - | - | - |", score(&hull)?);
    let max_tilt = args.max_tilt_deg.to_radians().sin();
    // Per face, the largest trusted tilt (a sine), by its least vertex slack.
    let face_tilt: Option<Vec<f32>> = (args.steep_tilt > 0.0).then(|| {
        gtsr_mesh::shading::slack_tilt_limits(
            &hull,
            &slack,
            args.steep_slack,
            max_tilt,
            args.steep_tilt.to_radians().sin(),
        )
    });
    for (k, &anchor) in args.anchors.iter().enumerate() {
        let refine_settings = RefineSettings {
            anchor,
            max_depth: args.max_depth,
            max_outward: args.max_outward * footprint,
            iterations: args.cg_iterations,
            max_tilt,
            ..RefineSettings::default()
        };
        let mut mesh = hull.clone();
        for round in 1..=args.rounds {
            let t = std::time::Instant::now();
            let (fit, truth) = observe(&mesh, round)?;
            if args.shrink {
                println!(
                    "shrink: mean share of the correction kept {:.3}",
                    fit.mean_confidence()
                );
            }
            let ShadingFit {
                normals: mut shading,
                eyes,
                response,
                interreflection,
                ..
            } = fit;
            let own = own_normals(&mesh);
            if args.interreflection {
                println!("interreflection: c = {interreflection:.4}");
            }
            if !response.is_empty() {
                let r: Vec<String> = response.iter().map(|g| format!("{g:.3}")).collect();
                println!("response g at cos {}..1: {}", args.min_cos, r.join(" "));
            }
            if args.debias {
                let beta = debias(&mut shading, &own, &eyes);
                println!("debias: removed a tilt of {beta:+.3} times the lopsidedness of the eyes");
            }
            if args.min_openness > 0.0 {
                for (f, o) in open.iter().enumerate() {
                    if *o < args.min_openness && shading.weight[f] > 0.0 {
                        shading.normal[f] = own.normal[f];
                    }
                }
            }
            if args.orient_debias > 0.0 {
                orient_debias(&mut shading, &own, args.orient_debias);
            }
            if args.low_pass > 0.0 {
                low_pass(&mesh, &mut shading, &own, args.low_pass);
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
                // Per face kept by `keep`, the tilt towards and (|.|) across, degrees.
                let tilts = |keep: &dyn Fn(usize) -> bool| -> (Vec<f32>, Vec<f32>) {
                    let (mut along, mut across) = (Vec::new(), Vec::new());
                    for f in 0..own.normal.len() {
                        let tn = t.normal[f];
                        let m = eyes[f] - eyes[f].dot(tn) * tn;
                        if off[f]
                            || t.weight[f] <= 0.0
                            || shading.weight[f] <= 0.0
                            || m.length() < 1e-3
                            || !keep(f)
                        {
                            continue;
                        }
                        let m = m.normalize();
                        let e = shading.normal[f] - shading.normal[f].dot(tn) * tn;
                        along.push(e.dot(m).clamp(-1.0, 1.0).asin().to_degrees());
                        across.push(e.dot(tn.cross(m)).abs().clamp(0.0, 1.0).asin().to_degrees());
                    }
                    (along, across)
                };
                let (along, across) = tilts(&|_| true);
                let mean =
                    |v: &[f32]| v.iter().map(|x| *x as f64).sum::<f64>() / v.len().max(1) as f64;
                println!(
                    "flush surface ({} faces): shading tilt towards the eyes' mean direction {:+.2} deg (mean), across it {:.2} deg (mean |.|)",
                    along.len(),
                    mean(&along),
                    mean(&across)
                );
                // The same tilt by how open the face is to the rest of the object.
                let bins = [0.0, 0.5, 0.75, 0.9, 0.97, 1.01];
                let row: Vec<String> = bins
                    .windows(2)
                    .map(|b| {
                        let (al, ac) = tilts(&|f| (b[0]..b[1]).contains(&open[f]));
                        format!(
                            "[{:.2}, {:.2}): {} faces {:+.2} / {:.2}",
                            b[0],
                            b[1].min(1.0),
                            al.len(),
                            mean(&al),
                            mean(&ac)
                        )
                    })
                    .collect();
                println!(
                    "by openness (faces, tilt towards / across): {}",
                    row.join("; ")
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
                .then(|| pin_scale(&hull, &departs, args.free_radius, args.pin))
                .or_else(|| slack_scale.clone());
            let filtered_truth = match (&truth, args.truth_normals && args.low_pass > 0.0) {
                (Some(t), true) => {
                    let mut t = t.clone();
                    low_pass(&mesh, &mut t, &own, args.low_pass);
                    Some(t)
                }
                _ => None,
            };
            let targets = match (
                filtered_truth.as_ref().or(truth.as_ref()),
                args.truth_normals,
            ) {
                (Some(t), true) => t,
                (None, true) => bail!("--truth-normals needs the scene's mesh.ply"),
                _ => &departing,
            };
            let (refined, d) = gtsr_mesh::refine::refine_anchored(
                &hull,
                targets,
                None,
                &refine_settings,
                scale.as_deref(),
                face_tilt.as_deref(),
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

/// `--depth-search`: the search of [`crate::shading_depth`] over the masks' mesh, scored
/// against the truth's depth along each face's normal where the scene has one.
fn depth_search(
    args: &ShadingStereoArgs,
    scene: &gtsr_data::Scene,
    hull: &TriMesh,
    gt: Option<&TriMesh>,
    radiances: &[Vec<f32>],
    footprint: f32,
) -> Result<()> {
    use crate::shading_depth::{SearchSettings, SearchView, search};
    let t0 = std::time::Instant::now();
    let caster = gtsr_mesh::raycast::MeshRaycaster::new(hull, "the masks' mesh")?;
    let depths: Vec<Vec<f32>> = (scene.train.iter())
        .map(|v| caster.render(&v.camera).depth)
        .collect();
    let views: Vec<SearchView<'_>> = (scene.train.iter().zip(radiances).zip(&depths))
        .map(|((v, r), d)| SearchView {
            camera: &v.camera,
            radiance: r,
            mask: v.mask.as_deref(),
            mesh_depth: d,
        })
        .collect();
    let mask_views: Vec<(Camera, &[f32])> = (scene.train.iter())
        .filter_map(|v| v.mask.as_deref().map(|m| (v.camera, m)))
        .collect();
    let centroids: Vec<Vec3> = (hull.triangles.iter())
        .map(|t| face_centroid(hull, *t))
        .collect();
    let max = args.depth_search.max(args.depth_search_min_slack);
    let face_slack: Vec<f32> =
        gtsr_mesh::hull::hull_slack(&mask_views, &centroids, 0.25 * footprint, max * footprint)?
            .iter()
            .map(|s| s / footprint)
            .collect();
    let settings = SearchSettings {
        max_depth: args.depth_search,
        min_slack: args.depth_search_min_slack,
        min_cos: args.min_cos,
        min_views: args.min_views,
        footprint,
    };
    let found = search(hull, &views, &face_slack, &settings);
    println!(
        "depth search: {} faces with a slack of at least {} footprints searched ({:.1} s)",
        found.len(),
        args.depth_search_min_slack,
        t0.elapsed().as_secs_f64()
    );
    let Some(gt) = gt else {
        return Ok(());
    };
    let truth = gtsr_mesh::raycast::MeshRaycaster::new(gt, "ground-truth mesh")?;
    let own = own_normals(hull).normal;
    // The truth's depth along the inward normal (from two footprints outside), footprints.
    let truth_depth = |f: usize| -> f32 {
        let start = centroids[f] + own[f] * (2.0 * footprint);
        truth
            .first_hit(start, -own[f])
            .map_or(f32::INFINITY, |(t, _)| t / footprint - 2.0)
    };
    println!(
        "\n| truth's depth under the face (fp) | faces | truth mean | found mean | |found - truth| median | within 1 fp | the face itself within 1 fp | misfit at the face / found |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    let bins = [(-1e9, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0), (8.0, 1e9)];
    for (lo, hi) in bins {
        let sel: Vec<(f32, &crate::shading_depth::Found)> = (found.iter())
            .map(|x| (truth_depth(x.face).min(args.depth_search), x))
            .filter(|(t, _)| (lo..hi).contains(t))
            .collect();
        if sel.is_empty() {
            continue;
        }
        let n = sel.len() as f32;
        let mut err: Vec<f32> = sel.iter().map(|(t, x)| (x.depth - t).abs()).collect();
        err.sort_by(f32::total_cmp);
        let within = |d: &dyn Fn(&(f32, &crate::shading_depth::Found)) -> f32| {
            100.0 * sel.iter().filter(|s| d(s) <= 1.0).count() as f32 / n
        };
        let mean = |g: &dyn Fn(&(f32, &crate::shading_depth::Found)) -> f32| {
            sel.iter().map(g).sum::<f32>() / n
        };
        println!(
            "| {lo}-{hi} | {} | {:.2} | {:.2} | {:.2} | {:.1} % | {:.1} % | {:.4} / {:.4} |",
            sel.len(),
            mean(&|(t, _)| *t),
            mean(&|(_, x)| x.depth),
            err[err.len() / 2],
            within(&|(t, x)| (x.depth - t).abs()),
            within(&|(t, _)| t.abs()),
            mean(&|(_, x)| x.misfit_at_face),
            mean(&|(_, x)| x.misfit),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid whose shading normals are all tilted by 5 degrees, and one face's by 20
    /// more: the low-pass removes the tilt and keeps most of the face's own departure.
    #[test]
    fn the_low_pass_removes_a_long_range_tilt_and_keeps_the_detail() {
        let n = 20usize;
        let mesh =
            gtsr_mesh::mesh::height_grid(n, glam::Vec2::ZERO, glam::Vec2::splat(0.2), |_, _| 0.0);
        let own = own_normals(&mesh);
        let tilt = glam::Quat::from_rotation_x(5f32.to_radians());
        let mut shading = FaceNormals {
            normal: vec![tilt * Vec3::Z; own.normal.len()],
            weight: vec![1.0; own.normal.len()],
        };
        let detail = 2 * (10 * n + 10);
        shading.normal[detail] = glam::Quat::from_rotation_y(20f32.to_radians()) * tilt * Vec3::Z;
        low_pass(&mesh, &mut shading, &own, 0.03);
        let angle = |v: Vec3| v.dot(Vec3::Z).clamp(-1.0, 1.0).acos().to_degrees();
        for (f, v) in shading.normal.iter().enumerate() {
            if f != detail {
                assert!(angle(*v) < 0.5, "face {f}: {} degrees", angle(*v));
            }
        }
        assert!(angle(shading.normal[detail]) > 15.0);
    }

    /// Shading normals tilted by an amount that depends on their direction alone lose the
    /// tilt through `orient_debias`.
    #[test]
    fn orient_debias_removes_a_direction_dependent_tilt() {
        let mut own = FaceNormals {
            normal: Vec::new(),
            weight: Vec::new(),
        };
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..200_000 {
            let z = 2.0 * next() - 1.0;
            let p = std::f32::consts::TAU * next();
            let r = (1.0 - z * z).max(0.0).sqrt();
            own.normal.push(Vec3::new(r * p.cos(), r * p.sin(), z));
            own.weight.push(1.0);
        }
        // A tilt of 3 degrees towards +z, fading to nothing at the poles.
        let tilt = |n: Vec3| {
            let t = (Vec3::Z - n.z * n).normalize_or_zero();
            (n + 3f32.to_radians().tan() * t).normalize()
        };
        let mut shading = FaceNormals {
            normal: own.normal.iter().map(|n| tilt(*n)).collect(),
            weight: own.weight.clone(),
        };
        let err = |x: &FaceNormals| {
            x.normal
                .iter()
                .zip(&own.normal)
                .map(|(a, b)| f64::from(a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees()))
                .sum::<f64>()
                / own.normal.len() as f64
        };
        assert!(err(&shading) > 2.5);
        orient_debias(&mut shading, &own, 5.0);
        assert!(err(&shading) < 0.5, "{}", err(&shading));
    }
}
