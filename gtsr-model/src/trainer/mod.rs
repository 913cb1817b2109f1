//! The training step and its schedule.
//!
//! Stage 1 (steps `< stage2_start`): the surface set alone, photometric (C_SH) plus mask and
//! flattening. Stage 2: the interior set is added (placed just inside the surface set), C_SH
//! blends both with Fresnel-weighted surface opacity, and C_PBR, the PGSR geometric terms,
//! interior containment and material smoothness join the loss (each as switched on).
//!
//! A step whose loss or any gradient is not finite is skipped (nothing is written into the
//! parameters or the optimiser) and counted. Every random choice is derived from the seed
//! and the step number, so a resumed run repeats an uninterrupted one exactly.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use burn::tensor::{Bool, Device, Tensor};
use gtsr_render_kernels::cpu::{KernelTimes, kernel_times};
use rand::{RngExt, SeedableRng, rngs::StdRng};
use serde::{Deserialize, Serialize};

use crate::config::{LossWeights, TrainConfig};
use crate::densify::{DensifyReport, DensifyStats};
use crate::error::ModelError;
use crate::gaussians::{GaussianSet, ParamKind, SetKind, host_set_from_points, host_vec};
use crate::losses;
use crate::model::{Model, RenderOptions, scalar_param};
use crate::optim::SetOptimizer;
use crate::pbr::ShadingParams;
use crate::views::{ViewTensors, neighbours};

mod density;
mod init;

pub use init::initial_points;

/// Counters kept across the run (saved in checkpoints).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Counters {
    /// Steps skipped because the loss or a gradient was not finite.
    pub skipped_steps: usize,
    /// Raster passes run so far.
    pub passes: usize,
    /// Densifications run.
    pub densifications: usize,
    /// Tile-splat pairs blended so far, over every pass (what the passes cost; 0 in checkpoints
    /// written before it was counted).
    #[serde(default)]
    pub tile_splats: u64,
    /// Surface Gaussians removed by the multi-view trim so far.
    #[serde(default)]
    pub trimmed: usize,
    /// Hidden surface Gaussians moved to the interior set so far
    /// ([`Trainer::demote_hidden`]).
    #[serde(default)]
    pub demoted: usize,
}

/// What one step did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// The step index (before incrementing).
    pub step: usize,
    /// 1 or 2.
    pub stage: u8,
    /// Training view used.
    pub view: usize,
    /// Total loss (NaN if it was not finite).
    pub loss: f64,
    /// Each term's weighted value.
    pub terms: Vec<(&'static str, f64)>,
    /// Raster passes this step.
    pub passes: usize,
    /// Tile-splat pairs of this step's passes.
    pub tile_splats: u64,
    /// Whether the update was skipped.
    pub skipped: bool,
    /// Densification done after this step.
    pub densified: Option<(DensifyReport, DensifyReport)>,
    /// Set sizes after the step.
    pub counts: (usize, usize),
    /// Where the step's wall time went.
    pub times: StepTimes,
}

/// Wall time of one step by phase. `forward` and `backward` include the splatting kernels,
/// whose own phases (CPU backend) are in `kernels`; the rest of them is Burn's tensor work
/// (SH, Fresnel, C_PBR, losses and their autodiff).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepTimes {
    /// Renders and losses (the graph's forward pass), including the loss read-backs.
    pub forward: Duration,
    /// `backward()` on the total loss.
    pub backward: Duration,
    /// Gradient read-out, the finiteness check and the densification statistics.
    pub gradients: Duration,
    /// The Adam updates.
    pub adam: Duration,
    /// Densification and pruning (on its schedule).
    pub densify: Duration,
    /// The CPU splatting kernels' phases within `forward` and `backward`.
    pub kernels: KernelTimes,
    /// `forward` by part: the renders, then each loss term (named as in
    /// [`StepReport::terms`]; `multi_view` includes the neighbour's render).
    pub forward_parts: Vec<(&'static str, Duration)>,
}

impl StepTimes {
    /// The whole step.
    pub fn total(&self) -> Duration {
        self.forward + self.backward + self.gradients + self.adam + self.densify
    }
}

/// Adds phase by phase.
impl std::ops::AddAssign<&StepTimes> for StepTimes {
    fn add_assign(&mut self, other: &StepTimes) {
        self.forward += other.forward;
        self.backward += other.backward;
        self.gradients += other.gradients;
        self.adam += other.adam;
        self.densify += other.densify;
        self.kernels += &other.kernels;
        for (name, d) in &other.forward_parts {
            match self.forward_parts.iter_mut().find(|(n, _)| n == name) {
                Some(slot) => slot.1 += *d,
                None => self.forward_parts.push((name, *d)),
            }
        }
    }
}

/// The loss of one step before its backward pass.
pub struct Forward {
    /// The total loss.
    pub total: Tensor<1>,
    /// The weighted terms.
    pub terms: Vec<(&'static str, Tensor<1>)>,
    /// The renders of the step's view.
    pub renders: crate::model::Renders,
    /// Raster passes run (including the multi-view neighbour).
    pub passes: usize,
    /// Tile-splat pairs of those passes.
    pub tile_splats: u64,
    /// Wall time of each part of the forward pass (the renders, then each term's
    /// computation), in order.
    pub term_times: Vec<(&'static str, Duration)>,
    /// Training view index.
    pub view: usize,
    /// Whether the step is in stage 2.
    pub stage2: bool,
}

/// A model, its optimiser state and the training views.
pub struct Trainer {
    /// The configuration.
    pub(crate) config: TrainConfig,
    /// The model (autodiff leaves).
    pub(crate) model: Model,
    /// Training views on the device.
    pub(crate) views: Vec<ViewTensors>,
    /// Neighbours of each training view (multi-view term).
    pub(crate) neighbours: Vec<Vec<usize>>,
    /// Scene extent (position learning rate and densification scale with it).
    pub(crate) extent: f64,
    /// Steps run so far (the next step's index).
    pub(crate) step: usize,
    /// Run counters.
    pub(crate) counters: Counters,
    pub(crate) opt_surface: SetOptimizer,
    pub(crate) opt_interior: SetOptimizer,
    pub(crate) opt_light: SetOptimizer,
    pub(crate) stats_surface: DensifyStats,
    pub(crate) stats_interior: DensifyStats,
    pub(crate) device: Device,
}

impl Trainer {
    /// The configuration.
    pub fn config(&self) -> &TrainConfig {
        &self.config
    }

    /// Replaces the loss weights, e.g. to see how other terms would push a checkpoint's model;
    /// nothing else in the trainer's state depends on them. Weights the configuration's
    /// checks refuse are refused, and the trainer is left as it was.
    pub fn set_loss_weights(&mut self, weights: LossWeights) -> Result<(), ModelError> {
        let config = TrainConfig {
            weights,
            ..self.config.clone()
        };
        config.validate().map_err(ModelError::Config)?;
        self.config = config;
        Ok(())
    }

    /// The model (autodiff leaves).
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The training views on the device.
    pub fn views(&self) -> &[ViewTensors] {
        &self.views
    }

    /// The multi-view neighbours of each training view.
    pub fn neighbours(&self) -> &[Vec<usize>] {
        &self.neighbours
    }

    /// The scene extent the position learning rate and densification scale with.
    pub fn extent(&self) -> f64 {
        self.extent
    }

    /// Steps run so far: the index of the next step.
    pub fn steps_done(&self) -> usize {
        self.step
    }

    /// The run's counters.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The model, to change by hand (tests and tools).
    #[cfg(any(test, feature = "test-utils"))]
    pub fn model_mut(&mut self) -> &mut Model {
        &mut self.model
    }

    /// Moves the schedule to `step` without training (tests and tools; a checkpoint restores
    /// the step of its run).
    #[cfg(any(test, feature = "test-utils"))]
    pub fn seek(&mut self, step: usize) {
        self.step = step;
    }
}

impl std::fmt::Debug for Trainer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Trainer")
            .field("step", &self.step)
            .field("counts", &self.model.counts())
            .field("counters", &self.counters)
            .finish()
    }
}

/// Seeded generator for one purpose at one step.
pub fn step_rng(seed: u64, step: usize, purpose: u64) -> StdRng {
    let mut x = seed
        ^ (step as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ purpose.wrapping_mul(0xD1B5_4A32_D192_ED03);
    x ^= x >> 31;
    StdRng::seed_from_u64(x)
}

const RNG_INIT: u64 = 1;
const RNG_VIEW: u64 = 2;
const RNG_NEIGHBOUR: u64 = 3;

/// Reference pixels per step of the multi-view photometric term (PGSR samples about 6 % of
/// its pixels; this is 6 % of 256 x 256).
pub const NCC_PIXELS: usize = 4096;

/// Up to `count` of the pixels with a positive weight in `weights` (`[H * W]`, detached), drawn
/// without replacement, with their weights.
fn ncc_pixels(weights: Tensor<1>, count: usize, rng: &mut StdRng) -> Vec<(usize, f32)> {
    let all: Vec<(usize, f32)> = host_vec(weights)
        .into_iter()
        .enumerate()
        .filter(|(_, w)| *w > 0.0)
        .collect();
    if all.len() <= count {
        return all;
    }
    rand::seq::index::sample(rng, all.len(), count)
        .into_iter()
        .map(|k| all[k])
        .collect()
}

const RNG_DENSIFY: u64 = 4;
const RNG_INTERIOR: u64 = 5;
const RNG_NCC: u64 = 6;

impl Trainer {
    /// A new run: `views` on an autodiff `device`, `extent` the scene radius, the surface set
    /// started from `points` (see [`initial_points`]).
    pub fn new(
        config: TrainConfig,
        views: Vec<ViewTensors>,
        extent: f64,
        points: &[[f32; 3]],
        device: &Device,
    ) -> Result<Trainer, ModelError> {
        config.validate().map_err(ModelError::Config)?;
        if views.is_empty() {
            return Err(ModelError::Data("no training views".into()));
        }
        if !(extent.is_finite() && extent > 0.0) {
            return Err(ModelError::Config(format!(
                "scene extent must be positive, got {extent}"
            )));
        }
        let c = config.components;
        let mut rng = step_rng(config.seed, 0, RNG_INIT ^ 0xFF);
        let host = host_set_from_points(
            SetKind::Surface,
            points,
            c.sh_coeffs(),
            c.pbr,
            0.1,
            &mut rng,
        );
        let mean_dist2 = views
            .iter()
            .map(|v| v.camera.centre().iter().map(|x| x * x).sum::<f64>())
            .sum::<f64>()
            / views.len() as f64;
        let model = Model {
            components: c,
            surface: host.to_device(device),
            interior: None,
            log_light: c
                .pbr
                .then(|| scalar_param(mean_dist2.max(1e-6).ln(), device)),
            sh_degree: 0,
            blur_px2: config.blur_px2,
            compensate_blur: config.compensate_blur,
            surface_opacity_floor: config.surface_opacity_floor,
            plane_blur_px2: 0.0,
        };
        let cams: Vec<_> = views.iter().map(|v| v.camera.clone()).collect();
        let neighbours = neighbours(&cams, config.neighbour_max_angle_deg);
        let n = model.surface.len();
        Ok(Trainer {
            config,
            model,
            views,
            neighbours,
            extent,
            step: 0,
            counters: Counters::default(),
            opt_surface: SetOptimizer::default(),
            opt_interior: SetOptimizer::default(),
            opt_light: SetOptimizer::default(),
            stats_surface: DensifyStats::new(n),
            stats_interior: DensifyStats::new(0),
            device: device.clone(),
        })
    }

    /// Trains on `views` from now on: the same training views at another resolution (a
    /// coarse-to-fine schedule, [`TrainConfig::coarse_until`]). Each must show the same camera
    /// centre as the view it replaces, in the same order.
    pub fn set_views(&mut self, views: Vec<ViewTensors>) -> Result<(), ModelError> {
        if views.len() != self.views.len() {
            return Err(ModelError::Data(format!(
                "{} views replace {} training views",
                views.len(),
                self.views.len()
            )));
        }
        for (new, old) in views.iter().zip(&self.views) {
            let (a, b) = (new.camera.centre(), old.camera.centre());
            let d = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
            if d > 1e-4 * (1.0 + b.iter().map(|x| x.abs()).fold(0.0, f64::max)) {
                return Err(ModelError::Data(format!(
                    "view {} replaces {} from another camera centre",
                    new.name, old.name
                )));
            }
        }
        self.views = views;
        Ok(())
    }

    /// Whether `step` is in stage 2.
    pub fn is_stage2(&self, step: usize) -> bool {
        step >= self.config.stage2_start
    }

    /// The training view used at `step`: a seeded permutation per epoch (as 3DGS).
    pub fn view_for_step(&self, step: usize) -> usize {
        let n = self.views.len();
        let epoch = step / n;
        let mut perm: Vec<usize> = (0..n).collect();
        let mut rng = step_rng(self.config.seed, epoch, RNG_VIEW);
        for i in (1..n).rev() {
            let j = rng.random_range(0..=i);
            perm.swap(i, j);
        }
        perm[step % n]
    }

    /// lambda2 at `step`: linear from `single_view_start` at stage 2's start to
    /// `single_view_end` at the last step.
    pub fn lambda2(&self, step: usize) -> f64 {
        let w = &self.config.weights;
        let (s, e) = (self.config.stage2_start, self.config.iterations.max(1));
        let t = if e > s {
            (step.saturating_sub(s)) as f64 / (e - s) as f64
        } else {
            1.0
        };
        w.single_view_start + (w.single_view_end - w.single_view_start) * t.clamp(0.0, 1.0)
    }

    /// Position learning rate at `step` (exponential decay, times the extent).
    pub fn position_lr(&self, step: usize) -> f64 {
        let lr = &self.config.lr;
        let t = (step as f64 / self.config.iterations.max(1) as f64).clamp(0.0, 1.0);
        (lr.position_start.ln() * (1.0 - t) + lr.position_end.max(1e-30).ln() * t).exp()
            * self.extent
    }

    fn lr_for(&self, step: usize, kind: ParamKind) -> f64 {
        let lr = &self.config.lr;
        match kind {
            ParamKind::Means => self.position_lr(step),
            ParamKind::Rotations => lr.rotation,
            ParamKind::LogScales => lr.scale,
            ParamKind::Opacity => lr.opacity,
            ParamKind::ShDc => lr.sh_dc,
            ParamKind::ShRest => lr.sh_rest,
            ParamKind::BaseColour => lr.base_colour,
            ParamKind::Roughness => lr.roughness,
        }
    }

    /// Render options at `step` (without the spread moments, which only the training loss
    /// reads: [`Trainer::forward`] asks for them).
    pub fn render_options(&self, step: usize, track_offsets: bool) -> RenderOptions {
        RenderOptions {
            stage2: self.is_stage2(step),
            geometry: self.is_stage2(step),
            track_offsets,
            shading: ShadingParams {
                f0: self.config.f0,
                gamma: self.config.pbr_gamma,
                min_roughness: self.config.min_roughness,
                scatter_lambert: self.config.scatter_lambert,
                scatter_srgb: self.config.pbr_srgb_output && self.config.pbr_scatter_srgb,
            },
            pbr_srgb: self.config.pbr_srgb_output,
            spread: false,
        }
    }

    /// Adds the interior set (stage 2): points just inside the surface set, each moved from a
    /// random surface Gaussian against its normal as seen from the nearest training camera
    /// (which faces outwards on the visible surface) by 2 to 10 % of the extent.
    fn add_interior(&mut self) {
        let host = self.model.surface.to_host();
        let (means, _) = host.column(ParamKind::Means).expect("means");
        let (rots, _) = host.column(ParamKind::Rotations).expect("rotations");
        let (ls, _) = host.column(ParamKind::LogScales).expect("scales");
        let mut rng = step_rng(self.config.seed, self.step, RNG_INTERIOR);
        let centres: Vec<[f64; 3]> = self.views.iter().map(|v| v.camera.centre()).collect();
        let m = self.config.init_interior;
        let mut pts = Vec::with_capacity(m);
        for _ in 0..m {
            let i = rng.random_range(0..host.n);
            let mu: [f32; 3] = std::array::from_fn(|k| means[3 * i + k]);
            let q = &rots[4 * i..4 * i + 4];
            let s = &ls[3 * i..3 * i + 3];
            let axis = (0..3).min_by(|a, b| s[*a].total_cmp(&s[*b])).unwrap_or(0);
            let r = crate::densify::quat_matrix(q);
            let mut nrm = [r[0][axis], r[1][axis], r[2][axis]];
            let cam = centres
                .iter()
                .min_by(|a, b| {
                    let d = |c: &[f64; 3]| {
                        (0..3)
                            .map(|k| (c[k] - f64::from(mu[k])).powi(2))
                            .sum::<f64>()
                    };
                    d(a).total_cmp(&d(b))
                })
                .expect("views");
            let to_cam: f64 = (0..3)
                .map(|k| (cam[k] - f64::from(mu[k])) * f64::from(nrm[k]))
                .sum();
            if to_cam < 0.0 {
                nrm = nrm.map(|v| -v);
            }
            let depth = rng.random_range(0.02..0.1) * self.extent;
            pts.push(std::array::from_fn(|k| mu[k] - (depth as f32) * nrm[k]));
        }
        let c = self.config.components;
        let set =
            host_set_from_points(SetKind::Interior, &pts, c.sh_coeffs(), false, 0.1, &mut rng);
        self.stats_interior = DensifyStats::new(set.n);
        self.opt_interior = SetOptimizer::default();
        self.model.interior = Some(set.to_device(&self.device));
    }

    /// Prepares `step` (adds the interior set at stage 2, sets the SH degree) and computes its
    /// loss: the weighted terms, the renders and the raster passes run.
    pub fn forward(&mut self, step: usize) -> Result<Forward, ModelError> {
        let cfg = self.config.clone();
        let c = cfg.components;
        let stage2 = self.is_stage2(step);
        if stage2 && c.interior && self.model.interior.is_none() {
            self.add_interior();
        }
        self.model.sh_degree = ((step / cfg.sh_increase_every.max(1)) as u32).min(c.sh_degree);
        let vi = self.view_for_step(step);
        let view = self.views[vi].clone();
        let opts = RenderOptions {
            spread: cfg.weights.spread > 0.0,
            ..self.render_options(step, true)
        };
        let mut clock = Instant::now();
        let mut term_times: Vec<(&'static str, Duration)> = Vec::new();
        let r = self.model.render(&view.camera, &view.rays, opts)?;
        let mut lap = |name: &'static str| {
            let now = Instant::now();
            term_times.push((name, now - clock));
            clock = now;
        };
        lap("renders");
        let mut passes = r.passes;
        let mut tile_splats = r.tile_splats;
        let mut terms: Vec<(&'static str, Tensor<1>)> = Vec::new();
        // Adds a weighted term and times its computation.
        let mut add = |name: &'static str, term: Tensor<1>| {
            terms.push((name, term));
            lap(name);
        };
        let w = &cfg.weights;
        let photo_keep = match (&view.mask_edge_px, w.photometric_band) {
            (Some(edge), band) if band > 0 => Some(losses::outside_band(edge, f64::from(band))),
            _ => None,
        };
        let photometric = |render: Tensor<3>| match &photo_keep {
            Some(keep) => losses::photometric_masked(render, view.rgb.clone(), w.lambda_l1, keep),
            None => losses::photometric(render, view.rgb.clone(), w.lambda_l1),
        };
        add("c_sh", photometric(r.c_sh.clone()));
        if let Some(pbr) = &r.c_pbr {
            add("c_pbr", photometric(pbr.clone()));
        }
        let coverage = r
            .geometry
            .as_ref()
            .map_or(r.alpha_sh.clone(), |g| g.coverage.clone());
        if let (Some(mask), true) = (&view.mask, w.mask > 0.0) {
            let term = match (&view.mask_edge_px, w.mask_band) {
                _ if stage2 && w.mask_deficit_only => losses::mask_deficit(&coverage, mask),
                (Some(edge), band) if band > 0 && w.mask_band_hinge => {
                    losses::mask_l1_band_hinge(&coverage, mask, edge, f64::from(band))
                }
                (Some(edge), band) if band > 0 => {
                    losses::mask_l1_outside_band(&coverage, mask, edge, f64::from(band))
                }
                _ => losses::mask_l1(&coverage, mask),
            };
            add("mask", term * w.mask);
        }
        if stage2 && w.opacity_entropy > 0.0 {
            add(
                "opacity_entropy",
                losses::opacity_entropy(self.model.surface.req(ParamKind::Opacity))
                    * w.opacity_entropy,
            );
        }
        if w.opacity_l1 > 0.0 {
            add(
                "opacity_l1",
                losses::opacity_l1(self.model.surface.req(ParamKind::Opacity)) * w.opacity_l1,
            );
        }
        if w.flatten > 0.0 {
            add(
                "flatten",
                losses::flatten(&self.model.surface.scales()) * w.flatten,
            );
        }
        if let Some(g) = &r.geometry {
            let valid = valid_pixels(&g.coverage, view.mask.as_ref());
            if c.single_view {
                let l2 = self.lambda2(step);
                add(
                    "single_view",
                    losses::single_view(&g.depth, &g.normal, &view.rays, &valid, &view.edge_weight)
                        * l2,
                );
            }
            let every = cfg.multi_view_every;
            if c.multi_view && !self.neighbours[vi].is_empty() && step.is_multiple_of(every) {
                let mut rng = step_rng(cfg.seed, step, RNG_NEIGHBOUR);
                let list = &self.neighbours[vi];
                let ni = list[rng.random_range(0..list.len())];
                let nv = self.views[ni].clone();
                let ng = self.model.render_depth(&nv.camera, &nv.rays)?;
                passes += 1;
                tile_splats += ng.tile_splats;
                let valid_n = valid_pixels(&ng.coverage, nv.mask.as_ref());
                let mv = losses::multi_view(
                    &g.depth,
                    &view.rays,
                    &valid,
                    &view.camera,
                    &ng.depth,
                    &valid_n,
                    &nv.camera,
                    cfg.multi_view_max_error_px,
                );
                if w.multi_view_ncc > 0.0 {
                    let pixels = ncc_pixels(
                        mv.pixel_weights,
                        NCC_PIXELS,
                        &mut step_rng(cfg.seed, step, RNG_NCC),
                    );
                    let ncc = losses::multi_view_ncc(
                        &g.depth,
                        &g.normal,
                        &losses::grey(&view.rgb),
                        &view.camera,
                        &losses::grey(&nv.rgb),
                        &nv.camera,
                        &pixels,
                    );
                    add(
                        "multi_view_ncc",
                        ncc.loss * (w.multi_view_ncc * every as f64),
                    );
                }
                add("multi_view", mv.loss * (w.multi_view * every as f64));
            }
            if stage2 && w.front_depth > 0.0 {
                let front = self.model.detached().render_depth_crossing(
                    &view.camera,
                    &view.rays,
                    losses::FRONT_TRANSMITTANCE,
                )?;
                let weights = self.model.render_depth_weights(&view.camera, &view.rays)?;
                passes += 2;
                tile_splats += weights.tile_splats;
                let front_valid = valid
                    .clone()
                    .bool_and(front.coverage.greater_equal_elem(0.5));
                add(
                    "front_depth",
                    losses::front_depth(&weights.depth, &front.depth, view.camera.fx, &front_valid)
                        * w.front_depth,
                );
            }
            if stage2 && w.interior_front > 0.0 {
                // Reads the interior set detached: the term moves the surface only.
                let front = self
                    .model
                    .render_interior_front(&view.camera, losses::INTERIOR_FRONT_TRANSMITTANCE)?;
                if let Some(front) = front {
                    passes += 1;
                    add(
                        "interior_front",
                        losses::interior_front(&g.depth, &front, view.camera.fx, &valid)
                            * w.interior_front,
                    );
                }
            }
            let hull_on =
                w.hull_depth > 0.0 && step as f64 >= w.hull_depth_from * cfg.iterations as f64;
            if let (Some(hull), true) = (&view.hull_depth, hull_on) {
                add(
                    "hull_depth",
                    losses::hull_depth(
                        &g.depth,
                        hull,
                        view.hull_occluders.as_ref(),
                        view.camera.fx,
                        &valid,
                    ) * w.hull_depth,
                );
            }
            if let Some(spread) = &g.spread {
                add(
                    "spread",
                    losses::layer_spread(spread, &g.depth, view.camera.fx, &valid) * w.spread,
                );
            }
            if let (Some(int), true) = (&self.model.interior, w.interior > 0.0) {
                add(
                    "interior",
                    losses::interior_containment(
                        int.req(ParamKind::Means),
                        &view.camera,
                        &g.depth,
                        &valid,
                    ) * w.interior,
                );
            }
            if let (Some(scatter), true) = (&r.scatter, w.smooth_scatter > 0.0) {
                add(
                    "smooth_scatter",
                    losses::edge_aware_smoothness(scatter, &view.smooth_wx, &view.smooth_wy)
                        * w.smooth_scatter,
                );
            }
            if c.smoothness {
                if let Some(b) = &g.base {
                    add(
                        "smooth_base",
                        losses::edge_aware_smoothness(b, &view.smooth_wx, &view.smooth_wy)
                            * w.smooth_base,
                    );
                }
                if let Some(rough) = &g.roughness {
                    let [h, wd] = rough.dims();
                    add(
                        "smooth_roughness",
                        losses::edge_aware_smoothness(
                            &rough.clone().reshape([h, wd, 1]),
                            &view.smooth_wx,
                            &view.smooth_wy,
                        ) * w.smooth_roughness,
                    );
                }
            }
        }
        let total = terms
            .iter()
            .map(|(_, t)| t.clone())
            .reduce(|a, b| a + b)
            .expect("at least the photometric term");
        lap("sum");
        Ok(Forward {
            total,
            terms,
            term_times,
            renders: r,
            passes,
            tile_splats,
            view: vi,
            stage2,
        })
    }

    /// Gradient magnitudes (sum of absolute values) of every parameter tensor for the loss of
    /// the current step, without updating anything: `(set, parameter, |grad|_1)`.
    pub fn gradient_norms(&mut self) -> Result<Vec<(String, String, f64)>, ModelError> {
        let f = self.forward(self.step)?;
        let grads = f.total.backward();
        let mut out = Vec::new();
        let sets = std::iter::once(&self.model.surface).chain(self.model.interior.as_ref());
        for set in sets {
            for (k, t) in &set.params {
                let g = t
                    .grad(&grads)
                    .map_or(0.0, |g| g.abs().sum().into_scalar::<f64>());
                out.push((set.kind.name().to_string(), k.name().to_string(), g));
            }
        }
        if let Some(l) = &self.model.log_light {
            let g = l
                .grad(&grads)
                .map_or(0.0, |g| g.abs().sum().into_scalar::<f64>());
            out.push(("light".into(), "log_intensity".into(), g));
        }
        Ok(out)
    }

    /// Runs one step (render, loss, backward, Adam, densification on schedule).
    pub fn step(&mut self) -> Result<StepReport, ModelError> {
        let step = self.step;
        let cfg = self.config.clone();
        let kernels0 = kernel_times();
        let t0 = Instant::now();
        let Forward {
            total,
            terms,
            renders: r,
            passes,
            tile_splats,
            view: vi,
            stage2,
            term_times,
        } = self.forward(step)?;
        let view = self.views[vi].clone();
        let loss = total.clone().into_scalar::<f64>();
        let term_values: Vec<(&'static str, f64)> = terms
            .iter()
            .map(|(n, t)| (*n, t.clone().into_scalar::<f64>()))
            .collect();
        self.counters.passes += passes;
        self.counters.tile_splats += tile_splats;
        let mut times = StepTimes {
            forward: t0.elapsed(),
            forward_parts: term_times,
            ..StepTimes::default()
        };
        let t0 = Instant::now();
        let grads = total.backward();
        times.backward = t0.elapsed();
        let t0 = Instant::now();
        let collect = |set: &GaussianSet| -> HashMap<ParamKind, Tensor<2>> {
            set.params
                .iter()
                .filter_map(|(k, t)| t.grad(&grads).map(|g| (*k, g)))
                .collect()
        };
        let g_surf = collect(&self.model.surface);
        let g_int = self.model.interior.as_ref().map(collect);
        let g_light = self.model.log_light.as_ref().and_then(|l| l.grad(&grads));
        let finite = |m: &HashMap<ParamKind, Tensor<2>>| {
            m.values()
                .all(|g| g.clone().sum().into_scalar::<f64>().is_finite())
        };
        let all_finite = loss.is_finite()
            && finite(&g_surf)
            && g_int.as_ref().is_none_or(finite)
            && g_light
                .as_ref()
                .is_none_or(|g| g.clone().sum().into_scalar::<f64>().is_finite());
        let mut report = StepReport {
            step,
            stage: if stage2 { 2 } else { 1 },
            view: vi,
            loss,
            terms: term_values,
            passes,
            tile_splats,
            skipped: !all_finite,
            densified: None,
            counts: self.model.counts(),
            times,
        };
        if !all_finite {
            self.counters.skipped_steps += 1;
            self.step += 1;
            report.times.gradients = t0.elapsed();
            report.times.kernels = kernel_times().since(&kernels0);
            return Ok(report);
        }
        // Densification statistics: read back only while a densification can still use them.
        let (w, h) = view.size();
        let densifies_later = step < self.config.densify.end;
        for (offsets, radii, stats) in [
            (
                &r.surface_offsets,
                &r.surface_radii,
                &mut self.stats_surface,
            ),
            (
                &r.interior_offsets,
                &r.interior_radii,
                &mut self.stats_interior,
            ),
        ] {
            if densifies_later && let Some(g) = offsets.as_ref().and_then(|o| o.grad(&grads)) {
                stats.add(&host_vec(g), radii, w, h);
            }
        }
        report.times.gradients = t0.elapsed();
        // Adam.
        let t0 = Instant::now();
        let rates: HashMap<ParamKind, f64> = ParamKind::ALL
            .iter()
            .map(|k| (*k, self.lr_for(step, *k)))
            .collect();
        let lr = |k: ParamKind| rates[&k];
        self.model.surface = self
            .opt_surface
            .step(self.model.surface.clone(), &g_surf, &lr);
        if let (Some(int), Some(g)) = (self.model.interior.clone(), g_int) {
            self.model.interior = Some(self.opt_interior.step(int, &g, &lr));
        }
        if let (Some(l), Some(g)) = (self.model.log_light.clone(), g_light) {
            let set = GaussianSet {
                kind: SetKind::Surface,
                params: vec![(ParamKind::Opacity, l)],
            };
            let grads = HashMap::from([(ParamKind::Opacity, g)]);
            let light_lr = cfg.lr.light;
            let out = self.opt_light.step(set, &grads, &|_| light_lr);
            self.model.log_light = out.params.into_iter().next().map(|(_, t)| t);
        }
        report.times.adam = t0.elapsed();
        let t0 = Instant::now();
        report.densified = self.maybe_densify(step)?;
        report.times.densify = t0.elapsed();
        report.times.kernels = kernel_times().since(&kernels0);
        report.counts = self.model.counts();
        self.step += 1;
        Ok(report)
    }

    /// The device the run is on.
    pub fn device(&self) -> &Device {
        &self.device
    }
}

/// Pixels whose depth is trusted: the mask (when present) and surface coverage above 0.5.
pub fn valid_pixels(coverage: &Tensor<2>, mask: Option<&Tensor<2>>) -> Tensor<2, Bool> {
    let cov = coverage.clone().detach().greater_elem(0.5);
    match mask {
        Some(m) => cov.bool_and(m.clone().greater_equal_elem(0.5)),
        None => cov,
    }
}
