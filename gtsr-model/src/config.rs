//! Every setting of the model and its training: components (what to leave out), loss weights,
//! learning rates, schedule and densification. Serde-serialisable so a run can record and
//! reload the resolved configuration.

use serde::{Deserialize, Serialize};

/// Which parts of the method are switched on. A disabled component allocates no parameters
/// and runs no raster pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Components {
    /// The interior Gaussian set (scattering colour; C_SH blends it with the surface set).
    pub interior: bool,
    /// Surface opacity times the Schlick Fresnel term in C_SH.
    pub fresnel: bool,
    /// The deferred C_PBR render (material maps, scattering map, co-located light).
    pub pbr: bool,
    /// PGSR's multi-view geometric term (renders a neighbour view's depth every step).
    pub multi_view: bool,
    /// PGSR's single-view depth-normal term.
    pub single_view: bool,
    /// Edge-aware smoothness of the roughness and base-colour maps (needs `pbr`).
    pub smoothness: bool,
    /// Largest spherical-harmonics degree (0 to 3); grown during training.
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

/// Named component sets: the paper's model, its ablations, a PGSR-like baseline, and `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// Everything on (the paper's method).
    Full,
    /// Ablation: no C_PBR (and hence no material smoothness).
    NoPbr,
    /// Ablation: surface opacity not weighted by the Fresnel term.
    NoFresnel,
    /// Ablation: no interior set (the scattering map is then absent from C_PBR).
    NoInterior,
    /// PGSR-like baseline: surface set only, no PBR, no Fresnel, PGSR's geometric terms.
    Pgsr,
    /// Decide from the scene (see [`crate::config::auto_components`]).
    Auto,
}

impl Preset {
    /// All presets, for listings and benchmarks.
    pub const ALL: [Preset; 6] = [
        Preset::Full,
        Preset::NoPbr,
        Preset::NoFresnel,
        Preset::NoInterior,
        Preset::Pgsr,
        Preset::Auto,
    ];

    /// The kebab-case name used on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            Preset::Full => "full",
            Preset::NoPbr => "no-pbr",
            Preset::NoFresnel => "no-fresnel",
            Preset::NoInterior => "no-interior",
            Preset::Pgsr => "pgsr",
            Preset::Auto => "auto",
        }
    }

    /// Parses a name as printed by [`Preset::name`].
    pub fn from_name(s: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.name() == s)
    }

    /// The components of a fixed preset (`None` for [`Preset::Auto`], which needs the scene).
    pub fn components(&self) -> Option<Components> {
        let full = Components::FULL;
        Some(match self {
            Preset::Full => full,
            Preset::NoPbr => Components {
                pbr: false,
                smoothness: false,
                ..full
            },
            Preset::NoFresnel => Components {
                fresnel: false,
                ..full
            },
            Preset::NoInterior => Components {
                interior: false,
                ..full
            },
            Preset::Pgsr => Components {
                interior: false,
                fresnel: false,
                pbr: false,
                smoothness: false,
                ..full
            },
            Preset::Auto => return None,
        })
    }
}

/// What the scene tells `auto` (gathered by the caller from metadata and images).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneEvidence {
    /// `Some(true)` when metadata says the only light is a point light at the camera,
    /// `Some(false)` when it says otherwise, `None` when there is no such metadata.
    pub colocated_light: Option<bool>,
    /// `Some(true)` when metadata says the material is opaque (no subsurface scattering).
    pub opaque: Option<bool>,
    /// Mean background brightness (pixels whose mask is below 0.5), when masks exist.
    pub background_level: Option<f32>,
    /// Number of training views (the multi-view term needs neighbours).
    pub train_views: usize,
    /// Views that have at least one neighbour within the multi-view angle.
    pub views_with_neighbours: usize,
}

/// One decision of `auto`: a component, whether it is on, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// Component name.
    pub component: String,
    /// Whether it is kept.
    pub enabled: bool,
    /// Why, in words.
    pub reason: String,
}

/// Resolves [`Preset::Auto`]: starts from the full model and leaves out what the evidence says
/// the scene does not need. Every decision is returned with its reason.
pub fn auto_components(e: &SceneEvidence) -> (Components, Vec<Decision>) {
    let mut c = Components::FULL;
    let mut d = Vec::new();
    let mut say = |component: &str, enabled: bool, reason: String| {
        d.push(Decision {
            component: component.into(),
            enabled,
            reason,
        })
    };
    match (e.colocated_light, e.background_level) {
        (Some(true), _) => say("pbr", true, "metadata: point light at the camera".into()),
        (Some(false), _) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                "metadata: the light is not co-located with the camera, so the PBR model does not apply".into(),
            )
        }
        (None, Some(level)) if level <= 0.02 => say(
            "pbr",
            true,
            format!(
                "no light metadata; background level {level:.3} is black, consistent with a flash in the dark"
            ),
        ),
        (None, Some(level)) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                format!(
                    "no light metadata; background level {level:.3} shows ambient light, so a co-located light cannot be assumed"
                ),
            )
        }
        (None, None) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                "no light metadata and no masks to check for a dark background".into(),
            )
        }
    }
    if !c.pbr {
        c.smoothness = false;
        say(
            "smoothness",
            false,
            "regularises PBR material maps only".into(),
        );
    }
    match e.opaque {
        Some(true) => {
            c.interior = false;
            c.fresnel = false;
            say(
                "interior",
                false,
                "metadata: opaque material, nothing scatters inside".into(),
            );
            say(
                "fresnel",
                false,
                "opaque surface: nothing to see through".into(),
            );
        }
        Some(false) => say("interior", true, "metadata: translucent material".into()),
        None => say(
            "interior",
            true,
            "opacity cannot be told from images alone; kept (the safe choice for translucent data)"
                .into(),
        ),
    }
    if e.views_with_neighbours * 2 < e.train_views {
        c.multi_view = false;
        say(
            "multi_view",
            false,
            format!(
                "only {} of {} training views have a neighbour within the angle limit",
                e.views_with_neighbours, e.train_views
            ),
        );
    }
    (c, d)
}

/// Loss weights (names follow the paper).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// lambda1: weight of L1 in `lambda1 L1 + (1 - lambda1) (1 - SSIM)`, on each render.
    pub lambda_l1: f64,
    /// lambda2 at the start of stage 2 (rises linearly to `single_view_end`).
    pub single_view_start: f64,
    /// lambda2 at the end of training.
    pub single_view_end: f64,
    /// lambda3: multi-view geometric term.
    pub multi_view: f64,
    /// lambda4: interior containment.
    pub interior: f64,
    /// lambda5: roughness smoothness.
    pub smooth_roughness: f64,
    /// lambda6: base-colour smoothness.
    pub smooth_base: f64,
    /// Flattening: mean smallest scale of the surface set.
    pub flatten: f64,
    /// L1 between the surface set's alpha and the mask (when the data has masks).
    pub mask: f64,
    /// Layer spread (not in the paper; 0, off, by default): the mean over the valid pixels of
    /// the blend-weighted standard deviation of the depths at which the surface splats cross
    /// the pixel's ray, in pixels (see [`crate::losses::layer_spread`]). 2DGS's depth
    /// distortion in another form: it asks the surface set for one layer per pixel instead of
    /// a stack of faint ones.
    #[serde(default)]
    pub spread: f64,
    /// Opacity binarisation of the surface set in stage 2 (not in the paper): the mean binary
    /// entropy of the surface opacities ([`crate::losses::opacity_entropy`]), which pushes
    /// each towards 0 or 1, so the surface ends one opaque layer rather than a stack of faint
    /// ones whose blended depth lies behind the surface.
    #[serde(default)]
    pub opacity_entropy: f64,
    /// In stage 2 the mask term counts only missing coverage inside the mask
    /// ([`crate::losses::mask_deficit`]), not coverage spilling past it, which pulls the
    /// surface Gaussians inward (not in the paper; off by default).
    #[serde(default)]
    pub mask_deficit_only: bool,
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights {
            lambda_l1: 0.2,
            single_view_start: 0.0025,
            single_view_end: 0.9,
            multi_view: 0.01,
            interior: 0.01,
            smooth_roughness: 0.01,
            smooth_base: 0.01,
            flatten: 100.0,
            mask: 0.1,
            spread: 0.0,
            opacity_entropy: 0.0,
            mask_deficit_only: false,
        }
    }
}

/// Adam learning rates per parameter (PGSR/3DGS values; positions scale with the scene).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LearningRates {
    /// Position rate at step 0, times the scene extent.
    pub position_start: f64,
    /// Position rate at the last step, times the scene extent (exponential decay between).
    /// A tenth of the start rather than 3DGS's hundredth, so that stage 2's geometric terms
    /// can still move the surface out to where the depth says it is.
    pub position_end: f64,
    /// SH DC coefficients.
    pub sh_dc: f64,
    /// Higher SH coefficients.
    pub sh_rest: f64,
    /// Opacity logits.
    pub opacity: f64,
    /// Log-scales.
    pub scale: f64,
    /// Quaternions.
    pub rotation: f64,
    /// Base colour logits.
    pub base_colour: f64,
    /// Roughness logits.
    pub roughness: f64,
    /// Log light intensity.
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

/// Densification, pruning and opacity reset (applied to each set separately).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DensifyConfig {
    /// First step that densifies.
    pub start: usize,
    /// Last step that densifies (fraction of the run is common: set by the caller).
    pub end: usize,
    /// Densify every this many steps.
    pub every: usize,
    /// Mean screen-space gradient threshold, in NDC units as 3DGS (`|dL/d mean2d| * W / 2`).
    pub grad_threshold: f64,
    /// Gaussians larger than this fraction of the scene extent are split, smaller ones cloned.
    pub percent_dense: f64,
    /// Prune below this opacity.
    pub min_opacity: f64,
    /// Reset opacities to at most 0.01 every this many steps (0: never), while densification
    /// still runs (see [`DensifyConfig::resets_after`]).
    pub opacity_reset_every: usize,
    /// Cap on the surface set (densification stops growing it past this).
    pub max_surface: usize,
    /// Cap on the interior set.
    pub max_interior: usize,
    /// PGSR's multi-view trim: every this many steps while densification runs (0: never, the
    /// default; PGSR: every 1000 of 30000 steps), the surface Gaussians observed in fewer than
    /// [`Self::trim_min_views`] training views are pruned, where observed means blended at some
    /// pixel while the transmittance in front is above [`Self::trim_transmittance`]
    /// ([`crate::Model::observed_surface`]). It brings the depth closer to the surface but
    /// costs image quality on strongly scattering objects (`gtsr-model/README.md`).
    #[serde(default)]
    pub trim_every: usize,
    /// Views in which a surface Gaussian must be observed to survive the trim.
    #[serde(default = "default_trim_min_views")]
    pub trim_min_views: usize,
    /// Transmittance above which a splat counts as observed by the trim: 0.9, the front layers.
    /// PGSR's 0.5 keeps the splats up to the median depth, but with a faint surface set the
    /// median lies deep inside the object, and 0.5 spares the deep layers that bias the depth
    /// (`gtsr-model/README.md`).
    #[serde(default = "default_trim_transmittance")]
    pub trim_transmittance: f64,
}

fn default_trim_min_views() -> usize {
    2
}

fn default_trim_transmittance() -> f64 {
    0.9
}

impl DensifyConfig {
    /// Whether the opacities are reset after the step that makes `done` steps in all: every
    /// [`Self::opacity_reset_every`] steps strictly before [`Self::end`], as 3DGS does. A reset at
    /// the end itself would leave every Gaussian at opacity 0.01 with no pruning to follow, and
    /// the layers that pruning removes after the other resets would all grow back: on
    /// amber_ingot (1500 steps, end 750) that reset took chamfer x1e3 from 28 to 42 within
    /// 150 steps, and leaving it out gave 22.2 against 30.6 at the end.
    pub fn resets_after(&self, done: usize) -> bool {
        self.opacity_reset_every > 0
            && done.is_multiple_of(self.opacity_reset_every)
            && done < self.end
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
            max_surface: 200_000,
            max_interior: 50_000,
            trim_every: 0,
            trim_min_views: default_trim_min_views(),
            trim_transmittance: default_trim_transmittance(),
        }
    }
}

/// How the surface set starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Init {
    /// Uniform random points in a ball (the paper: COLMAP fails on textureless objects).
    Random,
    /// Random points kept only where every training mask covers their projection.
    MaskCarved,
    /// Points on the boundary of the mask-carved volume (the masks' visual hull).
    HullSurface,
}

/// Everything that defines a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Components in use (already resolved from a preset).
    pub components: Components,
    /// Total steps.
    pub iterations: usize,
    /// First step of stage 2 (interior set and geometric terms); before it only the surface
    /// set is trained, photometrically.
    pub stage2_start: usize,
    /// Add one SH degree every this many steps.
    pub sh_increase_every: usize,
    /// Loss weights.
    pub weights: LossWeights,
    /// Learning rates.
    pub lr: LearningRates,
    /// Densification.
    pub densify: DensifyConfig,
    /// Surface initialisation.
    pub init: Init,
    /// Number of initial surface Gaussians.
    pub init_surface: usize,
    /// Number of interior Gaussians added at stage 2.
    pub init_interior: usize,
    /// Radius of the initial ball (scene units; the data loaders normalise scenes).
    pub init_radius: f64,
    /// gamma: weight of the diffuse term in C_PBR.
    pub pbr_gamma: f64,
    /// Schlick F0.
    pub f0: f64,
    /// Lower clamp of roughness in the shading (keeps GGX finite).
    pub min_roughness: f64,
    /// Encode C_PBR with the sRGB transfer curve before comparing with sRGB images.
    pub pbr_srgb_output: bool,
    /// Largest angle between a view and its multi-view neighbour, degrees.
    pub neighbour_max_angle_deg: f64,
    /// Multi-view: pixels whose forward-backward reprojection error exceeds this (pixels)
    /// are left out.
    pub multi_view_max_error_px: f64,
    /// Seed of every random choice (initialisation, view order, densification).
    pub seed: u64,
    /// Screen-space blur of the splats, pixels^2. Default: the pixel box's 1/12
    /// (`gtsr_render_kernels::PIXEL_BOX_BLUR_PX2`); 3DGS's 0.3 (`BLUR_PX2`, what a config
    /// without this field was trained with) makes the silhouettes spill past the masks, and
    /// the fit pulls the surface set about a pixel inside the object.
    #[serde(default = "legacy_blur_px2")]
    pub blur_px2: f64,
}

/// The blur of configs written before `blur_px2` was a setting.
fn legacy_blur_px2() -> f64 {
    gtsr_render_kernels::BLUR_PX2
}

impl TrainConfig {
    /// Defaults for `iterations` steps, with the schedule scaled as PGSR's 30k-step one.
    pub fn for_iterations(components: Components, iterations: usize) -> TrainConfig {
        let frac = |f: f64| ((iterations as f64) * f).round() as usize;
        TrainConfig {
            components,
            iterations,
            stage2_start: frac(7000.0 / 30000.0),
            sh_increase_every: frac(1000.0 / 30000.0).max(1),
            weights: LossWeights::default(),
            lr: LearningRates::default(),
            densify: DensifyConfig {
                start: frac(500.0 / 30000.0),
                end: frac(0.5),
                every: frac(100.0 / 30000.0).max(10),
                opacity_reset_every: frac(3000.0 / 30000.0),
                ..DensifyConfig::default()
            },
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
            seed: 0,
            blur_px2: gtsr_render_kernels::PIXEL_BOX_BLUR_PX2,
        }
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
        let t = self.densify.trim_transmittance;
        if !(t > 0.0 && t < 1.0) {
            bad.push(format!(
                "densify.trim_transmittance must be in (0, 1), got {t}"
            ));
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
            ("weights.interior", self.weights.interior),
            ("weights.smooth_roughness", self.weights.smooth_roughness),
            ("weights.smooth_base", self.weights.smooth_base),
            ("weights.flatten", self.weights.flatten),
            ("weights.mask", self.weights.mask),
            ("weights.spread", self.weights.spread),
            ("weights.opacity_entropy", self.weights.opacity_entropy),
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
        if !(0.0..=1.0).contains(&self.f0) {
            bad.push(format!("f0 must be in [0, 1], got {}", self.f0));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opacity_resets_stop_before_the_end_of_densification() {
        let c = TrainConfig::for_iterations(Components::FULL, 1500);
        let d = &c.densify;
        assert_eq!((d.opacity_reset_every, d.end), (150, 750));
        let resets: Vec<usize> = (1..=c.iterations).filter(|s| d.resets_after(*s)).collect();
        assert_eq!(resets, vec![150, 300, 450, 600]);
        // Every reset is followed by a densification (and its pruning).
        for r in resets {
            assert!((r + 1..=d.end).any(|s| s >= d.start && s.is_multiple_of(d.every)));
        }
        let never = DensifyConfig {
            opacity_reset_every: 0,
            ..d.clone()
        };
        assert!(!(1..=c.iterations).any(|s| never.resets_after(s)));
    }

    #[test]
    fn trims_run_on_their_schedule_while_densification_runs() {
        let mut d = TrainConfig::for_iterations(Components::FULL, 1500).densify;
        assert!(!(1..=1500).any(|s| d.trims_after(s)), "off by default");
        // PGSR's every 1000 of 30000 steps, while densification runs (to step 750 here).
        d.trim_every = 50;
        let trims: Vec<usize> = (1..=1500).filter(|s| d.trims_after(*s)).collect();
        assert_eq!(trims.first(), Some(&50));
        assert_eq!(trims.last(), Some(&700));
        assert_eq!(trims.len(), 14);
        // Configurations written before the trim existed read with it off.
        let mut json =
            serde_json::to_value(TrainConfig::for_iterations(Components::FULL, 10)).unwrap();
        let obj = json["densify"].as_object_mut().unwrap();
        obj.remove("trim_every");
        obj.remove("trim_min_views");
        obj.remove("trim_transmittance");
        let back: TrainConfig = serde_json::from_value(json).unwrap();
        assert_eq!(
            (back.densify.trim_every, back.densify.trim_min_views),
            (0, 2)
        );
        assert_eq!(back.densify.trim_transmittance, 0.9);
    }

    #[test]
    fn blur_defaults_to_the_pixel_box_and_old_configs_keep_3dgs_blur() {
        let c = TrainConfig::for_iterations(Components::FULL, 100);
        assert_eq!(c.blur_px2, gtsr_render_kernels::PIXEL_BOX_BLUR_PX2);
        let mut json = serde_json::to_value(&c).unwrap();
        json.as_object_mut().unwrap().remove("blur_px2");
        let old: TrainConfig = serde_json::from_value(json).unwrap();
        assert_eq!(old.blur_px2, gtsr_render_kernels::BLUR_PX2);
        for bad in [-0.5, f64::NAN] {
            let e = TrainConfig {
                blur_px2: bad,
                ..c.clone()
            }
            .validate()
            .unwrap_err();
            assert!(e.contains("blur_px2"), "{e}");
        }
    }
}
