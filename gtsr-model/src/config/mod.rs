//! Every setting of the model and its training: components (what to leave out), loss weights,
//! learning rates, schedule and densification. Serde-serialisable so a run can record and
//! reload the resolved configuration, and [`clap::Args`] so a front end can flatten the same
//! structs into its command line.
//!
//! On the command line every setting's argument id is its path in a run's `config.json`
//! (`train.weights.mask` for `--mask-weight`), so a front end can start from defaults that
//! depend on the scene or from a saved configuration and overlay only what the user gave
//! (`gtsr-train` does this with [`clap::ArgMatches::value_source`]). The defaults shown by
//! `--help` are those of [`TrainConfig::for_iterations`]; where a default depends on the run
//! (the schedule, the caps, the preset's components) the help says so instead.

use clap::ArgAction;
use gtsr_data::parse::{
    parse_count, parse_non_negative, parse_open_unit, parse_positive, parse_unit,
};
use serde::{Deserialize, Serialize};

fn every_step() -> usize {
    1
}

/// Which parts of the method are switched on. A disabled component allocates no parameters
/// and runs no raster pass. On the command line each overrides what the preset chose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct Components {
    /// The interior Gaussian set (scattering colour; C_SH blends it with the surface set).
    #[arg(long = "interior", id = "train.components.interior", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub interior: bool,
    /// Surface opacity times the Schlick Fresnel term in C_SH.
    #[arg(long = "fresnel", id = "train.components.fresnel", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub fresnel: bool,
    /// The deferred C_PBR render (material maps, scattering map, co-located light).
    #[arg(long = "pbr", id = "train.components.pbr", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub pbr: bool,
    /// PGSR's multi-view geometric term (renders a neighbour view's depth every step).
    #[arg(long = "multi-view", id = "train.components.multi_view", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub multi_view: bool,
    /// PGSR's single-view depth-normal term.
    #[arg(long = "single-view", id = "train.components.single_view", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub single_view: bool,
    /// Edge-aware smoothness of the roughness and base-colour maps (needs `pbr`).
    #[arg(long = "smoothness", id = "train.components.smoothness", value_name = "BOOL", action = ArgAction::Set, default_value_t = true, hide_default_value = true)]
    pub smoothness: bool,
    /// Largest spherical-harmonics degree (0 to 3); grown during training.
    #[arg(long = "sh-degree", id = "train.components.sh_degree", value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub sh_degree: u32,
}

impl Components {
    /// The paper's full model.
    pub const FULL: Components = Components {
        interior: true,
        fresnel: true,
        pbr: true,
        multi_view: true,
        single_view: true,
        smoothness: true,
        sh_degree: 3,
    };

    /// Checks the switches for combinations that cannot work, returning the reason.
    pub fn validate(&self) -> Result<(), String> {
        if self.sh_degree > 3 {
            return Err(format!("sh_degree must be 0..=3, got {}", self.sh_degree));
        }
        if self.smoothness && !self.pbr {
            return Err("smoothness regularises the PBR material maps: it needs pbr".into());
        }
        Ok(())
    }

    /// Number of SH coefficients per colour channel.
    pub fn sh_coeffs(&self) -> usize {
        ((self.sh_degree + 1) * (self.sh_degree + 1)) as usize
    }
}

/// The largest distance [`crate::views::mask_edge_distance`] reports: the mask and photometric
/// bands must be narrower.
pub const MASK_EDGE_CAP: usize = 8;

/// [`LossWeights::hull_depth`] when every training view has a mask ([`TrainConfig::for_views`]).
pub const DEFAULT_HULL_DEPTH_WEIGHT: f64 = 0.03;

/// Loss weights (names follow the paper). The terms that are not in the paper and were not
/// kept on by default are set in a configuration file only (`--config`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// lambda1: weight of L1 in `lambda1 L1 + (1 - lambda1) (1 - SSIM)`, on each render.
    #[arg(long = "l1-weight", id = "train.weights.lambda_l1", value_name = "W", default_value_t = LossWeights::default().lambda_l1, value_parser = parse_unit::<f64>)]
    pub lambda_l1: f64,
    /// lambda2 at the start of stage 2 (rises linearly to `single_view_end`).
    #[arg(long = "single-view-weight-start", id = "train.weights.single_view_start", value_name = "W", default_value_t = LossWeights::default().single_view_start, value_parser = parse_non_negative::<f64>)]
    pub single_view_start: f64,
    /// lambda2 at the end of training.
    #[arg(long = "single-view-weight-end", id = "train.weights.single_view_end", value_name = "W", default_value_t = LossWeights::default().single_view_end, value_parser = parse_non_negative::<f64>)]
    pub single_view_end: f64,
    /// lambda3: multi-view geometric term.
    #[arg(long = "multi-view-weight", id = "train.weights.multi_view", value_name = "W", default_value_t = LossWeights::default().multi_view, value_parser = parse_non_negative::<f64>)]
    pub multi_view: f64,
    /// PGSR's multi-view photometric consistency ([`crate::losses::multi_view_ncc`]: `1 - cc^2`
    /// of 7x7 grey patches carried into the multi-view term's neighbour by each pixel's
    /// rendered plane), on the steps the multi-view term runs, weighted as it is. The GTSR
    /// paper leaves it out (translucent colour changes between views); 0: off.
    #[serde(default)]
    #[arg(long = "multi-view-ncc-weight", id = "train.weights.multi_view_ncc", value_name = "W", default_value_t = LossWeights::default().multi_view_ncc, value_parser = parse_non_negative::<f64>)]
    pub multi_view_ncc: f64,
    /// lambda4: interior containment.
    #[arg(long = "interior-weight", id = "train.weights.interior", value_name = "W", default_value_t = LossWeights::default().interior, value_parser = parse_non_negative::<f64>)]
    pub interior: f64,
    /// lambda5: roughness smoothness.
    #[arg(long = "roughness-smoothness-weight", id = "train.weights.smooth_roughness", value_name = "W", default_value_t = LossWeights::default().smooth_roughness, value_parser = parse_non_negative::<f64>)]
    pub smooth_roughness: f64,
    /// lambda6: base-colour smoothness.
    #[arg(long = "base-smoothness-weight", id = "train.weights.smooth_base", value_name = "W", default_value_t = LossWeights::default().smooth_base, value_parser = parse_non_negative::<f64>)]
    pub smooth_base: f64,
    /// Flattening: mean smallest scale of the surface set.
    #[arg(long = "flatten-weight", id = "train.weights.flatten", value_name = "W", default_value_t = LossWeights::default().flatten, value_parser = parse_non_negative::<f64>)]
    pub flatten: f64,
    /// L1 between the surface set's alpha and the mask (when the data has masks). Default: 1
    /// when every training view has a mask, 0.1 otherwise.
    #[arg(long = "mask-weight", id = "train.weights.mask", value_name = "W", default_value_t = LossWeights::default().mask, value_parser = parse_non_negative::<f64>, hide_default_value = true)]
    pub mask: f64,
    /// Layer spread (not in the paper; 0, off, by default): the mean over the valid pixels of
    /// the blend-weighted standard deviation of the depths at which the surface splats cross
    /// the pixel's ray, in pixels (see [`crate::losses::layer_spread`]). 2DGS's depth
    /// distortion in another form: it asks the surface set for one layer per pixel instead of
    /// a stack of faint ones.
    #[serde(default)]
    #[arg(skip)]
    pub spread: f64,
    /// Opacity binarisation of the surface set in stage 2 (not in the paper): the mean binary
    /// entropy of the surface opacities ([`crate::losses::opacity_entropy`]), which pushes
    /// each towards 0 or 1, so the surface ends one opaque layer rather than a stack of faint
    /// ones whose blended depth lies behind the surface.
    #[serde(default)]
    #[arg(skip)]
    pub opacity_entropy: f64,
    /// In stage 2 the mask term counts only missing coverage inside the mask
    /// ([`crate::losses::mask_deficit`]), not coverage spilling past it, which pulls the
    /// surface Gaussians inward (not in the paper; off by default).
    #[serde(default)]
    #[arg(skip)]
    pub mask_deficit_only: bool,
    /// The mask term leaves out the pixels within this many pixels of each view's silhouette
    /// ([`crate::losses::mask_l1_outside_band`]; 0: every pixel counts, as the paper).
    #[serde(default)]
    #[arg(long = "mask-band", id = "train.weights.mask_band", value_name = "PX", default_value_t = LossWeights::default().mask_band)]
    pub mask_band: u32,
    /// With [`LossWeights::mask_band`], the band's pixels keep a hinge at 0.5 instead of being
    /// left out ([`crate::losses::mask_l1_band_hinge`]): the rendered silhouette must cross 0.5
    /// between the same pixel centres as the mask, at any edge width (not in the paper; off
    /// by default).
    #[serde(default)]
    #[arg(skip)]
    pub mask_band_hinge: bool,
    /// The photometric terms (C_SH and C_PBR) leave out the pixels within this many pixels of
    /// each view's silhouette as well ([`crate::losses::photometric_masked`]; 0: every pixel
    /// counts, as the paper; needs masks).
    #[serde(default)]
    #[arg(skip)]
    pub photometric_band: u32,
    /// Stage 2: the weight of the front-layer depth term ([`crate::losses::front_depth`]: the
    /// blended depth, differentiated through the surface opacities only, against the depth
    /// where the surface set's transmittance first falls to 0.9; not in the paper, 0: off).
    #[serde(default)]
    #[arg(skip)]
    pub front_depth: f64,
    /// Stage 2: the weight of the interior-front term ([`crate::losses::interior_front`]: the
    /// surface set's blended depth pulled to the interior set's front where that lies more
    /// than [`crate::losses::INTERIOR_FRONT_BAND`] footprints behind it; not in the paper, 0:
    /// off). One more host render of the interior set per step.
    #[serde(default)]
    #[arg(skip)]
    pub interior_front: f64,
    /// Opacity sparsity of the surface set, both stages (not in the paper; 3DGS-MCMC's
    /// regulariser): this weight times the mean surface opacity
    /// ([`crate::losses::opacity_l1`]). It fades the surface Gaussians that no other term
    /// needs, such as the layers hidden behind the front of the surface (0: off).
    #[serde(default)]
    #[arg(skip)]
    pub opacity_l1: f64,
    /// Stage 2: edge-aware smoothness of C_PBR's scattering map
    /// ([`crate::losses::edge_aware_smoothness`], the material maps' regulariser; not in the
    /// paper, 0: off). Read with [`TrainConfig::scatter_lambert`], it asks the smooth part of
    /// the shading to come from the lit lobe `n . v` rather than from the interior colours:
    /// reflectance piecewise smooth, shading in the normals (the intrinsic-image prior).
    #[serde(default)]
    #[arg(skip)]
    pub smooth_scatter: f64,
    /// Stage 2: the surface set's blended depth against the masks' bound's own depth, where the
    /// two lie within 3 footprints of each other (not in the paper;
    /// [`crate::losses::hull_depth`]). Default: 0.03 when every training view has a
    /// mask, 0 (off) otherwise. Needs each view's [`crate::views::ViewTensors::hull_depth`].
    #[serde(default)]
    #[arg(long = "hull-depth-weight", id = "train.weights.hull_depth", value_name = "W", default_value_t = LossWeights::default().hull_depth, value_parser = parse_non_negative::<f64>, hide_default_value = true)]
    pub hull_depth: f64,
    /// With [`LossWeights::hull_depth`]: the masks' bound gives no depth at the pixels where
    /// its own depth jumps by more than this many footprints to a 4-neighbour or a neighbour
    /// misses it (its outline and occluding edges, where a pixel's blend mixes two surfaces);
    /// 0: every pixel the bound covers counts.
    #[serde(default)]
    #[arg(skip)]
    pub hull_depth_edges: f64,
    /// With [`LossWeights::hull_depth`]: a pixel just behind an occluding edge of the masks'
    /// bound (a 4-neighbour's bound depth lies more than this many footprints in front of its
    /// own) also counts where the blended depth reads that neighbour's depth, pulled to its own:
    /// the nearer surface must not spill past the edge (0: off).
    #[serde(default)]
    #[arg(skip)]
    pub hull_depth_occluders: f64,
    /// With [`LossWeights::hull_depth`]: the share of the run's steps before which the term is
    /// off (0: it runs from the start of stage 2). Stage 2 starts with the surface set on the
    /// masks' bound everywhere, over the concavities the masks cannot see too, and the term
    /// holds it there; started later, it finds the surface set already behind the bound where
    /// the images put it there, beyond the term's band.
    #[serde(default)]
    #[arg(skip)]
    pub hull_depth_from: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights {
            lambda_l1: 0.2,
            single_view_start: 0.0025,
            single_view_end: 0.9,
            multi_view: 0.01,
            multi_view_ncc: 0.0,
            interior: 0.01,
            smooth_roughness: 0.01,
            smooth_base: 0.01,
            flatten: 100.0,
            mask: 0.1,
            spread: 0.0,
            opacity_entropy: 0.0,
            mask_deficit_only: false,
            mask_band: 0,
            mask_band_hinge: false,
            photometric_band: 0,
            front_depth: 0.0,
            interior_front: 0.0,
            opacity_l1: 0.0,
            smooth_scatter: 0.0,
            hull_depth: 0.0,
            hull_depth_edges: 0.0,
            hull_depth_occluders: 0.0,
            hull_depth_from: 0.0,
        }
    }
}

/// Adam learning rates per parameter (PGSR/3DGS values; positions scale with the scene).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct LearningRates {
    /// Position rate at step 0, times the scene extent.
    #[arg(long = "lr-position-start", id = "train.lr.position_start", value_name = "RATE", default_value_t = LearningRates::default().position_start, value_parser = parse_non_negative::<f64>)]
    pub position_start: f64,
    /// Position rate at the last step, times the scene extent (exponential decay between).
    ///
    /// A tenth of the start rather than 3DGS's hundredth, so that stage 2's geometric terms
    /// can still move the surface out to where the depth says it is.
    #[arg(long = "lr-position-end", id = "train.lr.position_end", value_name = "RATE", default_value_t = LearningRates::default().position_end, value_parser = parse_non_negative::<f64>)]
    pub position_end: f64,
    /// SH DC coefficients.
    #[arg(long = "lr-sh-dc", id = "train.lr.sh_dc", value_name = "RATE", default_value_t = LearningRates::default().sh_dc, value_parser = parse_non_negative::<f64>)]
    pub sh_dc: f64,
    /// Higher SH coefficients.
    #[arg(long = "lr-sh-rest", id = "train.lr.sh_rest", value_name = "RATE", default_value_t = LearningRates::default().sh_rest, value_parser = parse_non_negative::<f64>)]
    pub sh_rest: f64,
    /// Opacity logits.
    #[arg(long = "lr-opacity", id = "train.lr.opacity", value_name = "RATE", default_value_t = LearningRates::default().opacity, value_parser = parse_non_negative::<f64>)]
    pub opacity: f64,
    /// Log-scales.
    #[arg(long = "lr-scale", id = "train.lr.scale", value_name = "RATE", default_value_t = LearningRates::default().scale, value_parser = parse_non_negative::<f64>)]
    pub scale: f64,
    /// Quaternions.
    #[arg(long = "lr-rotation", id = "train.lr.rotation", value_name = "RATE", default_value_t = LearningRates::default().rotation, value_parser = parse_non_negative::<f64>)]
    pub rotation: f64,
    /// Base colour logits.
    #[arg(long = "lr-base-colour", id = "train.lr.base_colour", value_name = "RATE", default_value_t = LearningRates::default().base_colour, value_parser = parse_non_negative::<f64>)]
    pub base_colour: f64,
    /// Roughness logits.
    #[arg(long = "lr-roughness", id = "train.lr.roughness", value_name = "RATE", default_value_t = LearningRates::default().roughness, value_parser = parse_non_negative::<f64>)]
    pub roughness: f64,
    /// Log light intensity.
    #[arg(long = "lr-light", id = "train.lr.light", value_name = "RATE", default_value_t = LearningRates::default().light, value_parser = parse_non_negative::<f64>)]
    pub light: f64,
}

impl Default for LearningRates {
    fn default() -> Self {
        LearningRates {
            position_start: 1.6e-4,
            position_end: 1.6e-5,
            sh_dc: 2.5e-3,
            sh_rest: 2.5e-3 / 20.0,
            opacity: 0.05,
            scale: 0.005,
            rotation: 0.001,
            base_colour: 0.01,
            roughness: 0.01,
            light: 0.01,
        }
    }
}

/// Densification, pruning and opacity reset (applied to each set separately). The schedule's
/// defaults scale with the run's length as PGSR's 30k-step one ([`TrainConfig::for_iterations`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct DensifyConfig {
    /// First step that densifies. Default: 1/60 of the run.
    #[arg(long = "densify-start", id = "train.densify.start", value_name = "STEP", default_value_t = DensifyConfig::default().start, value_parser = clap::value_parser!(usize), hide_default_value = true)]
    pub start: usize,
    /// Last step that densifies. Default: half the run.
    #[arg(long = "densify-end", id = "train.densify.end", value_name = "STEP", default_value_t = DensifyConfig::default().end, value_parser = clap::value_parser!(usize), hide_default_value = true)]
    pub end: usize,
    /// Densify every this many steps. Default: 1/300 of the run, at least 10.
    #[arg(long = "densify-every", id = "train.densify.every", value_name = "STEPS", default_value_t = DensifyConfig::default().every, value_parser = parse_count, hide_default_value = true)]
    pub every: usize,
    /// Mean screen-space gradient threshold, in NDC units as 3DGS (`|dL/d mean2d| * W / 2`).
    #[arg(long = "densify-grad-threshold", id = "train.densify.grad_threshold", value_name = "G", default_value_t = DensifyConfig::default().grad_threshold, value_parser = parse_non_negative::<f64>)]
    pub grad_threshold: f64,
    /// Gaussians larger than this fraction of the scene extent are split, smaller ones cloned.
    #[arg(long = "percent-dense", id = "train.densify.percent_dense", value_name = "F", default_value_t = DensifyConfig::default().percent_dense, value_parser = parse_non_negative::<f64>)]
    pub percent_dense: f64,
    /// Prune below this opacity.
    #[arg(long = "prune-opacity", id = "train.densify.min_opacity", value_name = "A", default_value_t = DensifyConfig::default().min_opacity, value_parser = parse_unit::<f64>)]
    pub min_opacity: f64,
    /// Reset opacities to at most 0.01 every this many steps (0: never), while densification
    /// still runs. Default: a tenth of the run.
    ///
    /// See [`DensifyConfig::resets_after`].
    #[arg(long = "opacity-reset-every", id = "train.densify.opacity_reset_every", value_name = "STEPS", default_value_t = DensifyConfig::default().opacity_reset_every, value_parser = clap::value_parser!(usize), hide_default_value = true)]
    pub opacity_reset_every: usize,
    /// No opacity reset at or after this step. Default: the end of densification.
    ///
    /// See [`DensifyConfig::resets_after`].
    #[serde(default = "default_reset_until")]
    #[arg(long = "opacity-reset-until", id = "train.densify.reset_until", value_name = "STEP", default_value_t = DensifyConfig::default().reset_until, value_parser = clap::value_parser!(usize), hide_default_value = true)]
    pub reset_until: usize,
    /// Cap on the surface set (densification stops growing it past this). Default: three per
    /// pixel of a view (10,000 to 65,536).
    #[arg(long = "max-surface", id = "train.densify.max_surface", value_name = "N", default_value_t = DensifyConfig::default().max_surface, value_parser = parse_count, hide_default_value = true)]
    pub max_surface: usize,
    /// Cap on the interior set. Default: one per pixel of a view (4,000 to 32,768).
    #[arg(long = "max-interior", id = "train.densify.max_interior", value_name = "N", default_value_t = DensifyConfig::default().max_interior, value_parser = parse_count, hide_default_value = true)]
    pub max_interior: usize,
    /// PGSR's multi-view trim every this many steps while densification runs (0: never):
    /// prunes the surface Gaussians that too few training views observe.
    ///
    /// PGSR trims every 1000 of 30000 steps. The surface Gaussians observed in fewer than
    /// [`Self::trim_min_views`] training views are pruned, where observed means blended at some
    /// pixel while the transmittance in front is above [`Self::trim_transmittance`]
    /// ([`crate::model::Model::observed_surface`]). It brings the depth closer to the surface but
    /// costs image quality on strongly scattering objects (`docs/log/2026-12-07-model-readme-lab-notes.md`).
    #[serde(default)]
    #[arg(long = "trim-every", id = "train.densify.trim_every", value_name = "STEPS", default_value_t = DensifyConfig::default().trim_every, value_parser = clap::value_parser!(usize))]
    pub trim_every: usize,
    /// Views in which a surface Gaussian must be observed to survive the trim.
    #[serde(default = "default_trim_min_views")]
    #[arg(long = "trim-min-views", id = "train.densify.trim_min_views", value_name = "N", default_value_t = DensifyConfig::default().trim_min_views, value_parser = parse_count)]
    pub trim_min_views: usize,
    /// Transmittance above which a splat counts as observed by the trim (the front layers).
    ///
    /// PGSR's 0.5 keeps the splats up to the median depth, but with a faint surface set the
    /// median lies deep inside the object, and 0.5 spares the deep layers that bias the depth
    /// (`docs/log/2026-12-07-model-readme-lab-notes.md`).
    #[serde(default = "default_trim_transmittance")]
    #[arg(long = "trim-transmittance", id = "train.densify.trim_transmittance", value_name = "T", default_value_t = DensifyConfig::default().trim_transmittance, value_parser = parse_open_unit::<f64>)]
    pub trim_transmittance: f64,
    /// Moves the surface Gaussians hidden behind the surface set's front into the interior
    /// set every this many steps of stage 2, to the end of the run (0: never).
    ///
    /// A surface Gaussian is hidden when fewer than [`Self::demote_min_views`] training views
    /// observe it: blend it at some pixel while the transmittance in front is above
    /// [`Self::demote_transmittance`] ([`crate::model::Model::observed_surface`]). Stage 1 fits the
    /// translucent glow with the surface set alone, as a stack of layers; the layers behind
    /// the front are what the interior set models, and they keep their parameters there.
    /// The trim prunes the same Gaussians instead.
    #[serde(default)]
    #[arg(long = "demote-every", id = "train.densify.demote_every", value_name = "STEPS", default_value_t = DensifyConfig::default().demote_every, value_parser = clap::value_parser!(usize))]
    pub demote_every: usize,
    /// Views in which a surface Gaussian must be observed to stay in the surface set.
    #[serde(default = "default_trim_min_views")]
    #[arg(long = "demote-min-views", id = "train.densify.demote_min_views", value_name = "N", default_value_t = DensifyConfig::default().demote_min_views, value_parser = parse_count)]
    pub demote_min_views: usize,
    /// Transmittance above which a surface splat counts as observed by the demotion.
    #[serde(default = "default_trim_transmittance")]
    #[arg(long = "demote-transmittance", id = "train.densify.demote_transmittance", value_name = "T", default_value_t = DensifyConfig::default().demote_transmittance, value_parser = parse_open_unit::<f64>)]
    pub demote_transmittance: f64,
}

fn default_reset_until() -> usize {
    usize::MAX
}

fn default_trim_min_views() -> usize {
    2
}

fn default_trim_transmittance() -> f64 {
    0.9
}

impl DensifyConfig {
    /// Whether the opacities are reset after the step that makes `done` steps in all: every
    /// [`Self::opacity_reset_every`] steps strictly before [`Self::end`], as 3DGS does, and
    /// before [`Self::reset_until`]. A reset at the end itself would leave every Gaussian at
    /// opacity 0.01 with no pruning to follow, and the layers that pruning removes after the
    /// other resets would all grow back.
    pub fn resets_after(&self, done: usize) -> bool {
        self.opacity_reset_every > 0
            && done.is_multiple_of(self.opacity_reset_every)
            && done < self.end
            && done < self.reset_until
    }

    /// Whether the multi-view trim runs after the step that makes `done` steps in all: every
    /// [`Self::trim_every`] steps from [`Self::start`] while densification runs (PGSR: every
    /// 1000 of 30000 steps, before the end of densification).
    pub fn trims_after(&self, done: usize) -> bool {
        self.trim_every > 0
            && done >= self.start
            && done.is_multiple_of(self.trim_every)
            && done < self.end
    }

    /// Whether hidden surface Gaussians move to the interior set after the step that makes
    /// `done` steps in all, in a run whose stage 2 starts at `stage2_start`: every
    /// [`Self::demote_every`] steps of stage 2, and once right where it starts.
    pub fn demotes_after(&self, done: usize, stage2_start: usize) -> bool {
        self.demote_every > 0
            && done > stage2_start
            && (done - stage2_start - 1).is_multiple_of(self.demote_every)
    }
}

impl Default for DensifyConfig {
    fn default() -> Self {
        DensifyConfig {
            start: 500,
            end: 15_000,
            every: 100,
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            min_opacity: 0.005,
            opacity_reset_every: 3000,
            reset_until: 15_000,
            max_surface: 200_000,
            max_interior: 50_000,
            trim_every: 0,
            trim_min_views: default_trim_min_views(),
            trim_transmittance: default_trim_transmittance(),
            demote_every: 0,
            demote_min_views: default_trim_min_views(),
            demote_transmittance: default_trim_transmittance(),
        }
    }
}

/// How the surface set starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Init {
    /// Uniform random points in a ball (the paper: COLMAP fails on textureless objects).
    Random,
    /// Random points kept only where every training mask covers their projection.
    MaskCarved,
    /// Points on the boundary of the mask-carved volume (the masks' visual hull).
    HullSurface,
}

/// The largest default cap on the surface set ([`TrainConfig::for_views`]).
pub const MAX_SURFACE: usize = 65_536;
/// The largest default cap on the interior set ([`TrainConfig::for_views`]).
pub const MAX_INTERIOR: usize = 32_768;

/// Everything that defines a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Components in use (already resolved from a preset).
    #[command(flatten, next_help_heading = "Components (default: from --preset)")]
    pub components: Components,
    /// Total steps.
    #[arg(skip)]
    pub iterations: usize,
    /// First step of stage 2 (interior set and geometric terms); before it only the surface
    /// set is trained, photometrically. Default: 7/30 of the run.
    #[arg(long = "stage2-start", id = "train.stage2_start", value_name = "STEP", default_value_t = 0, value_parser = clap::value_parser!(usize), hide_default_value = true, help_heading = "Training")]
    pub stage2_start: usize,
    /// Add one SH degree every this many steps. Default: 1/30 of the run.
    #[arg(long = "sh-increase-every", id = "train.sh_increase_every", value_name = "STEPS", default_value_t = 1, value_parser = parse_count, hide_default_value = true, help_heading = "Training")]
    pub sh_increase_every: usize,
    /// Loss weights.
    #[command(flatten, next_help_heading = "Loss weights")]
    pub weights: LossWeights,
    /// Learning rates.
    #[command(flatten, next_help_heading = "Learning rates")]
    pub lr: LearningRates,
    /// Densification.
    #[command(flatten, next_help_heading = "Densification")]
    pub densify: DensifyConfig,
    /// Surface initialisation. Default: mask-carved when every training view has a mask,
    /// random (the paper) otherwise.
    #[arg(long = "init", id = "train.init", value_name = "INIT", value_enum, default_value_t = Init::Random, hide_default_value = true, help_heading = "Training")]
    pub init: Init,
    /// Number of initial surface Gaussians. Default: one per pixel of a view (2,000 to 20,000).
    #[arg(long = "init-surface", id = "train.init_surface", value_name = "N", default_value_t = 1, value_parser = parse_count, hide_default_value = true, help_heading = "Training")]
    pub init_surface: usize,
    /// Number of interior Gaussians added at stage 2. Default: one per two pixels of a view
    /// (1,000 to 10,000).
    #[arg(long = "init-interior", id = "train.init_interior", value_name = "N", default_value_t = 1, value_parser = parse_count, hide_default_value = true, help_heading = "Training")]
    pub init_interior: usize,
    /// Radius of the initial ball (scene units; the data loaders normalise scenes).
    #[arg(long = "init-radius", id = "train.init_radius", value_name = "R", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).init_radius, value_parser = parse_positive::<f64>, help_heading = "Training")]
    pub init_radius: f64,
    /// gamma: weight of the diffuse term in C_PBR.
    #[arg(long = "pbr-gamma", id = "train.pbr_gamma", value_name = "G", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).pbr_gamma, value_parser = parse_non_negative::<f64>, help_heading = "Training")]
    pub pbr_gamma: f64,
    /// Schlick F0.
    #[arg(long = "f0", id = "train.f0", value_name = "F0", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).f0, value_parser = parse_unit::<f64>, help_heading = "Training")]
    pub f0: f64,
    /// Lower clamp of roughness in the shading (keeps GGX finite).
    #[arg(long = "min-roughness", id = "train.min_roughness", value_name = "R", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).min_roughness, value_parser = parse_unit::<f64>, help_heading = "Training")]
    pub min_roughness: f64,
    /// Encode C_PBR with the sRGB transfer curve before comparing with sRGB images.
    #[arg(long = "pbr-srgb-output", id = "train.pbr_srgb_output", value_name = "BOOL", action = ArgAction::Set, default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).pbr_srgb_output, help_heading = "Training")]
    pub pbr_srgb_output: bool,
    /// Largest angle between a view and its multi-view neighbour, degrees.
    #[arg(long = "neighbour-max-angle", id = "train.neighbour_max_angle_deg", value_name = "DEG", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).neighbour_max_angle_deg, value_parser = parse_positive::<f64>, help_heading = "Training")]
    pub neighbour_max_angle_deg: f64,
    /// Multi-view: pixels whose forward-backward reprojection error exceeds this (pixels)
    /// are left out.
    #[arg(long = "multi-view-max-error", id = "train.multi_view_max_error_px", value_name = "PX", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).multi_view_max_error_px, value_parser = parse_positive::<f64>, help_heading = "Training")]
    pub multi_view_max_error_px: f64,
    /// Multi-view: the term runs on one step in this many, weighted by it so that its mean
    /// pull stays the same (1: every step, as PGSR). The neighbour's render is one of the
    /// four raster passes of a full stage-2 step, with its backward pass. Default: 2.
    #[arg(long = "multi-view-every", id = "train.multi_view_every", value_name = "N", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).multi_view_every, value_parser = parse_count, help_heading = "Training")]
    #[serde(default = "every_step")]
    pub multi_view_every: usize,
    /// Steps trained at half the resolution before the full one (0: none; a coarse-to-fine
    /// schedule, applied by the front end that loads the views).
    #[arg(long = "coarse-until", id = "train.coarse_until", value_name = "STEP", default_value_t = 0, value_parser = clap::value_parser!(usize), help_heading = "Training")]
    #[serde(default)]
    pub coarse_until: usize,
    /// Seed of every random choice (initialisation, view order, densification).
    #[arg(long = "seed", id = "train.seed", value_name = "SEED", default_value_t = 0, value_parser = clap::value_parser!(u64), help_heading = "Training")]
    pub seed: u64,
    /// Screen-space blur of the splats, pixels^2. Default: the pixel box's 1/12.
    ///
    /// `gtsr_render_kernels::PIXEL_BOX_BLUR_PX2`. 3DGS's 0.3 (`BLUR_PX2`, what a config
    /// without this field was trained with) makes the silhouettes spill past the masks, and
    /// the fit pulls the surface set about a pixel inside the object.
    #[serde(default = "legacy_blur_px2")]
    #[arg(long = "blur", id = "train.blur_px2", value_name = "PX2", default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).blur_px2, value_parser = parse_non_negative::<f64>, hide_default_value = true, help_heading = "Training")]
    pub blur_px2: f64,
    /// Scale every splat's opacity so that the blur does not add to what it covers
    /// (`SplatConfig::compensate_blur`, Mip-Splatting's 2D filter, in the projection kernels):
    /// a flat surface Gaussian seen edge-on, dilated to the blur's width, fades accordingly.
    /// Sharper depth maps, the same meshes, a few percent more time per step; below 256 px
    /// the normals lose a degree or two (`docs/log/2026-11-27-compensation-in-the-kernels.md`).
    /// Off in configs written before this setting.
    #[serde(default)]
    #[arg(long = "compensate-blur", id = "train.compensate_blur", value_name = "BOOL", action = ArgAction::Set, default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).compensate_blur, help_heading = "Training")]
    pub compensate_blur: bool,
    /// The least opacity of a surface Gaussian, `[0, 1)`: its opacity is
    /// `floor + (1 - floor) logistic(logit)`. 0 (the default) is 3DGS's logistic. Above 0 the
    /// surface set cannot be a stack of faint layers: each splat hides what lies behind it by at
    /// least the floor, in the depth and material maps (C_SH still weighs it by Fresnel).
    /// Pruning and the opacity reset act on the logistic part. An experiment: `config.json`
    /// only (`gtsr-train --config`).
    #[serde(default)]
    #[arg(skip)]
    pub surface_opacity_floor: f64,
    /// C_PBR's scattering map as a diffuse lobe under the point light
    /// ([`crate::pbr::ShadingParams::scatter_lambert`]): the interior set's view-independent
    /// colour times the irradiance `n . v L / dist^2` of the surface in front of it. Off (the
    /// default): the paper's view-dependent scattering colour. An experiment: `config.json`
    /// only (`gtsr-train --config`).
    #[serde(default)]
    #[arg(skip)]
    pub scatter_lambert: bool,
    /// With `pbr_srgb_output`: decode C_PBR's scattering map from the sRGB curve before it
    /// is added to the linear specular and diffuse terms
    /// ([`crate::pbr::ShadingParams::scatter_srgb`]), since the interior set's colours are
    /// the ones C_SH compares with the sRGB images. Off by default: it gains 1-4 dB of C_SH
    /// and 2-8 dB of C_PBR, but the surface set's depth ends deeper, and on amber_ingot the
    /// carving then cuts into the object (`docs/log/2026-11-27-scatter-srgb.md`).
    #[serde(default)]
    #[arg(long = "pbr-scatter-srgb", id = "train.pbr_scatter_srgb", value_name = "BOOL", action = ArgAction::Set, default_value_t = TrainConfig::for_iterations(Components::FULL, 30_000).pbr_scatter_srgb, help_heading = "Training")]
    pub pbr_scatter_srgb: bool,
}

/// The blur of configs written before `blur_px2` was a setting.
fn legacy_blur_px2() -> f64 {
    gtsr_render_kernels::BLUR_PX2
}

impl TrainConfig {
    /// Defaults for `iterations` steps, with the schedule scaled as PGSR's 30k-step one.
    pub fn for_iterations(components: Components, iterations: usize) -> TrainConfig {
        let mut c = TrainConfig {
            components,
            iterations,
            stage2_start: 0,
            sh_increase_every: 1,
            weights: LossWeights::default(),
            lr: LearningRates::default(),
            densify: DensifyConfig::default(),
            init: Init::Random,
            init_surface: 10_000,
            init_interior: 5_000,
            init_radius: 1.2,
            pbr_gamma: 0.3,
            f0: 0.04,
            min_roughness: 0.08,
            pbr_srgb_output: true,
            neighbour_max_angle_deg: 30.0,
            multi_view_max_error_px: 1.0,
            multi_view_every: 2,
            coarse_until: 0,
            seed: 0,
            blur_px2: gtsr_render_kernels::PIXEL_BOX_BLUR_PX2,
            compensate_blur: false,
            surface_opacity_floor: 0.0,
            scatter_lambert: false,
            pbr_scatter_srgb: false,
        };
        c.set_schedule(iterations);
        c
    }

    /// The CPU-sized defaults for a scene whose views have `pixels` pixels each, `masked` when
    /// every training view has a mask: [`Self::for_iterations`] with the set sizes scaled to
    /// the images and, with masks, the surface set started inside them and the mask term
    /// weighed as much as the images.
    ///
    /// The caps are about 3 surface and 1 interior Gaussian per pixel of one view (64x64:
    /// 12k + 4k; 128x128: 49k + 16k), at most 64k + 32k: a stage-2 step's cost grows with the
    /// Gaussians. With the paper's random start and mask weight 0.1 the surface set stayed a
    /// smooth blob over the holes of a knot, which the Fresnel weighting hides from C_SH.
    pub fn for_views(
        components: Components,
        iterations: usize,
        pixels: usize,
        masked: bool,
    ) -> TrainConfig {
        let mut c = TrainConfig::for_iterations(components, iterations);
        c.init_surface = pixels.clamp(2_000, 20_000);
        c.init_interior = (pixels / 2).clamp(1_000, 10_000);
        c.densify.max_surface = (3 * pixels).clamp(10_000, MAX_SURFACE);
        c.densify.max_interior = pixels.clamp(4_000, MAX_INTERIOR);
        if masked {
            c.init = Init::MaskCarved;
            c.weights.mask = 1.0;
            c.weights.hull_depth = DEFAULT_HULL_DEPTH_WEIGHT;
        }
        c
    }

    /// Lays the schedule out for `iterations` steps as PGSR's 30k-step one: stage 2 from 7/30
    /// of the run, an SH degree every 1/30, densification from 1/60 to half the run every 1/300
    /// (at least 10 steps), an opacity reset every tenth. Every other setting is kept.
    pub fn set_schedule(&mut self, iterations: usize) {
        let frac = |f: f64| ((iterations as f64) * f).round() as usize;
        self.iterations = iterations;
        self.stage2_start = frac(7000.0 / 30000.0);
        self.sh_increase_every = frac(1000.0 / 30000.0).max(1);
        self.densify.start = frac(500.0 / 30000.0);
        self.densify.end = frac(0.5);
        self.densify.every = frac(100.0 / 30000.0).max(10);
        self.densify.opacity_reset_every = frac(3000.0 / 30000.0);
        self.densify.reset_until = self.densify.end;
    }

    /// Checks the configuration, returning every problem in words.
    pub fn validate(&self) -> Result<(), String> {
        self.components.validate()?;
        let mut bad = Vec::new();
        if self.iterations == 0 {
            bad.push("iterations must be positive".to_string());
        }
        if self.init_surface == 0 {
            bad.push("init_surface must be positive".into());
        }
        if self.components.interior && self.init_interior == 0 {
            bad.push("init_interior must be positive when the interior set is on".into());
        }
        if self.densify.every == 0 {
            bad.push("densify.every must be positive".into());
        }
        if self.multi_view_every == 0 {
            bad.push("multi_view_every must be at least 1 (1: every step)".into());
        }
        let t = self.densify.trim_transmittance;
        if !(t > 0.0 && t < 1.0) {
            bad.push(format!(
                "densify.trim_transmittance must be in (0, 1), got {t}"
            ));
        }
        let t = self.densify.demote_transmittance;
        if !(t > 0.0 && t < 1.0) {
            bad.push(format!(
                "densify.demote_transmittance must be in (0, 1), got {t}"
            ));
        }
        if self.densify.demote_every > 0 && !self.components.interior {
            bad.push("densify.demote_every needs the interior set".into());
        }
        if self.weights.multi_view_ncc > 0.0 && !self.components.multi_view {
            bad.push(
                "weights.multi_view_ncc needs the multi-view component (it runs on that term's \
                 steps, with its neighbour)"
                    .into(),
            );
        }
        if self.weights.mask_band_hinge && self.weights.mask_band == 0 {
            bad.push(
                "weights.mask_band_hinge needs a weights.mask_band of at least 1 pixel".into(),
            );
        }
        let cap = MASK_EDGE_CAP as u32;
        for (name, band) in [
            ("weights.mask_band", self.weights.mask_band),
            ("weights.photometric_band", self.weights.photometric_band),
        ] {
            if band >= cap {
                bad.push(format!(
                    "{name} must be below {cap} pixels (the silhouette distance is measured up to \
                     {cap}), got {band}"
                ));
            }
        }
        for (name, v) in [
            ("init_radius", self.init_radius),
            ("pbr_gamma", self.pbr_gamma),
            ("f0", self.f0),
            ("min_roughness", self.min_roughness),
            ("lr.position_start", self.lr.position_start),
            ("lr.position_end", self.lr.position_end),
            ("densify.grad_threshold", self.densify.grad_threshold),
            ("blur_px2", self.blur_px2),
            ("weights.single_view_start", self.weights.single_view_start),
            ("weights.single_view_end", self.weights.single_view_end),
            ("weights.multi_view", self.weights.multi_view),
            ("weights.multi_view_ncc", self.weights.multi_view_ncc),
            ("weights.interior", self.weights.interior),
            ("weights.smooth_roughness", self.weights.smooth_roughness),
            ("weights.smooth_base", self.weights.smooth_base),
            ("weights.flatten", self.weights.flatten),
            ("weights.mask", self.weights.mask),
            ("weights.spread", self.weights.spread),
            ("weights.opacity_entropy", self.weights.opacity_entropy),
            ("weights.front_depth", self.weights.front_depth),
            ("weights.opacity_l1", self.weights.opacity_l1),
            ("weights.smooth_scatter", self.weights.smooth_scatter),
            ("weights.hull_depth", self.weights.hull_depth),
            ("weights.hull_depth_edges", self.weights.hull_depth_edges),
            (
                "weights.hull_depth_occluders",
                self.weights.hull_depth_occluders,
            ),
        ] {
            if !v.is_finite() || v < 0.0 {
                bad.push(format!("{name} must be finite and non-negative, got {v}"));
            }
        }
        if !(0.0..=1.0).contains(&self.weights.lambda_l1) {
            bad.push(format!(
                "weights.lambda_l1 must be in [0, 1], got {}",
                self.weights.lambda_l1
            ));
        }
        if !(0.0..=1.0).contains(&self.weights.hull_depth_from) {
            bad.push(format!(
                "weights.hull_depth_from must be a share of the run in [0, 1], got {}",
                self.weights.hull_depth_from
            ));
        }
        if !(0.0..=1.0).contains(&self.f0) {
            bad.push(format!("f0 must be in [0, 1], got {}", self.f0));
        }
        if !(0.0..1.0).contains(&self.surface_opacity_floor) {
            bad.push(format!(
                "surface_opacity_floor must be in [0, 1), got {}",
                self.surface_opacity_floor
            ));
        }
        if !(0.0..1.0).contains(&self.min_roughness) {
            bad.push(format!(
                "min_roughness must be in [0, 1), got {}",
                self.min_roughness
            ));
        }
        if bad.is_empty() {
            Ok(())
        } else {
            Err(bad.join("; "))
        }
    }
}

mod preset;
#[cfg(test)]
mod tests;

pub use preset::{Decision, Preset, SceneEvidence, auto_components};
