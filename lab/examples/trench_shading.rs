//! Whether the images' shading tells a concavity the masks cannot see from the lid the masks
//! put over it (a diagnosis: it reads the ground truth, so only on development scenes).
//!
//! For every training view at the dataset's resolution it fits the scattering model
//! `I = a (P * L) + b (G_s * L)` (`gtsr_mesh::scatter::fit_scatter`, the widths of
//! `PIXEL_SIGMAS` x `SCATTER_SIGMAS`) to the images' grey linear radiance, with `L` the ground
//! truth's Lambertian radiance `(n . w) / r^2` under the light at the camera, over the flush
//! pixels (the truth within half a footprint of the masks' mesh). It then predicts each image
//! twice, once from the truth's `L` and once from the masks' mesh's (the lid), and compares
//! the two with the image over the concave pixels (the truth more than `--gap` footprints
//! behind the masks' mesh) and, as the control, over the flush ones. Where the shading
//! carries the concavity, the truth's prediction explains those pixels clearly better than
//! the lid's. A last table bins the image over the diffuse prediction by the cosine between
//! the normal and the direction to the camera: the specular lobe under the light at the
//! camera shows where that cosine nears 1.
//!
//! ```text
//! cargo run --release -p lab --example trench_shading -- ../shared/data/amber_ingot [GAP]
//! ```

use std::path::PathBuf;

use gtsr_mesh::raycast::MeshRaycaster;
use gtsr_mesh::scatter::{
    PIXEL_SIGMAS, SCATTER_MAX_AMPLIFICATION, SCATTER_SIGMAS, Scatter, ScatterView, fit_scatter,
    lambert_of_depth,
};
use gtsr_mesh::shading::view_radiance;

mod common;

/// Sums over a pixel class.
#[derive(Default)]
struct Tally {
    n: usize,
    image: f64,
    abs_truth: f64,
    abs_lid: f64,
    signed_truth: f64,
    signed_lid: f64,
    contrast: f64,
    truth_better: usize,
}

impl Tally {
    fn add(&mut self, i: f32, t: f32, l: f32) {
        let (i, t, l) = (f64::from(i), f64::from(t), f64::from(l));
        self.n += 1;
        self.image += i;
        self.abs_truth += (i - t).abs();
        self.abs_lid += (i - l).abs();
        self.signed_truth += i - t;
        self.signed_lid += i - l;
        self.contrast += (t - l).abs();
        self.truth_better += usize::from((i - t).abs() < (i - l).abs());
    }

    fn row(&self, label: &str) -> String {
        let n = self.n.max(1) as f64;
        let rel = |x: f64| 100.0 * x / self.image.max(f64::MIN_POSITIVE);
        format!(
            "| {label} | {} | {:.2} | {:.2} | {:+.2} | {:+.2} | {:.2} | {:.1} % |",
            self.n,
            rel(self.abs_truth),
            rel(self.abs_lid),
            rel(self.signed_truth),
            rel(self.signed_lid),
            rel(self.contrast),
            100.0 * self.truth_better as f64 / n,
        )
    }
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let dir: PathBuf = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: trench_shading SCENE_DIR [GAP_FOOTPRINTS]"))?
        .into();
    let gap: f32 = match args.next() {
        Some(s) => s
            .parse()
            .map_err(|e| anyhow::anyhow!("GAP_FOOTPRINTS '{s}': {e}"))?,
        None => 3.0,
    };
    let common::DevScene { scene, hull, gt } = common::load(&dir)?;
    let truth = MeshRaycaster::new(&gt, "ground truth")?;
    let lid = MeshRaycaster::new(&hull, "masks' mesh")?;

    // Per view: grey linear radiance, both Lambert maps and cosines, both depth maps.
    struct Maps {
        w: usize,
        h: usize,
        grey: Vec<f32>,
        mask: Vec<f32>,
        l_truth: Vec<f32>,
        c_truth: Vec<f32>,
        l_lid: Vec<f32>,
        c_lid: Vec<f32>,
        behind: Vec<f32>,
        concave: Vec<bool>,
        flush: Vec<bool>,
    }
    let maps: Vec<Maps> = scene
        .train
        .iter()
        .map(|v| {
            let (w, h) = (v.width() as usize, v.height() as usize);
            let grey = view_radiance(v, None);
            let (dt, dl) = (truth.render(&v.camera), lid.render(&v.camera));
            let (l_truth, c_truth) = lambert_of_depth(&dt, &v.camera);
            let (l_lid, c_lid) = lambert_of_depth(&dl, &v.camera);
            // The masks' mesh's occluding edges are left out (a pixel there mixes two
            // surfaces); the truth's are not, since a narrow concavity is nearly all edge.
            let edges = dl.occluding_edges(gtsr_mesh::raycast::EDGE_FOOTPRINTS);
            let mask = v.mask.clone().unwrap_or_default();
            let (mut concave, mut flush) = (vec![false; w * h], vec![false; w * h]);
            let mut behind_fp = vec![f32::NAN; w * h];
            for p in 0..w * h {
                let (zt, zl) = (dt.depth[p], dl.depth[p]);
                if zt <= 0.0 || zl <= 0.0 || edges[p] || mask[p] < 0.99 {
                    continue;
                }
                let behind = (zt - zl) / (zl / dt.focal);
                behind_fp[p] = behind;
                concave[p] = behind > gap;
                flush[p] = behind.abs() < 0.5;
            }
            Maps {
                w,
                h,
                grey,
                mask,
                l_truth,
                c_truth,
                l_lid,
                c_lid,
                behind: behind_fp,
                concave,
                flush,
            }
        })
        .collect();

    // The scattering model, fitted on the truth over the flush pixels of every view.
    let model = fit_best(
        &maps
            .iter()
            .map(|m| {
                (
                    m.w,
                    m.h,
                    &m.grey[..],
                    &m.mask[..],
                    &m.l_truth[..],
                    &m.c_truth[..],
                    m.flush.iter().map(|f| !f).collect(),
                )
            })
            .collect::<Vec<_>>(),
    )?;
    // The same model fitted on the masks' mesh over every pixel it covers off its occluding
    // edges: what a run could fit without the truth.
    let model_lid = fit_best(
        &maps
            .iter()
            .map(|m| {
                (
                    m.w,
                    m.h,
                    &m.grey[..],
                    &m.mask[..],
                    &m.l_lid[..],
                    &m.c_lid[..],
                    m.behind.iter().map(|b| b.is_nan()).collect(),
                )
            })
            .collect::<Vec<_>>(),
    )?;

    let (mut concave, mut flush) = (Tally::default(), Tally::default());
    let mut views_concave = 0;
    // Image over the image-only prediction from the masks' mesh, per pixel class.
    let bins = [
        (0.5f32, "flush"),
        (3.0, "3-10 fp behind"),
        (10.0, "10-20 fp"),
        (20.0, "20-30 fp"),
        (30.0, "30-40 fp"),
        (40.0, "40+ fp"),
    ];
    let mut ratios: Vec<Vec<f32>> = vec![Vec::new(); bins.len()];
    // Image over the truth's prediction by the truth's cosine to the camera (the specular
    // lobe under the light at the camera peaks where the normal faces the camera).
    let mut by_cos: [Vec<Vec<f32>>; 2] = [
        vec![Vec::new(); COS_BINS.len()],
        vec![Vec::new(); COS_BINS.len()],
    ];
    let mut lid_by_cos: Vec<Vec<f32>> = vec![Vec::new(); COS_BINS.len()];
    let mut concave_by_lid_cos: Vec<Vec<f32>> = vec![Vec::new(); COS_BINS.len()];
    let mut other = Vec::new();
    for m in &maps {
        let pt = model.predict(&m.l_truth, m.w, m.h);
        let pl = model.predict(&m.l_lid, m.w, m.h);
        let pi = model_lid.predict(&m.l_lid, m.w, m.h);
        let mut any = false;
        for p in 0..m.w * m.h {
            if m.concave[p] {
                concave.add(m.grey[p], pt[p], pl[p]);
                any = true;
            } else if m.flush[p] {
                flush.add(m.grey[p], pt[p], pl[p]);
            }
            let b = m.behind[p];
            if b.is_nan() || pi[p] <= 0.0 || m.c_lid[p] < 0.2 {
                continue;
            }
            let r = m.grey[p] / pi[p];
            if b.abs() < 0.5 {
                ratios[0].push(r);
            } else if let Some(k) = (1..bins.len()).rev().find(|&k| b > bins[k].0) {
                ratios[k].push(r);
            } else {
                other.push(r);
            }
        }
        views_concave += usize::from(any);
        for p in 0..m.w * m.h {
            let class = if m.concave[p] {
                1
            } else if m.flush[p] {
                0
            } else {
                continue;
            };
            let c = m.c_truth[p];
            if pt[p] <= 0.0 || c < COS_BINS[0] {
                continue;
            }
            let k = COS_BINS.iter().rposition(|&b| c >= b).unwrap_or(0);
            by_cos[class][k].push(m.grey[p] / pt[p]);
            if class == 1 && pl[p] > 0.0 {
                lid_by_cos[k].push(m.grey[p] / pl[p]);
                let c = m.c_lid[p];
                if c >= COS_BINS[0] {
                    let k = COS_BINS.iter().rposition(|&b| c >= b).unwrap_or(0);
                    concave_by_lid_cos[k].push(m.grey[p] / pl[p]);
                }
            }
        }
    }
    println!(
        "scattering model (fitted on the truth's flush pixels): {}",
        describe(&model)
    );
    println!(
        "concave: the truth more than {gap} footprints behind the masks' mesh ({views_concave} of {} views show some)",
        maps.len()
    );
    println!();
    println!(
        "Errors as % of the image's summed radiance over the class; contrast: |truth's prediction - lid's|."
    );
    println!();
    println!(
        "| pixels | count | abs error, truth | abs error, lid | signed, truth | signed, lid | contrast | truth nearer |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    println!("{}", concave.row("concave"));
    println!("{}", flush.row("flush (control)"));
    println!();
    println!(
        "Image-only: the model fitted on the masks' mesh ({}); the image over its prediction, \
         pixels whose cosine on the masks' mesh is at least 0.2:",
        describe(&model_lid)
    );
    println!();
    println!(
        "| pixels (truth behind the masks' mesh) | count | 10th | median | 90th | below 0.6 |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    let mut rows: Vec<(String, Vec<f32>)> = bins
        .iter()
        .zip(ratios)
        .map(|((_, l), r)| (l.to_string(), r))
        .collect();
    rows.insert(1, ("0.5-3 fp (or in front)".into(), other));
    for (label, mut r) in rows {
        r.sort_by(f32::total_cmp);
        let q = |f: f64| {
            r.get(((r.len() as f64 - 1.0) * f).round() as usize)
                .copied()
                .unwrap_or(f32::NAN)
        };
        let low = r.iter().filter(|x| **x < 0.6).count();
        println!(
            "| {label} | {} | {:.3} | {:.3} | {:.3} | {} ({:.2} %) |",
            r.len(),
            q(0.1),
            q(0.5),
            q(0.9),
            low,
            100.0 * low as f64 / r.len().max(1) as f64
        );
    }
    println!();
    println!(
        "By the truth's cosine to the camera: the image over the truth's prediction (median, 90th), \
         flush and concave, and over the lid's prediction on the concave pixels:"
    );
    println!();
    println!(
        "| cosine from | flush n | flush median | flush 90th | concave n | concave median | concave 90th | concave / lid median | concave by the lid's cosine: n | its image / lid median |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (k, lo) in COS_BINS.iter().enumerate() {
        let mut f = std::mem::take(&mut by_cos[0][k]);
        let mut c = std::mem::take(&mut by_cos[1][k]);
        let mut l = std::mem::take(&mut lid_by_cos[k]);
        let mut b = std::mem::take(&mut concave_by_lid_cos[k]);
        println!(
            "| {lo} | {} | {:.3} | {:.3} | {} | {:.3} | {:.3} | {:.3} | {} | {:.3} |",
            f.len(),
            quantile(&mut f, 0.5),
            quantile(&mut f, 0.9),
            c.len(),
            quantile(&mut c, 0.5),
            quantile(&mut c, 0.9),
            quantile(&mut l, 0.5),
            b.len(),
            quantile(&mut b, 0.5),
        );
    }
    Ok(())
}

/// Lower edges of the cosine bins of the specular table.
const COS_BINS: [f32; 11] = [
    0.2, 0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.998, 0.999, 0.9995,
];

fn quantile(v: &mut [f32], q: f64) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    v.sort_by(f32::total_cmp);
    v[((v.len() as f64 - 1.0) * q).round() as usize]
}

/// One view's maps for [`fit_best`]: size, radiance, mask, Lambert, cosine, pixels skipped.
type FitView<'a> = (
    usize,
    usize,
    &'a [f32],
    &'a [f32],
    &'a [f32],
    &'a [f32],
    Vec<bool>,
);

/// The scattering model of least residual over every pixel filter and blur width tried.
fn fit_best(views: &[FitView<'_>]) -> anyhow::Result<Scatter> {
    let views: Vec<ScatterView> = views
        .iter()
        .map(
            |(w, h, radiance, mask, lambert, cosine, skip)| ScatterView {
                width: *w,
                height: *h,
                radiance,
                mask: Some(mask),
                lambert,
                cosine,
                skip: Some(skip),
            },
        )
        .collect();
    let mut sigmas = vec![0.0];
    sigmas.extend(SCATTER_SIGMAS);
    let mut best: Option<Scatter> = None;
    for pixel in PIXEL_SIGMAS {
        for s in fit_scatter(&views, pixel, &sigmas, 0.2, SCATTER_MAX_AMPLIFICATION)? {
            if best.is_none_or(|b| s.residual < b.residual) {
                best = Some(s);
            }
        }
    }
    best.ok_or_else(|| anyhow::anyhow!("no scattering model fitted"))
}

fn describe(m: &Scatter) -> String {
    format!(
        "a {:.4}, b {:.4}, blur {:.1} px, pixel filter {:.1} px, relative residual {:.4}",
        m.sharp, m.blurred, m.sigma, m.pixel, m.residual
    )
}
