//! The mesh extraction settings: one serde and [`clap::Args`] struct that a run records in its
//! `config.json` and a front end flattens into its command line.
//!
//! Each argument's id is its path in a run's `config.json` (`mesh.carve_views`), as for the
//! training settings of `gtsr-model`, so that a front end can overlay what the user gave on a
//! saved configuration. The fusion variants that were measured and not kept (see
//! `docs/results.md`) are fields of the file only, not command-line flags.

use clap::ValueEnum;
use serde::{Deserialize, Serialize};

use crate::carve::{CarveSettings, MAX_CARVE_VIEWS};
use crate::consistency::ConsistencySettings;
use crate::error::{EvalError, Result};

/// How the mesh is extracted.
#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fusion {
    /// The masks at the dataset's resolution bound the object with sub-pixel placement, and
    /// the rendered depth carves inside that bound where enough views agree (needs a mask on
    /// every view; [`crate::carve_mesh`]).
    Carve,
    /// TSDF fusion of the rendered depth, with the masks' hull when there are masks
    /// ([`crate::TsdfVolume`]).
    Tsdf,
}

fn parse_positive(s: &str) -> std::result::Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be a finite number > 0, got {s}"))
    }
}

fn parse_non_negative(s: &str) -> std::result::Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("must be a finite number >= 0, got {s}"))
    }
}

fn parse_unit(s: &str) -> std::result::Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("must be in [0, 1], got {s}"))
    }
}

/// Every mesh extraction setting. Scenes without masks always use [`Fusion::Tsdf`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(default, deny_unknown_fields)]
pub struct MeshConfig {
    /// How the mesh is extracted: `carve` (the masks at the dataset's resolution bound the
    /// object, the rendered depth carves inside where views agree; needs masks) or `tsdf`.
    #[arg(long = "fusion", id = "mesh.fusion", value_name = "METHOD", value_enum, default_value_t = Fusion::Carve)]
    pub fusion: Fusion,
    /// Carving: the depth views that must each put a point in front of their rendered surface.
    #[arg(long = "carve-views", id = "mesh.carve_views", value_name = "N", default_value_t = 3,
          value_parser = clap::value_parser!(u64).range(1..=MAX_CARVE_VIEWS as u64))]
    pub carve_views: u64,
    /// Carving: how far in front, in that view's training-pixel footprints.
    #[arg(long = "carve-margin", id = "mesh.carve_margin", value_name = "FOOTPRINTS",
          default_value_t = 3.0, value_parser = parse_non_negative)]
    pub carve_margin: f32,
    /// Carving: the least share of the views that put a point in front of their surface among
    /// those that put it in front or near it (the rest see it hidden and do not count).
    #[arg(long = "carve-free-ratio", id = "mesh.carve_free_ratio", value_name = "SHARE",
          default_value_t = 0.5, value_parser = parse_unit)]
    pub carve_free_ratio: f32,
    /// Carving: the grid spacing (scene units). Default: 0.75 of the masks' pixel footprint
    /// at the object, at the dataset's resolution.
    #[arg(long = "carve-voxel", id = "mesh.carve_voxel", value_name = "SIZE", value_parser = parse_positive)]
    pub carve_voxel: Option<f32>,
    /// TSDF: the voxel size (scene units). Default: the radius of the mesh box / 256.
    #[arg(long = "voxel", id = "mesh.voxel", value_name = "SIZE", value_parser = parse_positive)]
    pub voxel: Option<f32>,
    /// TSDF: the truncation (scene units). Default: the larger of 0.75 times the radius of the
    /// mesh box and 6 training-pixel footprints at the object.
    #[arg(long = "truncation", id = "mesh.truncation", value_name = "DIST",
          value_parser = parse_positive, conflicts_with = "mesh.truncation_footprints")]
    pub truncation: Option<f32>,
    /// TSDF: the truncation in training-pixel footprints at the mesh box's centre.
    #[arg(long = "truncation-footprints", id = "mesh.truncation_footprints",
          value_name = "FOOTPRINTS", value_parser = parse_positive)]
    pub truncation_footprints: Option<f32>,
    /// Longest image side of the depth maps fused into the mesh (the trained Gaussians are
    /// rendered again at this size). Default: the training resolution; at most the dataset's.
    #[arg(long = "mesh-resolution", id = "mesh.mesh_resolution", value_name = "PIXELS",
          value_parser = clap::value_parser!(u32).range(1..))]
    pub mesh_resolution: Option<u32>,
    /// TSDF: fuse, per pixel, the depth of the surface splat at which the transmittance falls
    /// to this value (0.5: the median depth of 2DGS) instead of the blended depth of PGSR; the
    /// test-view depth metrics then measure this depth. In (0, 1).
    #[arg(skip)]
    pub depth_crossing: Option<f64>,
    /// TSDF on a masked scene: keep the masks' visual hull in the volume, so the surface never
    /// leaves a silhouette ([`crate::TsdfVolume::with_silhouette_carving`]). Off: pixels
    /// outside the masks cast no votes (depth alone, as PGSR and 2DGS fuse).
    #[arg(skip = true)]
    pub silhouette_carving: bool,
    /// TSDF: fuse the rendered depth. Off: the masks alone on the fusion grid.
    #[arg(skip = true)]
    pub fuse_depth: bool,
    /// TSDF with the hull: where no depth was fused inside it, the hull's own distance instead
    /// of `-truncation` ([`crate::TsdfVolume::with_hull_inside_distance`]).
    #[arg(skip)]
    pub hull_inside_distance: bool,
    /// TSDF with the hull: depth samples less than this many footprints behind the masks' hull
    /// (or in front of it) are replaced by the hull's depth ([`crate::tsdf::snap_to_hull`]).
    #[arg(skip)]
    pub snap_to_hull: Option<f32>,
    /// TSDF: keep a depth sample only where this many neighbouring views agree with it
    /// ([`crate::filter_consistent`]).
    #[arg(skip)]
    pub depth_consistency: Option<ConsistencySettings>,
}

impl Default for MeshConfig {
    fn default() -> Self {
        MeshConfig {
            fusion: Fusion::Carve,
            carve_views: CarveSettings::default().min_views as u64,
            carve_margin: CarveSettings::default().margin_footprints,
            carve_free_ratio: CarveSettings::default().min_free_ratio,
            carve_voxel: None,
            voxel: None,
            truncation: None,
            truncation_footprints: None,
            mesh_resolution: None,
            depth_crossing: None,
            silhouette_carving: true,
            fuse_depth: true,
            hull_inside_distance: false,
            snap_to_hull: None,
            depth_consistency: None,
        }
    }
}

impl MeshConfig {
    /// The carving rule.
    pub fn carve(&self) -> CarveSettings {
        CarveSettings {
            min_views: self.carve_views as usize,
            margin_footprints: self.carve_margin,
            min_free_ratio: self.carve_free_ratio,
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
            ("depth_crossing", self.depth_crossing.is_some()),
            (
                "silhouette_carving",
                self.silhouette_carving != d.silhouette_carving,
            ),
            ("fuse_depth", self.fuse_depth != d.fuse_depth),
            ("hull_inside_distance", self.hull_inside_distance),
            ("snap_to_hull", self.snap_to_hull.is_some()),
            ("depth_consistency", self.depth_consistency.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect()
    }

    /// Checks every range and combination, naming the setting at fault.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(EvalError::InvalidArgument(m));
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
        if let Some(t) = self.depth_crossing
            && !(t > 0.0 && t < 1.0)
        {
            return bad(format!("mesh.depth_crossing must be in (0, 1), got {t}"));
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
