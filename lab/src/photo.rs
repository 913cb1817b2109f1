//! `cargo lab photo-consistency`: do the images themselves say how deep a concavity the
//! masks cannot see lies?
//!
//! A plane sweep on the training images, scored by the ground truth (development scenes
//! only). On each reference view, every pixel whose ray meets the truth more than `--gap`
//! footprints behind the masks' mesh (into a concavity the masks cannot see), and a sample of
//! the pixels where the two agree (the flush surface, a control), is searched along its ray
//! from the masks' depth inwards in quarter-footprint steps. At each depth a fronto-parallel
//! patch around the pixel is carried into the reference view's nearest views and compared by
//! normalised cross-correlation (grey levels, the mean of the three channels); a depth's cost
//! is the mean `1 - NCC` over the better half of those views (the others may see a wall or a
//! rim in front). The least cost wins. The ground truth only scores: where the winner lies
//! against the truth's depth and against the masks' (the lid), and whether the truth's depth
//! costs less than the lid's. Where the images prefer the truth, a wide search can find what
//! a gradient from the lid cannot; where they do not, no photometric term will.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use gtsr_data::Camera;
use gtsr_mesh::consistency::nearest_views;
use gtsr_mesh::pixels::bilinear;
use gtsr_mesh::raycast::MeshRaycaster;
use rayon::prelude::*;

use gtsr_eval::{ground_truth, native_masks_mesh};

#[derive(Args, Debug)]
pub struct PhotoConsistencyArgs {
    /// Scene folder (Blender/NeRF with `mesh.ply` and masks), read at its own resolution.
    #[arg(long)]
    pub data: PathBuf,
    /// Reference views, spread evenly over the training views.
    #[arg(long, default_value_t = 8)]
    pub views: usize,
    /// A pixel looks into a concavity when the truth lies this many footprints behind the
    /// masks' mesh on its ray.
    #[arg(long, default_value_t = 3.0)]
    pub gap: f32,
    /// Neighbour views per reference view (the nearest by their optical axes,
    /// [`gtsr_mesh::consistency::nearest_views`]).
    #[arg(long, default_value_t = 6)]
    pub neighbours: usize,
    /// How far behind the masks' depth the sweep goes, in footprints.
    #[arg(long, default_value_t = 16.0)]
    pub max_depth: f32,
    /// Half the patch's side in pixels (the patch is `2 r + 1` pixels square).
    #[arg(long, default_value_t = 3)]
    pub patch_radius: usize,
    /// Every this many flush pixels one is searched (the control).
    #[arg(long, default_value_t = 9)]
    pub flush_stride: usize,
    /// Write the report here (markdown) as well as to standard output.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Sweep steps per footprint.
const STEPS_PER_FOOTPRINT: f32 = 4.0;
/// A reference patch whose grey levels vary less than this (standard deviation) has nothing
/// to correlate and is counted as textureless.
const MIN_PATCH_STD: f32 = 2e-3;

/// One searched pixel's outcome.
#[derive(Clone, Copy)]
struct Found {
    /// The truth's depth behind the masks', footprints.
    truth: f32,
    /// The least-cost depth behind the masks', footprints.
    best: f32,
    /// The cost at the lid (the masks' depth), at the truth, at the best depth.
    costs: [f32; 3],
}

/// Per class (0: into a concavity, 1: flush), the searched pixels' outcomes and how many had
/// a textureless patch.
#[derive(Default)]
struct ClassFinds {
    found: Vec<Found>,
    textureless: usize,
    unseen: usize,
}

/// The grey level of each pixel (the mean of the three channels).
fn grey(rgb: &[f32]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|c| (c[0] + c[1] + c[2]) / 3.0)
        .collect()
}

/// Normalised cross-correlation of two equally long samples; `None` when either is flat.
fn ncc(a: &[f32], b: &[f32]) -> Option<f32> {
    let n = a.len() as f32;
    let (ma, mb) = (a.iter().sum::<f32>() / n, b.iter().sum::<f32>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0f32, 0.0f32, 0.0f32);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    let den = (saa * sbb).sqrt();
    (den > 1e-12).then(|| sab / den)
}

/// The world-space rays of the `(2 r + 1)^2` pixels of the patch around pixel `(i, j)` of
/// `cam`: the camera centre and, per pixel, the direction whose camera-space z is 1, so that
/// `centre + d * direction` lies at z-depth `d` (a fronto-parallel patch).
fn patch_rays(cam: &Camera, (i, j): (usize, usize), r: isize) -> (Vec3, Vec<Vec3>) {
    let c2w = cam.camera_to_world();
    let dirs = (-r..=r)
        .flat_map(|dv| (-r..=r).map(move |du| (du, dv)))
        .map(|(du, dv)| {
            let u = i as f32 + 0.5 + du as f32;
            let v = j as f32 + 0.5 + dv as f32;
            c2w.transform_vector3(cam.camera_direction(u, v))
        })
        .collect();
    (cam.centre(), dirs)
}

/// The sweep's cost at z-depth `d` for the patch whose rays are `rays` ([`patch_rays`]): the
/// mean `1 - NCC` over the better half of the neighbours the patch falls into; `None` when
/// none does.
fn cost_at(
    ref_patch: &[f32],
    (centre, dirs): &(Vec3, Vec<Vec3>),
    d: f32,
    neighbours: &[(&Camera, &[f32])],
    scratch: &mut Vec<f32>,
) -> Option<f32> {
    let mut costs: Vec<f32> = Vec::with_capacity(neighbours.len());
    'views: for (ncam, ngrey) in neighbours {
        scratch.clear();
        let (w, h) = (ncam.width as usize, ncam.height as usize);
        for dir in dirs {
            let Some((uv, _)) = ncam.project(*centre + *dir * d) else {
                continue 'views;
            };
            if uv.x < 0.5 || uv.y < 0.5 || uv.x > w as f32 - 0.5 || uv.y > h as f32 - 0.5 {
                continue 'views;
            }
            scratch.push(bilinear(ngrey, w, h, uv.x, uv.y));
        }
        if let Some(c) = ncc(ref_patch, scratch) {
            costs.push(1.0 - c);
        }
    }
    if costs.is_empty() {
        return None;
    }
    costs.sort_unstable_by(f32::total_cmp);
    let half = costs.len().div_ceil(2);
    Some(costs[..half].iter().sum::<f32>() / half as f32)
}

pub fn run(args: &PhotoConsistencyArgs) -> Result<()> {
    if args.views == 0 || args.neighbours == 0 || args.flush_stride == 0 {
        bail!("--views, --neighbours and --flush-stride must be at least 1");
    }
    if !(args.gap.is_finite() && args.gap > 0.0 && args.max_depth.is_finite())
        || args.max_depth <= args.gap
    {
        bail!("--gap must be positive and below --max-depth, both finite");
    }
    let t0 = std::time::Instant::now();
    let (scene, hull_mesh) = native_masks_mesh(&args.data)?;
    let gt = ground_truth(&scene, &args.data)?;
    let hull_caster = MeshRaycaster::new(&hull_mesh, "masks' mesh")?;
    let gt_caster = MeshRaycaster::new(&gt, "ground-truth mesh")?;
    let cameras: Vec<&Camera> = scene.train.iter().map(|v| &v.camera).collect();
    let greys: Vec<Vec<f32>> = scene.train.iter().map(|v| grey(&v.rgb)).collect();
    let n = scene.train.len();
    let refs: Vec<usize> = (0..args.views.min(n))
        .map(|k| k * n / args.views.min(n))
        .collect();
    let r = args.patch_radius as isize;
    let steps = (args.max_depth * STEPS_PER_FOOTPRINT).round() as usize;
    let mut classes = [ClassFinds::default(), ClassFinds::default()];
    for &rv in &refs {
        let view = &scene.train[rv];
        let cam = &view.camera;
        let mask = view
            .mask
            .as_deref()
            .with_context(|| format!("training view {} has no mask", view.name))?;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let truth = gt_caster.render(cam).depth;
        let hull = hull_caster.render(cam).depth;
        let neighbours: Vec<(&Camera, &[f32])> = nearest_views(&cameras, rv, args.neighbours)
            .into_iter()
            .map(|j| (cameras[j], greys[j].as_slice()))
            .collect();
        let g = &greys[rv];
        let fx = cam.fx;
        let offset = |p: usize| (truth[p] - hull[p]) * fx / hull[p];
        let inside = |p: usize| {
            let (i, j) = (p % w, p / w);
            mask[p] > 0.5
                && truth[p] > 0.0
                && hull[p] > 0.0
                && i as isize >= r
                && j as isize >= r
                && i + (r as usize) < w
                && j + (r as usize) < h
        };
        let mut flush_seen = 0usize;
        let mut work: Vec<(usize, usize)> = Vec::new();
        for p in (0..w * h).filter(|&p| inside(p)) {
            let o = offset(p);
            if o > args.gap {
                work.push((p, 0));
            } else if o.abs() < 0.5 {
                flush_seen += 1;
                if flush_seen.is_multiple_of(args.flush_stride) {
                    work.push((p, 1));
                }
            }
        }
        let results: Vec<(usize, Option<Option<Found>>)> = work
            .par_iter()
            .map_init(Vec::new, |scratch, &(p, class)| {
                let (i, j) = (p % w, p / w);
                let mut ref_patch = Vec::with_capacity((2 * r as usize + 1).pow(2));
                for dv in -r..=r {
                    for du in -r..=r {
                        let (x, y) = ((i as isize + du) as usize, (j as isize + dv) as usize);
                        ref_patch.push(g[y * w + x]);
                    }
                }
                let n = ref_patch.len() as f32;
                let mean = ref_patch.iter().sum::<f32>() / n;
                let var = ref_patch.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / n;
                if var.sqrt() < MIN_PATCH_STD {
                    return (class, Some(None));
                }
                let fp = hull[p] / fx;
                let rays = patch_rays(cam, (i, j), r);
                let costs: Vec<f32> = (0..=steps)
                    .map(|k| {
                        let d = hull[p] + k as f32 / STEPS_PER_FOOTPRINT * fp;
                        cost_at(&ref_patch, &rays, d, &neighbours, scratch).unwrap_or(f32::INFINITY)
                    })
                    .collect();
                let truth_t = offset(p);
                let kt = ((truth_t * STEPS_PER_FOOTPRINT).round().max(0.0) as usize).min(steps);
                let (kb, cb) = costs
                    .iter()
                    .enumerate()
                    .fold(
                        (0, f32::INFINITY),
                        |acc, (k, c)| if *c < acc.1 { (k, *c) } else { acc },
                    );
                if !cb.is_finite() {
                    return (class, None);
                }
                let found = Found {
                    truth: truth_t,
                    best: kb as f32 / STEPS_PER_FOOTPRINT,
                    costs: [costs[0], costs[kt], cb],
                };
                (class, Some(Some(found)))
            })
            .collect();
        for (class, res) in results {
            match res {
                None => classes[class].unseen += 1,
                Some(None) => classes[class].textureless += 1,
                Some(Some(f)) => classes[class].found.push(f),
            }
        }
    }
    let md = report(args, &refs, &mut classes, t0.elapsed().as_secs_f64());
    print!("{md}");
    if let Some(out) = &args.out {
        gtsr_data::image_io::write_atomic(out, md.as_bytes())
            .with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}

fn report(
    args: &PhotoConsistencyArgs,
    refs: &[usize],
    classes: &mut [ClassFinds; 2],
    secs: f64,
) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Photo-consistency along the rays: {}\n\n{} reference views ({:?}), {} neighbours each \
         (the better half scored), {}x{} px patches, depths 0 to {} footprints behind the \
         masks' mesh in steps of {}; concavity: the truth more than {} footprints behind it. \
         {:.0} s.\n",
        args.data.display(),
        refs.len(),
        refs,
        args.neighbours,
        2 * args.patch_radius + 1,
        2 * args.patch_radius + 1,
        args.max_depth,
        1.0 / STEPS_PER_FOOTPRINT,
        args.gap,
        secs
    );
    let _ = writeln!(
        md,
        "| pixels | searched | textureless / unseen | truth behind the masks (median fp) | \
         found (median fp) | found within 1 fp of the truth | found within 1 fp of the lid | \
         truth costs less than the lid | cost at the lid / truth / found (mean) |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (name, c) in ["into a concavity", "flush (a sample)"]
        .iter()
        .zip(classes.iter_mut())
    {
        let n = c.found.len();
        if n == 0 {
            let _ = writeln!(
                md,
                "| {name} | 0 | {} / {} | - | - | - | - | - | - |",
                c.textureless, c.unseen
            );
            continue;
        }
        let median = |v: &mut Vec<f32>| {
            v.sort_unstable_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let mut truths: Vec<f32> = c.found.iter().map(|f| f.truth).collect();
        let mut bests: Vec<f32> = c.found.iter().map(|f| f.best).collect();
        let share = |pred: &dyn Fn(&Found) -> bool| {
            100.0 * c.found.iter().filter(|f| pred(f)).count() as f64 / n as f64
        };
        let near_truth = share(&|f| (f.best - f.truth.min(args.max_depth)).abs() <= 1.0);
        let near_lid = share(&|f| f.best <= 1.0);
        let truth_wins = share(&|f| f.costs[1] < f.costs[0]);
        let mean = |k: usize| c.found.iter().map(|f| f.costs[k] as f64).sum::<f64>() / n as f64;
        let _ = writeln!(
            md,
            "| {name} | {n} | {} / {} | {:.2} | {:.2} | {near_truth:.1} % | {near_lid:.1} % | \
             {truth_wins:.1} % | {:.3} / {:.3} / {:.3} |",
            c.textureless,
            c.unseen,
            median(&mut truths),
            median(&mut bests),
            mean(0),
            mean(1),
            mean(2)
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ncc_is_one_for_an_affine_copy_and_none_when_flat() {
        let a = [0.1, 0.4, 0.2, 0.9, 0.5];
        let b: Vec<f32> = a.iter().map(|x| 0.3 + 2.0 * x).collect();
        assert!((ncc(&a, &b).unwrap() - 1.0).abs() < 1e-5);
        let neg: Vec<f32> = a.iter().map(|x| 1.0 - x).collect();
        assert!((ncc(&a, &neg).unwrap() + 1.0).abs() < 1e-5);
        assert!(ncc(&a, &[0.5; 5]).is_none());
    }
}
