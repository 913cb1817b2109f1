//! The extraction's settings: [`MeshConfig`], one serde and [`clap::Args`] struct that a run
//! records in its `config.json` and a front end flattens into its command line.
//!
//! Each argument's id is its path in a run's `config.json` (`mesh.carve_views`), as for the
//! training settings of `gtsr-model`, so that a front end can overlay what the user gave on a
//! saved configuration. The fusion variants that were measured and not kept (see
//! `docs/results.md`) are fields of the file only, not command-line flags.

use clap::ValueEnum;
use gtsr_data::parse::{parse_non_negative, parse_positive, parse_unit};
use serde::{Deserialize, Serialize};

use crate::carve::{CarveSettings, MAX_CARVE_VIEWS};
use crate::consistency::ConsistencySettings;
use crate::error::{MeshError, Result};

/// How the mesh is extracted.
#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fusion {
    /// The masks at the dataset's resolution bound the object with sub-pixel placement, and
    /// the rendered depth carves inside that bound where enough views agree (needs a mask on
    /// every view; [`crate::carve::carve_mesh`]).
    Carve,
    /// TSDF fusion of the rendered depth, with the masks' hull when there are masks
    /// ([`crate::tsdf::TsdfVolume`]).
    Tsdf,
}

/// The carving's default agreeing views: one. A concavity the masks miss is often seen by
/// one or two training views only; the concavity gate keeps a single view from eroding the
/// rest.
pub const DEFAULT_CARVE_VIEWS: u64 = 1;
/// The carving's default margin in footprints: the carved surface lies this far in front of
/// the rendered depth, which runs about a footprint behind the surface.
pub const DEFAULT_CARVE_MARGIN: f32 = 1.0;
/// The default concavity gate in footprints ([`CarveSettings::concavity_gate`]).
pub const DEFAULT_CONCAVITY_GATE: f32 = 3.0;
/// The default of [`MeshConfig::carve_max_opened`].
pub const DEFAULT_CARVE_MAX_OPENED: f32 = 0.01;
/// The default of [`MeshConfig::carve_max_spread`], footprints.
pub const DEFAULT_CARVE_MAX_SPREAD: f32 = 1.0;
/// The default of [`MeshConfig::carve_min_lid_departure`].
pub const DEFAULT_CARVE_MIN_LID_DEPARTURE: f32 = 1.25;
/// The default tolerance in footprints of [`MeshConfig::cull_unobserved`].
pub const DEFAULT_CULL_UNOBSERVED: f32 = 3.0;
/// How far the shading refinement may move a vertex outward, in the masks' footprints, when
/// one anchor holds every vertex (held by the slack it moves inward only: the object lies
/// inside the hull).
pub(crate) const SHADING_MAX_OUTWARD: f32 = 0.25;
/// The default of [`MeshConfig::shading_anchor`], footprints: long, for the vertices whose
/// slack on the masks' hull reaches [`DEFAULT_SHADING_SLACK`] (the others are held by it).
pub const DEFAULT_SHADING_ANCHOR: f32 = 100.0;
/// The default of [`MeshConfig::shading_slack`], footprints.
pub const DEFAULT_SHADING_SLACK: f32 = 4.0;
/// The default of [`MeshConfig::shading_rounds`].
pub const DEFAULT_SHADING_ROUNDS: usize = 6;
/// The default of [`MeshConfig::shading_unscatter`].
pub const DEFAULT_SHADING_UNSCATTER: bool = true;
/// The default of [`MeshConfig::shading_radiance_rendered`]: the model's render alone.
pub const DEFAULT_SHADING_RADIANCE_RENDERED: f32 = 1.0;
/// The default of [`MeshConfig::shading_steep_tilt`], degrees.
pub const DEFAULT_SHADING_STEEP_TILT: f32 = 60.0;
/// The default of [`MeshConfig::shading_depth_threshold`], footprints.
pub const DEFAULT_SHADING_DEPTH_THRESHOLD: f32 = 0.25;
/// [`MeshConfig::shading_depth`]: the depth's offsets count on faces at least this many views
/// observe.
pub(crate) const DEPTH_MIN_VIEWS: u32 = 3;

/// Where the depth that is fused and measured takes its blur in each splat's own plane rather
/// than on the screen ([`MeshConfig::readout_blur_in_plane`]). In the plane, a splat facing
/// the camera covers what the screen's blur makes it cover, and one seen edge-on at an
/// occluding outline does not spill past the outline; a tilted splat covers less.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlaneReadout {
    /// On the screen everywhere (the training's render).
    Off,
    /// In the plane everywhere.
    Everywhere,
    /// On the screen, except at the pixels where the plane's depth lies more than
    /// [`OUTLINE_GAP_FOOTPRINTS`] behind the screen's: there the nearer surface only spills
    /// past its outline, and the plane's layer is the one the pixel sees.
    #[default]
    Outlines,
}

/// [`PlaneReadout::Outlines`]: how far behind the screen's depth, in pixel footprints, the
/// plane's must lie for a pixel to count as spilled over.
pub const OUTLINE_GAP_FOOTPRINTS: f64 = 3.0;

/// Every mesh extraction setting. Scenes without masks always use [`Fusion::Tsdf`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(default, deny_unknown_fields)]
pub struct MeshConfig {
    /// How the mesh is extracted: `carve` (the masks at the dataset's resolution bound the
    /// object, the rendered depth carves inside where views agree; needs masks) or `tsdf`.
    #[arg(long = "fusion", id = "mesh.fusion", value_name = "METHOD", value_enum, default_value_t = Fusion::Carve)]
    pub fusion: Fusion,
    /// Carving: the depth views that must each put a point in front of their rendered surface.
    #[arg(long = "carve-views", id = "mesh.carve_views", value_name = "N", default_value_t = DEFAULT_CARVE_VIEWS,
          value_parser = clap::value_parser!(u64).range(1..=MAX_CARVE_VIEWS as u64))]
    pub carve_views: u64,
    /// Carving: how far in front, in that view's training-pixel footprints.
    #[arg(long = "carve-margin", id = "mesh.carve_margin", value_name = "FOOTPRINTS",
          default_value_t = DEFAULT_CARVE_MARGIN, value_parser = parse_non_negative::<f32>)]
    pub carve_margin: f32,
    /// Carving: the least share of the views that put a point in front of their surface among
    /// those that put it in front or near it (the rest see it hidden and do not count).
    #[arg(long = "carve-free-ratio", id = "mesh.carve_free_ratio", value_name = "SHARE",
          default_value_t = 0.5, value_parser = parse_unit::<f32>)]
    pub carve_free_ratio: f32,
    /// Carving: added to the margin, this many times the depth step from a view's pixel to its
    /// steepest neighbour (0: off).
    #[arg(skip)]
    pub carve_slope: f32,
    /// Carving: read each view's depth bilinearly at the point's projection, and take no vote
    /// from a view where one of the four pixels around it has no depth (false: the nearest
    /// pixel).
    #[serde(default)]
    #[arg(skip)]
    pub carve_bilinear: bool,
    /// Carving: a view votes a point free only where its depth lies more than this many
    /// footprints behind the masks' own depth at that pixel, i.e. where it looks into a
    /// concavity the masks cannot see (0: off; [`CarveSettings::concavity_gate`]).
    #[arg(long = "carve-concavity-gate", id = "mesh.carve_concavity_gate", value_name = "FOOTPRINTS",
          default_value_t = DEFAULT_CONCAVITY_GATE, value_parser = parse_non_negative::<f32>)]
    pub carve_concavity_gate: f32,
    /// Carving: the concavity gate's window radius in pixels ([`CarveSettings::gate_radius`]).
    #[arg(skip)]
    pub carve_gate_radius: usize,
    /// Carving: leave out the carved walls (faces off the masks' mesh) that no depth map
    /// observes within this many footprints ([`crate::visible::faces_observed`]): where a view
    /// carved through an opening into a cavity it sees only part of. The mesh is then open
    /// there (0: keep the closed mesh).
    #[arg(long = "cull-unobserved", id = "mesh.cull_unobserved", value_name = "FOOTPRINTS",
          default_value_t = DEFAULT_CULL_UNOBSERVED, value_parser = parse_non_negative::<f32>)]
    pub cull_unobserved: f32,
    /// Carving: then refine the mesh by the normals the training images' shading explains
    /// under a light at the camera (the paper's capture), with the light the object sends
    /// itself modelled and each normal shrunk towards the mesh's own by its uncertainty; each
    /// vertex moves inward along its normal, held to where it was over this many of the masks'
    /// pixel footprints where its slack on the masks' hull reaches `--shading-slack`, and over
    /// `(slack / shading-slack)^4` of that where it is smaller (0: off). Only where the light
    /// is at the camera (the PBR component's decision). A coarse extraction (the evaluations
    /// along a run) runs fewer rounds ([`MeshConfig::with_shading_rounds`]).
    #[arg(long = "shading-anchor", id = "mesh.shading_anchor", value_name = "FOOTPRINTS",
          default_value_t = DEFAULT_SHADING_ANCHOR, value_parser = parse_non_negative::<f32>)]
    pub shading_anchor: f32,
    /// Carving, with the shading refinement: also pull each face towards where the rendered
    /// depth maps see the surface (per face the median offset over the views, less the median
    /// over the faces: the depth's bias; trusted inward beyond
    /// [`MeshConfig::shading_depth_threshold`]), over this many footprints (0: off).
    #[arg(skip)]
    pub shading_depth: f32,
    /// Carving, with the shading refinement: the share in `[0, 1]` of each face's target
    /// normal taken from the fusion views' rendered normal maps
    /// ([`crate::shading::NormalPrior`]), the rest from the images' shading (0: the shading's
    /// alone).
    #[arg(skip)]
    pub shading_normals_rendered: f32,
    /// Carving, with the shading refinement: the share in `[0, 1]` of each view's radiance
    /// taken from the trained model's render of that view (C_SH, the images as the Gaussians
    /// reproduce them, without the images' per-pixel noise) instead of the image (0: the
    /// images alone), so that the refined mesh follows the model. The caller renders it
    /// ([`crate::MasksAlone::with_rendered_radiance`]).
    #[arg(skip = DEFAULT_SHADING_RADIANCE_RENDERED)]
    pub shading_radiance_rendered: f32,
    /// With [`MeshConfig::shading_depth`]: the depth's offsets are trusted inward beyond this
    /// many footprints; the faces within it are asked to stay.
    #[arg(skip = DEFAULT_SHADING_DEPTH_THRESHOLD)]
    pub shading_depth_threshold: f32,
    /// Carving, with the shading refinement: shrink each face's shading normal towards its
    /// own by its uncertainty ([`crate::shading::ShadingSettings::shrink`]; false: the plain
    /// least-squares normals).
    #[arg(skip = true)]
    pub shading_shrink: bool,
    /// Carving, with the shading refinement: hold each vertex by its slack on the masks' hull
    /// (`crate::hull::hull_slack`, an upper bound on how far the object lies from the hull
    /// there): its anchor is `--shading-anchor` times `min(1, slack / this)^4`, in footprints,
    /// and it moves inward only (0: one anchor for every vertex, which may also move a
    /// quarter footprint outward).
    #[arg(long = "shading-slack", id = "mesh.shading_slack", value_name = "FOOTPRINTS",
          default_value_t = DEFAULT_SHADING_SLACK, value_parser = parse_non_negative::<f32>)]
    pub shading_slack: f32,
    /// Carving, with the shading refinement: observe-and-refine rounds, each reading the
    /// normals on the last round's mesh, so that a sinking lid's faces are seen where they
    /// have moved ([`crate::shading::ShadingRefinement::rounds`]; at least 1).
    #[arg(skip = DEFAULT_SHADING_ROUNDS)]
    pub shading_rounds: usize,
    /// Carving, with the shading refinement held by the slack: the largest tilt of a target
    /// normal from its face trusted where a face's slack reaches twice `--shading-slack`
    /// (degrees, below 90), ramping from 30 degrees at `--shading-slack` and below
    /// ([`crate::shading::slack_tilt_limits`]): the masks leave room for steep walls only
    /// over the concavities they cannot see.
    #[arg(skip = DEFAULT_SHADING_STEEP_TILT)]
    pub shading_steep_tilt: f32,
    /// Carving, with the shading refinement: fit the light scattered under the surface as a
    /// blur of the shading on the faces the masks' hull holds, and invert it in the images
    /// before the shading fit ([`crate::scatter::unscatter`], the noise amplified at most
    /// twofold; false: the images as they are).
    #[arg(skip = DEFAULT_SHADING_UNSCATTER)]
    pub shading_unscatter: bool,
    /// Carving: the largest share of the masks' pixels (those the bound covers, over every
    /// view) that the carved mesh may leave uncovered; beyond it the carving is refused and
    /// the bound goes on alone. The object fills every mask, so a carving that opens the
    /// silhouettes has cut into the object: the depth is not yet a surface (a run stopped
    /// early, a failed one). 1: no check.
    #[arg(skip = DEFAULT_CARVE_MAX_OPENED)]
    pub carve_max_opened: f32,
    /// Carving: the widest spread the depth's offsets from the masks' bound may have between
    /// their quartiles ([`crate::carve::hull_offset`], footprints); wider, the carving is refused and
    /// the bound goes on alone. Where the bound is flush with the object, a depth that is a
    /// surface lies within a fraction of a footprint of it, so its quartiles lie close
    /// together; a depth still scattered in front of and behind the surface (a run stopped
    /// early) spreads them, and its far tail would pass the concavity gate and dig pits into
    /// the flush surface without opening a silhouette. An object whose concavities fill a
    /// quarter of what the views see spreads them too: raise it there. 0: no check.
    #[arg(skip = DEFAULT_CARVE_MAX_SPREAD)]
    pub carve_max_spread: f32,
    /// Carving, where the masks' views carry their radiance (as for the shading refinement):
    /// how much more the images' shading must depart from the masks' bound over the carved
    /// volume than elsewhere. The departure is the median angle between the shading normals
    /// and the bound's own, over the bound's faces that lie above the carved volume and over
    /// the others; at or below this ratio the carving is refused and the bound goes on alone.
    /// Each carved region (a connected part of the carved volume) is judged so by the part of
    /// the lid above it, where the shading solves any of it, and the others by the whole lid:
    /// a carving that took a true concavity and a wrong dent keeps the one and loses the
    /// other. Over a concavity the masks cannot see, the bound is a lid whose pixels show the
    /// concavity's shading, which no normal of the lid explains. Over a dent that the depth
    /// holds and the images do not (a model stopped mid-schedule, alike in every view that
    /// sees it, so that it passes the other checks), the shading finds the bound to be the
    /// surface, as anywhere else. 0: no check.
    #[arg(skip = DEFAULT_CARVE_MIN_LID_DEPARTURE)]
    pub carve_min_lid_departure: f32,
    /// Carving: before the gate and the carving read them, move the depth maps towards the
    /// cameras by the median of how far they lie behind the masks' bound where both see the
    /// object ([`crate::carve::hull_offset`], in footprints, when positive): a depth that runs behind
    /// the surface over the whole object then no longer looks like a concavity everywhere.
    /// On by default: the masks' bound is flush with the object over most of what the views
    /// see; on an object mostly made of concavities, turn it off.
    #[arg(skip = true)]
    pub carve_debias: bool,
    /// Carving: the grid spacing (scene units). Default: 0.75 of the masks' pixel footprint
    /// at the object, at the dataset's resolution.
    #[arg(long = "carve-voxel", id = "mesh.carve_voxel", value_name = "SIZE", value_parser = parse_positive::<f32>)]
    pub carve_voxel: Option<f32>,
    /// TSDF: the voxel size (scene units). Default: the radius of the mesh box / 256, and no
    /// finer than a quarter of a training pixel's footprint at the object
    /// ([`crate::tsdf::default_voxel`]).
    #[arg(long = "voxel", id = "mesh.voxel", value_name = "SIZE", value_parser = parse_positive::<f32>)]
    pub voxel: Option<f32>,
    /// TSDF: the truncation (scene units). Default: the larger of 0.75 times the radius of the
    /// mesh box and 6 training-pixel footprints at the object.
    #[arg(long = "truncation", id = "mesh.truncation", value_name = "DIST",
          value_parser = parse_positive::<f32>, conflicts_with = "mesh.truncation_footprints")]
    pub truncation: Option<f32>,
    /// TSDF: the truncation in training-pixel footprints at the mesh box's centre.
    #[arg(long = "truncation-footprints", id = "mesh.truncation_footprints",
          value_name = "FOOTPRINTS", value_parser = parse_positive::<f32>)]
    pub truncation_footprints: Option<f32>,
    /// Longest image side of the depth maps fused into the mesh (the trained Gaussians are
    /// rendered again at this size). Default: the training resolution; at most the dataset's.
    #[arg(long = "mesh-resolution", id = "mesh.mesh_resolution", value_name = "PIXELS",
          value_parser = clap::value_parser!(u32).range(1..))]
    pub mesh_resolution: Option<u32>,
    /// Fuse or carve with, per pixel, the depth of the surface splat at which the transmittance
    /// falls to this value (0.5: the median depth of 2DGS) instead of the blended depth of
    /// PGSR; the test-view depth metrics then measure this depth. In (0, 1).
    #[arg(skip)]
    pub depth_crossing: Option<f64>,
    /// Render the depth that is fused or carved (and that the test-view depth metrics measure)
    /// with this screen-space blur, in pixels^2, instead of the training's: the blur stands for
    /// the pixel filter of the images, and the geometry read without it lies where the splats
    /// themselves are. Also the blur of the plane's render
    /// ([`MeshConfig::readout_blur_in_plane`]). `None`: the training's blur. Finite, `>= 0`.
    #[arg(skip)]
    pub readout_blur_px2: Option<f64>,
    /// Where the readout's blur (the training's, or [`MeshConfig::readout_blur_px2`]) acts in
    /// each splat's own plane instead of on the screen ([`PlaneReadout`]).
    #[arg(skip)]
    pub readout_blur_in_plane: PlaneReadout,
    /// TSDF on a masked scene: keep the masks' visual hull in the volume, so the surface never
    /// leaves a silhouette ([`crate::tsdf::TsdfVolume::with_silhouette_carving`]). Off: pixels
    /// outside the masks cast no votes (depth alone, as PGSR and 2DGS fuse).
    #[arg(skip = true)]
    pub silhouette_carving: bool,
    /// TSDF: fuse the rendered depth. Off: the masks alone on the fusion grid.
    #[arg(skip = true)]
    pub fuse_depth: bool,
    /// TSDF with the hull: where no depth was fused inside it, the hull's own distance instead
    /// of `-truncation` ([`crate::tsdf::TsdfVolume::with_hull_inside_distance`]).
    #[arg(skip)]
    pub hull_inside_distance: bool,
    /// TSDF with the hull: depth samples less than this many footprints behind the masks' hull
    /// (or in front of it) are replaced by the hull's depth ([`crate::tsdf::snap_to_hull`]).
    #[arg(skip)]
    pub snap_to_hull: Option<f32>,
    /// Keep a depth sample (for the TSDF or the carving) only where this many neighbouring
    /// views agree with it ([`crate::consistency::filter_consistent`]); the others cast no vote.
    #[arg(skip)]
    pub depth_consistency: Option<ConsistencySettings>,
    /// Carving: bound the mesh by the hull of the masks' edges ([`crate::MasksAlone::with_edge_distance`],
    /// where the masks carry it; gtsr-train builds it when this is set) rather than by the
    /// masks' coverage interpolated between pixel centres (the baseline).
    #[arg(skip = true)]
    pub edge_hull: bool,
    /// Carving: read a hollow behind the masks' lid from the images by path tracing
    /// ([`crate::hollow::read_hollow`], where the masks carry the images and the fusion views
    /// are their size), and carve the dark pixels that far behind the lid. The reading
    /// depends on the masks and images alone, so a run searches once
    /// ([`crate::MasksAlone::hollow_reading`]) and every extraction along it uses the same. A scene
    /// without dark pixels costs one scattering fit.
    #[arg(long = "hollow-search", id = "mesh.hollow_search", value_name = "BOOL",
          default_value_t = true, action = clap::ArgAction::Set)]
    pub hollow_search: bool,
    /// With [`MeshConfig::edge_hull`]: read every mask with a Gaussian edge profile of this
    /// many pixels, or as box-filtered at 0 (`None`: the profile the masks' edge width says,
    /// [`crate::hull::EdgeProfile::from_width`]).
    #[arg(skip)]
    pub edge_sigma: Option<f32>,
}

impl Default for MeshConfig {
    fn default() -> Self {
        MeshConfig {
            fusion: Fusion::Carve,
            carve_views: DEFAULT_CARVE_VIEWS,
            carve_margin: DEFAULT_CARVE_MARGIN,
            carve_free_ratio: CarveSettings::default().min_free_ratio,
            carve_slope: CarveSettings::default().slope_margin,
            carve_bilinear: CarveSettings::default().bilinear,
            carve_concavity_gate: DEFAULT_CONCAVITY_GATE,
            carve_gate_radius: CarveSettings::default().gate_radius,
            cull_unobserved: DEFAULT_CULL_UNOBSERVED,
            carve_max_opened: DEFAULT_CARVE_MAX_OPENED,
            carve_max_spread: DEFAULT_CARVE_MAX_SPREAD,
            carve_min_lid_departure: DEFAULT_CARVE_MIN_LID_DEPARTURE,
            carve_debias: true,
            shading_anchor: DEFAULT_SHADING_ANCHOR,
            shading_depth: 0.0,
            shading_normals_rendered: 0.0,
            shading_radiance_rendered: DEFAULT_SHADING_RADIANCE_RENDERED,
            shading_depth_threshold: DEFAULT_SHADING_DEPTH_THRESHOLD,
            shading_shrink: true,
            shading_slack: DEFAULT_SHADING_SLACK,
            shading_rounds: DEFAULT_SHADING_ROUNDS,
            shading_steep_tilt: DEFAULT_SHADING_STEEP_TILT,
            shading_unscatter: DEFAULT_SHADING_UNSCATTER,
            carve_voxel: None,
            voxel: None,
            truncation: None,
            truncation_footprints: None,
            mesh_resolution: None,
            depth_crossing: None,
            readout_blur_px2: None,
            readout_blur_in_plane: PlaneReadout::default(),
            silhouette_carving: true,
            fuse_depth: true,
            hull_inside_distance: false,
            snap_to_hull: None,
            depth_consistency: None,
            edge_hull: true,
            edge_sigma: None,
            hollow_search: true,
        }
    }
}

impl MeshConfig {
    /// These settings fusing the rendered depth alone: a TSDF in which the masks cast no vote,
    /// as PGSR and 2DGS extract their meshes (the settings that read the masks' hull are off).
    /// Its mesh is the trained model's own geometry, which the default extraction, bounded by
    /// the masks, uses only to carve.
    pub fn depth_only(&self) -> MeshConfig {
        MeshConfig {
            fusion: Fusion::Tsdf,
            fuse_depth: true,
            silhouette_carving: false,
            hull_inside_distance: false,
            snap_to_hull: None,
            ..self.clone()
        }
    }

    /// These settings for a quicker extraction (an evaluation during training): the shading
    /// refinement in `shading_rounds` rounds instead of [`MeshConfig::shading_rounds`], or
    /// not at all with 0 (each round after the first reads the normals again on the mesh the
    /// last one moved).
    pub fn with_shading_rounds(&self, shading_rounds: usize) -> MeshConfig {
        if shading_rounds == 0 {
            MeshConfig {
                shading_anchor: 0.0,
                ..self.clone()
            }
        } else {
            MeshConfig {
                shading_rounds,
                ..self.clone()
            }
        }
    }

    /// The edge profile [`MeshConfig::edge_sigma`] asks for (`None`: the measured one).
    pub fn edge_profile(&self) -> Option<crate::hull::EdgeProfile> {
        self.edge_sigma.map(|sigma| {
            if sigma > 0.0 {
                crate::hull::EdgeProfile::Gaussian { sigma }
            } else {
                crate::hull::EdgeProfile::Box
            }
        })
    }

    /// The carving rule.
    pub fn carve(&self) -> CarveSettings {
        CarveSettings {
            min_views: self.carve_views as usize,
            margin_footprints: self.carve_margin,
            min_free_ratio: self.carve_free_ratio,
            slope_margin: self.carve_slope,
            bilinear: self.carve_bilinear,
            concavity_gate: self.carve_concavity_gate,
            gate_radius: self.carve_gate_radius,
        }
    }

    /// The settings that only [`Fusion::Tsdf`] reads, by their names in `config.json`: those
    /// set here (a carving run that sets one is refused rather than silently ignoring it).
    pub fn tsdf_settings_set(&self) -> Vec<&'static str> {
        let d = MeshConfig::default();
        [
            ("voxel", self.voxel.is_some()),
            ("truncation", self.truncation.is_some()),
            (
                "truncation_footprints",
                self.truncation_footprints.is_some(),
            ),
            (
                "silhouette_carving",
                self.silhouette_carving != d.silhouette_carving,
            ),
            ("fuse_depth", self.fuse_depth != d.fuse_depth),
            ("hull_inside_distance", self.hull_inside_distance),
            ("snap_to_hull", self.snap_to_hull.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect()
    }

    /// Checks every range and combination, naming the setting at fault.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(MeshError::InvalidArgument(m));
        self.carve().validate()?;
        for (name, v) in [
            ("carve_voxel", self.carve_voxel),
            ("voxel", self.voxel),
            ("truncation", self.truncation),
            ("truncation_footprints", self.truncation_footprints),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0)
            {
                return bad(format!("mesh.{name} must be a finite number > 0, got {v}"));
            }
        }
        if self.truncation.is_some() && self.truncation_footprints.is_some() {
            return bad("mesh.truncation and mesh.truncation_footprints exclude each other".into());
        }
        if self.mesh_resolution == Some(0) {
            return bad("mesh.mesh_resolution must be at least 1".into());
        }
        if let Some(s) = self.edge_sigma
            && !(s.is_finite() && s >= 0.0)
        {
            return bad(format!(
                "mesh.edge_sigma must be a number of pixels >= 0 (0: a box), got {s}"
            ));
        }
        if !(self.cull_unobserved.is_finite() && self.cull_unobserved >= 0.0) {
            return bad(format!(
                "mesh.cull_unobserved must be a finite number of footprints >= 0, got {}",
                self.cull_unobserved
            ));
        }
        if !(0.0..=1.0).contains(&self.carve_max_opened) {
            return bad(format!(
                "mesh.carve_max_opened must be a share in [0, 1], got {}",
                self.carve_max_opened
            ));
        }
        for (name, v) in [
            ("shading_anchor", self.shading_anchor),
            ("shading_depth", self.shading_depth),
            ("shading_depth_threshold", self.shading_depth_threshold),
            ("shading_slack", self.shading_slack),
            ("carve_max_spread", self.carve_max_spread),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!(
                    "mesh.{name} must be a finite number of footprints >= 0, got {v}"
                ));
            }
        }
        if !(self.carve_min_lid_departure.is_finite() && self.carve_min_lid_departure >= 0.0) {
            return bad(format!(
                "mesh.carve_min_lid_departure must be a finite ratio >= 0, got {}",
                self.carve_min_lid_departure
            ));
        }
        if !(0.0..=1.0).contains(&self.shading_normals_rendered) {
            return bad(format!(
                "mesh.shading_normals_rendered must be a share in [0, 1], got {}",
                self.shading_normals_rendered
            ));
        }
        if !(0.0..=1.0).contains(&self.shading_radiance_rendered) {
            return bad(format!(
                "mesh.shading_radiance_rendered must be a share in [0, 1], got {}",
                self.shading_radiance_rendered
            ));
        }
        if self.shading_rounds == 0 {
            return bad("mesh.shading_rounds must be at least 1".into());
        }
        if !(self.shading_steep_tilt > 0.0 && self.shading_steep_tilt < 90.0) {
            return bad(format!(
                "mesh.shading_steep_tilt must be an angle in (0, 90) degrees, got {}",
                self.shading_steep_tilt
            ));
        }
        if let Some(t) = self.depth_crossing
            && !(t > 0.0 && t < 1.0)
        {
            return bad(format!("mesh.depth_crossing must be in (0, 1), got {t}"));
        }
        if let Some(b) = self.readout_blur_px2
            && !(b.is_finite() && b >= 0.0)
        {
            return bad(format!(
                "mesh.readout_blur_px2 must be a finite number of pixels^2 >= 0, got {b}"
            ));
        }
        if let Some(f) = self.snap_to_hull {
            if !(f.is_finite() && f >= 0.0) {
                return bad(format!(
                    "mesh.snap_to_hull must be a finite number of footprints >= 0, got {f}"
                ));
            }
            if !(self.silhouette_carving && self.fuse_depth) {
                return bad(
                    "mesh.snap_to_hull needs silhouette_carving and fuse_depth (the hull and \
                     the depth)"
                        .into(),
                );
            }
        }
        if !self.fuse_depth && !self.silhouette_carving {
            return bad(
                "mesh.fuse_depth off fuses the masks alone: it needs silhouette_carving".into(),
            );
        }
        if let Some(c) = &self.depth_consistency {
            if !(c.min_agree >= 1 && c.min_agree <= c.neighbours) {
                return bad(format!(
                    "mesh.depth_consistency.min_agree must be in 1..=neighbours ({}), got {}",
                    c.neighbours, c.min_agree
                ));
            }
            if !(c.footprints.is_finite() && c.footprints > 0.0) {
                return bad(format!(
                    "mesh.depth_consistency.footprints must be positive, got {}",
                    c.footprints
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_bad_settings_are_named() {
        MeshConfig::default().validate().unwrap();
        assert!(MeshConfig::default().tsdf_settings_set().is_empty());
        for (c, word) in [
            (
                MeshConfig {
                    depth_crossing: Some(1.5),
                    ..Default::default()
                },
                "depth_crossing",
            ),
            (
                MeshConfig {
                    readout_blur_px2: Some(f64::NAN),
                    ..Default::default()
                },
                "readout_blur_px2",
            ),
            (
                MeshConfig {
                    readout_blur_px2: Some(-0.1),
                    ..Default::default()
                },
                "readout_blur_px2",
            ),
            (
                MeshConfig {
                    snap_to_hull: Some(-1.0),
                    ..Default::default()
                },
                "snap_to_hull",
            ),
            (
                MeshConfig {
                    snap_to_hull: Some(2.0),
                    silhouette_carving: false,
                    ..Default::default()
                },
                "snap_to_hull",
            ),
            (
                MeshConfig {
                    depth_consistency: Some(ConsistencySettings {
                        min_agree: 9,
                        ..Default::default()
                    }),
                    ..Default::default()
                },
                "min_agree",
            ),
            (
                MeshConfig {
                    carve_views: 0,
                    ..Default::default()
                },
                "agreeing views",
            ),
            (
                MeshConfig {
                    voxel: Some(f32::NAN),
                    ..Default::default()
                },
                "mesh.voxel",
            ),
            (
                MeshConfig {
                    shading_anchor: -1.0,
                    ..Default::default()
                },
                "mesh.shading_anchor",
            ),
            (
                MeshConfig {
                    shading_rounds: 0,
                    ..Default::default()
                },
                "mesh.shading_rounds",
            ),
            (
                MeshConfig {
                    shading_steep_tilt: 90.0,
                    ..Default::default()
                },
                "mesh.shading_steep_tilt",
            ),
            (
                MeshConfig {
                    shading_slack: f32::NAN,
                    ..Default::default()
                },
                "mesh.shading_slack",
            ),
            (
                MeshConfig {
                    edge_sigma: Some(-0.4),
                    ..Default::default()
                },
                "mesh.edge_sigma",
            ),
        ] {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(word), "{e}");
        }
        let c = MeshConfig {
            voxel: Some(0.01),
            snap_to_hull: Some(2.0),
            ..Default::default()
        };
        assert_eq!(c.tsdf_settings_set(), ["voxel", "snap_to_hull"]);
        let sigma = |s| MeshConfig {
            edge_sigma: s,
            ..Default::default()
        };
        assert_eq!(sigma(None).edge_profile(), None);
        assert_eq!(
            sigma(Some(0.0)).edge_profile(),
            Some(crate::hull::EdgeProfile::Box)
        );
        assert_eq!(
            sigma(Some(0.4)).edge_profile(),
            Some(crate::hull::EdgeProfile::Gaussian { sigma: 0.4 })
        );
    }

    #[test]
    fn the_depth_only_settings_fuse_the_depth_alone_and_stay_valid() {
        let with_hull = MeshConfig {
            fusion: Fusion::Tsdf,
            snap_to_hull: Some(2.0),
            hull_inside_distance: true,
            voxel: Some(0.02),
            depth_crossing: Some(0.9),
            ..Default::default()
        };
        for c in [MeshConfig::default(), with_hull] {
            c.validate().unwrap();
            let d = c.depth_only();
            d.validate().unwrap();
            assert_eq!(d.fusion, Fusion::Tsdf);
            assert!(d.fuse_depth && !d.silhouette_carving && !d.hull_inside_distance);
            assert_eq!(d.snap_to_hull, None);
            // The depth's own settings carry over.
            assert_eq!((d.voxel, d.depth_crossing), (c.voxel, c.depth_crossing));
        }
    }

    #[test]
    fn a_config_file_without_the_experiments_reads_with_their_defaults() {
        let c: MeshConfig = serde_json::from_str(r#"{"fusion": "tsdf", "voxel": 0.02}"#).unwrap();
        assert_eq!(c.fusion, Fusion::Tsdf);
        assert_eq!(c.voxel, Some(0.02));
        assert!(c.silhouette_carving && c.fuse_depth);
        assert!(serde_json::from_str::<MeshConfig>(r#"{"voxels": 1}"#).is_err());
    }
}
