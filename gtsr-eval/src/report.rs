//! A run's `metrics.json` ([`RunMetrics`]) and markdown result tables.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::depth::DepthMetrics;
use crate::error::{Result, write_atomic};
use crate::metrics::MeshMetrics;
use gtsr_mesh::MeshError;

/// What a training run writes to `metrics.json`, and what the benchmarks read back: one type
/// for both. Fields added after the first runs read as their defaults from older files.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunMetrics {
    /// Training steps run.
    pub iterations: usize,
    /// Training time, evaluations off the clock.
    pub train_seconds: f64,
    /// Surface Gaussians at the end.
    pub surface_gaussians: usize,
    /// Interior Gaussians at the end.
    pub interior_gaussians: usize,
    /// Steps skipped for non-finite losses or gradients.
    #[serde(default)]
    pub skipped_steps: usize,
    /// Raster passes over the run.
    #[serde(default)]
    pub raster_passes: usize,
    /// Tile-splat pairs blended over the run (every pass; 0 in files from before they were
    /// counted).
    #[serde(default)]
    pub tile_splats: u64,
    /// Their mean per pass.
    #[serde(default)]
    pub tile_splats_per_pass: f64,
    /// Surface Gaussians removed by the multi-view trim.
    #[serde(default)]
    pub trimmed_surface: usize,
    /// Hidden surface Gaussians moved to the interior set (`densify.demote_every`).
    #[serde(default)]
    pub demoted_surface: usize,
    /// Mean test PSNR of C_SH (dB).
    pub test_psnr: f64,
    /// Mean test SSIM of C_SH.
    pub test_ssim: f64,
    /// Mean test PSNR of C_SH inside the masks.
    #[serde(default)]
    pub test_psnr_masked: Option<f64>,
    /// Mean test PSNR of C_PBR.
    #[serde(default)]
    pub test_psnr_pbr: Option<f64>,
    /// The mesh against the ground truth the training cameras see.
    #[serde(default)]
    pub mesh: Option<MeshMetrics>,
    /// The mesh against the whole ground truth, faces no camera sees included.
    #[serde(default)]
    pub mesh_whole_gt: Option<MeshMetrics>,
    /// The masks alone at the dataset's resolution against the seen ground truth: the
    /// baseline beside `mesh`.
    #[serde(default)]
    pub masks_alone: Option<MeshMetrics>,
    /// The mesh fused from the rendered depth alone ([`gtsr_mesh::MeshConfig::depth_only`])
    /// against the seen ground truth, when the scene has masks (without them `mesh` is one).
    #[serde(default)]
    pub mesh_depth_only: Option<MeshMetrics>,
    /// Rendered test-view depth and normals against the ground-truth mesh's.
    #[serde(default)]
    pub test_depth: Option<DepthMetrics>,
    /// The same against the ground truth averaged over each pixel's area
    /// ([`gtsr_mesh::raycast::MeshRaycaster::render_area`]): what a rendering that blends a pixel's
    /// footprint can be held to at occluding edges.
    #[serde(default)]
    pub test_depth_area: Option<DepthMetrics>,
    /// Vertices of the mesh.
    #[serde(default)]
    pub mesh_vertices: usize,
    /// Triangles of the mesh.
    #[serde(default)]
    pub mesh_triangles: usize,
}

impl RunMetrics {
    /// Reads a run's `metrics.json`, naming the file in the error.
    pub fn read(path: &Path) -> Result<RunMetrics> {
        let text = std::fs::read_to_string(path).map_err(|e| MeshError::io(path, e))?;
        serde_json::from_str(&text).map_err(|e| {
            MeshError::InvalidArgument(format!("{}: not a run's metrics ({e})", path.display()))
                .into()
        })
    }

    /// Writes it as pretty JSON, atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|e| MeshError::InvalidArgument(format!("serialising metrics: {e}")))?;
        write_atomic(path, text.as_bytes())
    }
}

/// One row of a results table; missing values print as `-`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReportRow {
    /// Method name.
    pub method: String,
    /// Scene name.
    pub scene: String,
    /// Chamfer distance (mesh units; printed times 1e3), against the ground truth the cameras
    /// see ([`crate::chamfer_seen`]) where the caller has cameras.
    pub chamfer: Option<f64>,
    /// Chamfer distance against the whole ground truth ([`crate::chamfer`]), faces no camera
    /// sees included.
    #[serde(default)]
    pub chamfer_whole_gt: Option<f64>,
    /// Mean distance from the hull-blind ground truth to the mesh ([`crate::HullBlind::blind`]:
    /// the part the masks miss; printed times 1e3).
    #[serde(default)]
    pub hull_blind: Option<f64>,
    /// F-score in `[0, 1]`.
    pub fscore: Option<f64>,
    /// Median absolute error of the rendered test-view depth against the ground truth's (mesh
    /// units; printed times 1e3; [`crate::DepthMetrics::depth_median_abs`]).
    #[serde(default)]
    pub depth_err: Option<f64>,
    /// Mean signed depth error (positive: behind the true surface; printed times 1e3).
    #[serde(default)]
    pub depth_bias: Option<f64>,
    /// The same off the truth's occluding edges
    /// ([`crate::DepthMetrics::depth_mean_signed_off_edges`]).
    #[serde(default)]
    pub depth_bias_off_edges: Option<f64>,
    /// Mean angle between rendered and true normals, degrees.
    #[serde(default)]
    pub normal_err_deg: Option<f64>,
    /// PSNR in dB.
    pub psnr: Option<f64>,
    /// SSIM.
    pub ssim: Option<f64>,
    /// Run time in seconds (what it counts is the caller's to say: `cargo xtask bench-recon`
    /// puts the training time there, evaluations excluded, and the carving time for the hull).
    pub seconds: Option<f64>,
    /// Number of Gaussians.
    pub gaussians: Option<u64>,
    /// Mean tile-splat pairs blended per training step (what a step cost; printed in
    /// thousands).
    #[serde(default)]
    pub tile_splats_per_step: Option<f64>,
}

fn cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

fn opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    match v {
        Some(v) if v.is_finite() => f(v),
        Some(v) if v == f64::INFINITY => "inf".into(),
        _ => "-".into(),
    }
}

/// Wall time as `h:mm:ss` (or `m:ss` under an hour).
pub fn format_duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}:{:02}:{:02}", s / 3600, (s / 60) % 60, s % 60)
    } else {
        format!("{}:{:02}", s / 60, s % 60)
    }
}

/// A GitHub-flavoured markdown table: method, scene, chamfer x 1e3 (2 decimals), the same
/// against the whole ground truth, the mean distance on the hull-blind part x 1e3 (2), F-score
/// (3), depth error, bias and bias off the truth's occluding edges x 1e3 (2), normal error
/// (degrees, 1), PSNR (2), SSIM (4), time (`h:mm:ss`), Gaussians, tile-splat pairs per step
/// (thousands, 1).
pub fn markdown_table(rows: &[ReportRow]) -> String {
    let mut s = String::from(
        "| method | scene | chamfer x1e3 | chamfer x1e3, whole GT | hull-blind x1e3 | F-score | \
         depth err x1e3 | depth bias x1e3 | bias off edges x1e3 | normal err (deg) | PSNR | SSIM | \
         time | Gaussians | tile-splats/step |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            cell(&r.method),
            cell(&r.scene),
            opt(r.chamfer, |v| format!("{:.2}", v * 1e3)),
            opt(r.chamfer_whole_gt, |v| format!("{:.2}", v * 1e3)),
            opt(r.hull_blind, |v| format!("{:.2}", v * 1e3)),
            opt(r.fscore, |v| format!("{v:.3}")),
            opt(r.depth_err, |v| format!("{:.2}", v * 1e3)),
            opt(r.depth_bias, |v| format!("{:+.2}", v * 1e3)),
            opt(r.depth_bias_off_edges, |v| format!("{:+.2}", v * 1e3)),
            opt(r.normal_err_deg, |v| format!("{v:.1}")),
            opt(r.psnr, |v| format!("{v:.2}")),
            opt(r.ssim, |v| format!("{v:.4}")),
            opt(r.seconds, format_duration),
            r.gaussians
                .map(|g| g.to_string())
                .unwrap_or_else(|| "-".into()),
            opt(r.tile_splats_per_step, |v| format!("{:.1}k", v / 1e3)),
        ));
    }
    s
}

/// Writes [`markdown_table`] to `path` atomically.
pub fn write_markdown(path: &Path, rows: &[ReportRow]) -> Result<()> {
    write_atomic(path, markdown_table(rows).as_bytes())
}

/// `mean ± sd` of `values` (the sample standard deviation, over `n - 1`), each scaled by
/// `scale` and printed by `f`; the mean alone for one value, `-` for none.
fn mean_sd(values: &[f64], scale: f64, f: impl Fn(f64) -> String) -> String {
    let v: Vec<f64> = values
        .iter()
        .map(|x| x * scale)
        .filter(|x| x.is_finite())
        .collect();
    match v.len() {
        0 => "-".into(),
        1 => f(v[0]),
        n => {
            let mean = v.iter().sum::<f64>() / n as f64;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            format!("{} ± {}", f(mean), f(var.sqrt()).trim_start_matches('+'))
        }
    }
}

/// Over the seeds both `a` and `b` ran: how many seeds `a`'s value of `get` is the smaller,
/// out of how many, as `k/n` (`-` when they share no seed with a value).
fn paired_wins(
    a: &[(u64, &ReportRow)],
    b: &[(u64, &ReportRow)],
    get: impl Fn(&ReportRow) -> Option<f64>,
) -> String {
    let (mut wins, mut n) = (0, 0);
    for (seed, ra) in a {
        let Some(va) = get(ra).filter(|v| v.is_finite()) else {
            continue;
        };
        if let Some(vb) = b
            .iter()
            .find(|(s, _)| s == seed)
            .and_then(|(_, rb)| get(rb))
            .filter(|v| v.is_finite())
        {
            n += 1;
            wins += usize::from(va < vb);
        }
    }
    if n == 0 {
        "-".into()
    } else {
        format!("{wins}/{n}")
    }
}

/// The same methods trained with several seeds, summarised: per method and scene (in the
/// order they first appear in `rows`, `(seed, row)` pairs), the number of seeds and the
/// `mean ± sd` over them of the depth error, depth bias, normal error, chamfer (x 1e3),
/// PSNR, SSIM and time; and, against `reference` on the same scene and seed, in how many
/// seeds the reference's depth error and normal error are the smaller (`k/n`: the reference
/// ahead in k of the n seeds both ran).
pub fn seed_summary_table(rows: &[(u64, ReportRow)], reference: &str) -> String {
    // ((scene, method), the group's (seed, row) pairs).
    type Group<'a> = ((&'a str, &'a str), Vec<(u64, &'a ReportRow)>);
    let mut groups: Vec<Group> = Vec::new();
    for (seed, r) in rows {
        let key = (r.scene.as_str(), r.method.as_str());
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, g)) => g.push((*seed, r)),
            None => groups.push((key, vec![(*seed, r)])),
        }
    }
    let mut s = format!(
        "| method | scene | seeds | depth err x1e3 | depth bias x1e3 | normal err (deg) | \
         chamfer x1e3 | PSNR | SSIM | time | {reference} ahead on depth err | \
         {reference} ahead on normal err |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        reference = cell(reference)
    );
    for ((scene, method), g) in &groups {
        let col = |get: fn(&ReportRow) -> Option<f64>| -> Vec<f64> {
            g.iter().filter_map(|(_, r)| get(r)).collect()
        };
        let refs = groups
            .iter()
            .find(|((sc, m), _)| sc == scene && *m == reference)
            .map(|(_, g)| g.as_slice());
        let wins = |get: fn(&ReportRow) -> Option<f64>| match refs {
            Some(rg) if *method != reference => paired_wins(rg, g, get),
            _ => "-".into(),
        };
        let seeds: Vec<String> = g.iter().map(|(sd, _)| sd.to_string()).collect();
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            cell(method),
            cell(scene),
            seeds.join(", "),
            mean_sd(&col(|r| r.depth_err), 1e3, |v| format!("{v:.2}")),
            mean_sd(&col(|r| r.depth_bias), 1e3, |v| format!("{v:+.2}")),
            mean_sd(&col(|r| r.normal_err_deg), 1.0, |v| format!("{v:.1}")),
            mean_sd(&col(|r| r.chamfer), 1e3, |v| format!("{v:.2}")),
            mean_sd(&col(|r| r.psnr), 1.0, |v| format!("{v:.2}")),
            mean_sd(&col(|r| r.ssim), 1.0, |v| format!("{v:.4}")),
            mean_sd(&col(|r| r.seconds), 1.0, format_duration),
            wins(|r| r.depth_err),
            wins(|r| r.normal_err_deg),
        ));
    }
    s
}
