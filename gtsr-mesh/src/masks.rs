//! The masks at the dataset's own resolution ([`MasksAlone`]): the bound the carving works
//! inside, the baseline every mesh is held to, and the images the shading steps read.

use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;

use crate::error::{MeshError, Result};
use crate::shading::ShadingImage;
use rayon::prelude::*;

/// The masks at the dataset's own resolution and what they give alone: the baseline every mesh
/// is held to, and the bound the carving works inside.
#[derive(Clone, Debug)]
pub struct MasksAlone {
    /// Every training view's camera and mask.
    pub views: Vec<(Camera, Vec<f32>)>,
    /// The masks alone ([`crate::hull::masks_mesh`]).
    pub mesh: TriMesh,
    /// The grid spacing of [`MasksAlone::mesh`] ([`crate::hull::masks_voxel`]).
    pub voxel: f32,
    /// The views' linear radiance at the masks' size, one value per pixel
    /// ([`crate::shading::linear_radiance`]), for [`crate::MeshConfig::shading_anchor`]; `None`: the
    /// mesh is not refined by the shading.
    pub radiance: Option<Vec<Vec<f32>>>,
    /// The images' own linear radiance, as [`MasksAlone::with_radiance`] gave it (kept when
    /// [`MasksAlone::with_rendered_radiance`] blends a render into `radiance`), for
    /// [`crate::MeshConfig::hollow_search`].
    pub images: Option<Vec<Vec<f32>>>,
    /// The hull from the masks' edges ([`MasksAlone::with_edge_distance`]); `None`: the
    /// extraction is bounded by [`MasksAlone::mesh`]'s field.
    pub edge_hull: Option<EdgeHull>,
    /// [`MasksAlone::hollow_reading`] once read: it depends on the masks and the images only,
    /// so every extraction of a run (and every clone of these masks) shares one search.
    pub(crate) hollow: std::sync::Arc<std::sync::OnceLock<crate::hollow::HollowReading>>,
}

/// The visual hull of the masks read as distances to their edges
/// ([`crate::hull::coverage_to_distance`]) rather than as coverage interpolated between pixel
/// centres: each silhouette placed where the coverage says its edge is, so that the
/// intersection of the cones does not collect every view's sub-pixel error on its inner side.
#[derive(Clone, Debug)]
pub struct EdgeHull {
    /// Per view, `0.5 - d` with `d` the signed distance in pixels to the mask's edge (what the
    /// hull functions read where they read a mask).
    pub views: Vec<Vec<f32>>,
    /// Its mesh, on the grid of [`MasksAlone::mesh`].
    pub mesh: TriMesh,
    /// The edge profile the masks were read with.
    pub profile: crate::hull::EdgeProfile,
    /// The masks' measured edge width ([`crate::hull::edge_width`]; 0 when none has an edge).
    pub width: f32,
}

impl MasksAlone {
    /// The masks' mesh on their own grid; `None` when nothing lies inside every mask.
    pub fn new(views: Vec<(Camera, Vec<f32>)>) -> Result<Option<Self>> {
        let borrowed = borrow(&views);
        let Some((lo, hi)) = crate::hull::hull_box(&borrowed)? else {
            return Ok(None);
        };
        let voxel = crate::hull::masks_voxel(&borrowed, lo, hi);
        let Some(mesh) = crate::hull::masks_mesh(&borrowed, Some(voxel))? else {
            return Ok(None);
        };
        Ok(Some(MasksAlone {
            views,
            mesh,
            voxel,
            radiance: None,
            images: None,
            edge_hull: None,
            hollow: Default::default(),
        }))
    }

    /// With each view's linear radiance (one value per pixel of its mask), for the shading
    /// refinement.
    pub fn with_radiance(mut self, radiance: Vec<Vec<f32>>) -> Result<Self> {
        if radiance.len() != self.views.len() {
            return Err(MeshError::size(
                "radiance views",
                self.views.len(),
                radiance.len(),
            ));
        }
        for (r, (_, m)) in radiance.iter().zip(&self.views) {
            if r.len() != m.len() {
                return Err(MeshError::size("radiance", m.len(), r.len()));
            }
            if r.iter().any(|x| !x.is_finite()) {
                return Err(MeshError::NonFinite {
                    what: "radiance".into(),
                });
            }
        }
        self.images = Some(radiance.clone());
        self.radiance = Some(radiance);
        // Other images, another reading.
        self.hollow = Default::default();
        Ok(self)
    }

    /// These masks with each view's radiance blended with `rendered` (the same views' linear
    /// radiance as a model renders them, at the masks' size): `(1 - share)` of the image and
    /// `share` of the render ([`crate::MeshConfig::shading_radiance_rendered`]). Errors without
    /// [`MasksAlone::radiance`], on a share outside `[0, 1]`, and where the renders' count or
    /// sizes differ from the masks' or hold a value that is not finite.
    pub fn with_rendered_radiance(mut self, rendered: &[Vec<f32>], share: f32) -> Result<Self> {
        if !(0.0..=1.0).contains(&share) {
            return Err(MeshError::InvalidArgument(format!(
                "the rendered radiance's share must lie in [0, 1], got {share}"
            )));
        }
        let Some(radiance) = self.radiance.as_mut() else {
            return Err(MeshError::InvalidArgument(
                "blending rendered radiance needs the images' radiance".into(),
            ));
        };
        if rendered.len() != radiance.len() {
            return Err(MeshError::size(
                "rendered radiance views",
                radiance.len(),
                rendered.len(),
            ));
        }
        for (image, render) in radiance.iter_mut().zip(rendered) {
            if render.len() != image.len() {
                return Err(MeshError::size(
                    "rendered radiance",
                    image.len(),
                    render.len(),
                ));
            }
            if render.iter().any(|x| !x.is_finite()) {
                return Err(MeshError::NonFinite {
                    what: "rendered radiance".into(),
                });
            }
            for (i, r) in image.iter_mut().zip(render) {
                *i += share * (r - *i);
            }
        }
        Ok(self)
    }

    /// Each view's camera, radiance and mask as the shading reads them
    /// ([`crate::shading::refine_by_shading`]); `None` without [`MasksAlone::radiance`].
    pub(crate) fn shading_images(&self) -> Option<Vec<ShadingImage<'_>>> {
        let radiance = self.radiance.as_ref()?;
        Some(
            (self.views.iter().zip(radiance))
                .map(|((camera, mask), radiance)| ShadingImage {
                    camera,
                    radiance,
                    mask: Some(mask),
                })
                .collect(),
        )
    }

    /// With the hull of the masks' edges ([`EdgeHull`]), which then bounds the extraction
    /// ([`MasksAlone::bound`], [`MasksAlone::bound_mesh`]); [`MasksAlone::mesh`] stays the
    /// baseline. The masks are read with the profile their edges' width says
    /// ([`crate::hull::edge_width`], [`crate::hull::EdgeProfile::from_width`]): a box filter, or the
    /// smooth filter of a renderer such as Blender Cycles. Errors when the edge hull is empty.
    pub fn with_edge_distance(self) -> Result<Self> {
        self.with_edge_profile(None)
    }

    /// [`MasksAlone::with_edge_distance`] with this profile (`None`: the measured one).
    pub fn with_edge_profile(mut self, profile: Option<crate::hull::EdgeProfile>) -> Result<Self> {
        let sized: Vec<(&[f32], usize, usize)> = (self.views.iter())
            .map(|(c, m)| (m.as_slice(), c.width as usize, c.height as usize))
            .collect();
        let width = crate::hull::edge_width(&sized).unwrap_or(0.0);
        let profile = profile.unwrap_or_else(|| crate::hull::EdgeProfile::from_width(width));
        let views = (sized.par_iter())
            .map(|&(m, w, h)| crate::hull::coverage_to_distance_with(m, w, h, profile))
            .collect::<Result<Vec<_>>>()?;
        let mesh = crate::hull::masks_mesh(&paired(&self.views, &views), Some(self.voxel))?
            .ok_or_else(|| {
                MeshError::InvalidArgument("the hull of the masks' edges is empty".into())
            })?;
        self.edge_hull = Some(EdgeHull {
            views,
            mesh,
            profile,
            width,
        });
        Ok(self)
    }

    /// The views as the hull functions take them: the masks' coverage.
    pub fn borrowed(&self) -> Vec<(Camera, &[f32])> {
        borrow(&self.views)
    }

    /// The views that bound the extraction: the edge hull's when there is one, else the masks.
    pub fn bound(&self) -> Vec<(Camera, &[f32])> {
        match &self.edge_hull {
            Some(e) => paired(&self.views, &e.views),
            None => self.borrowed(),
        }
    }

    /// The mesh of [`MasksAlone::bound`].
    pub fn bound_mesh(&self) -> &TriMesh {
        self.edge_hull.as_ref().map_or(&self.mesh, |e| &e.mesh)
    }

    /// The hollow behind [`MasksAlone::mesh`] that [`MasksAlone::images`] read
    /// ([`crate::hollow::read_hollow`] at its default settings, the bound being the masks'
    /// field on this mesh's grid); `None` without images or when nothing lies inside every
    /// mask. The search runs on the first call; later calls, on these masks or a clone of
    /// them, return the same reading.
    pub fn hollow_reading(&self) -> Result<Option<&crate::hollow::HollowReading>> {
        if let Some(r) = self.hollow.get() {
            return Ok(Some(r));
        }
        let Some(radiance) = self.images.as_ref() else {
            return Ok(None);
        };
        let images: Vec<ShadingImage> = (self.views.iter().zip(radiance))
            .map(|((camera, mask), radiance)| ShadingImage {
                camera,
                radiance,
                mask: Some(mask),
            })
            .collect();
        let borrowed = self.borrowed();
        let Some((lo, hi)) = crate::hull::hull_box(&borrowed)? else {
            return Ok(None);
        };
        let bound = crate::hull::masks_grid(&borrowed, lo, hi, self.voxel)?;
        let settings = crate::hollow::HollowSettings::default();
        let reading = crate::hollow::read_hollow(&self.mesh, &bound, &images, &settings)?;
        // A reading another thread stored first is the same reading.
        Ok(Some(self.hollow.get_or_init(|| reading)))
    }
}

fn borrow(views: &[(Camera, Vec<f32>)]) -> Vec<(Camera, &[f32])> {
    views.iter().map(|(c, m)| (*c, m.as_slice())).collect()
}

/// The views' cameras with other images of the same size (the edge hull's).
fn paired<'a>(views: &'a [(Camera, Vec<f32>)], images: &'a [Vec<f32>]) -> Vec<(Camera, &'a [f32])> {
    views
        .iter()
        .zip(images)
        .map(|((c, _), d)| (*c, d.as_slice()))
        .collect()
}
