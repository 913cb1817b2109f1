//! The model read out for the mesh: per view, the surface set's depth, normal, plane distance
//! and coverage (what the fusion and the carving read), and its C_SH radiance as an image
//! (what the shading refinement and the test metrics read).
//!
//! The readout is a detached copy of the model, with the screen-space blur the mesh settings
//! ask for, or each splat blurred in its own plane ([`PlaneBlur`]): a splat's plane keeps its
//! depth where the screen's blur lets a nearer surface spill past an outline.

use burn::tensor::Tensor;
use gtsr_render_kernels::Camera;

use crate::error::ModelError;
use crate::gaussians::host_vec;
use crate::model::{GeometryMaps, Model};

/// Where the readout blurs each splat in its own plane instead of on the screen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlaneBlur {
    /// Nowhere: the screen's blur everywhere.
    Off,
    /// Everywhere.
    Everywhere,
    /// At the outlines only: the plane's maps where the screen's nearer surface only spills
    /// over ([`GeometryMaps::with_farther`]).
    Outlines,
}

/// How the model is read out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadoutSettings {
    /// The blur of the readout, px² (`None`: the training's).
    pub blur_px2: Option<f64>,
    /// Where the blur is in each splat's plane.
    pub plane_blur: PlaneBlur,
    /// `Some(t)`: the geometry of the splat at which the transmittance first falls to `t`
    /// ([`Model::render_depth_crossing`]) instead of the blended maps.
    pub depth_crossing: Option<f64>,
    /// With [`PlaneBlur::Outlines`]: how many pixel footprints the plane's depth must lie
    /// behind the screen's for the plane's maps to be taken.
    pub outline_gap_footprints: f64,
}

/// The model(s) whose geometry is read: the training's render (or a copy with the settings'
/// blur), and with [`PlaneBlur::Outlines`] the copy with the blur in each splat's plane.
pub struct Readout {
    model: Model,
    outlines: Option<Model>,
    depth_crossing: Option<f64>,
    outline_gap_footprints: f64,
}

/// A view's geometry on the host, row-major: z-depth, camera-space normals (3 a pixel,
/// premultiplied by the coverage), the blended plane distance, the coverage and the pixels'
/// ray directions (3 a pixel, camera frame).
#[derive(Clone, Debug, PartialEq)]
pub struct HostGeometry {
    /// Z-depth per pixel (the unbiased depth of PGSR).
    pub depth: Vec<f32>,
    /// Camera-space normals, 3 per pixel.
    pub normal: Vec<f32>,
    /// Blended plane distance per pixel.
    pub plane: Vec<f32>,
    /// Surface coverage per pixel.
    pub coverage: Vec<f32>,
    /// Ray directions, 3 per pixel.
    pub rays: Vec<f32>,
}

impl Readout {
    /// The readout of `model` under `settings` (detached copies: no gradient flows).
    pub fn new(model: &Model, settings: &ReadoutSettings) -> Readout {
        let screen = || {
            settings
                .blur_px2
                .map(|b| model.detached_with_blur(b))
                .unwrap_or_else(|| model.detached())
        };
        let plane = || model.detached_with_plane_blur(settings.blur_px2.unwrap_or(model.blur_px2));
        let (model, outlines) = match settings.plane_blur {
            PlaneBlur::Off => (screen(), None),
            PlaneBlur::Everywhere => (plane(), None),
            PlaneBlur::Outlines => (screen(), Some(plane())),
        };
        Readout {
            model,
            outlines,
            depth_crossing: settings.depth_crossing,
            outline_gap_footprints: settings.outline_gap_footprints,
        }
    }

    /// The surface geometry seen from `camera` through `rays` (`[H, W, 3]`): the blended maps,
    /// or those of the crossing splat; at the outlines, the plane's maps where the screen's
    /// nearer surface only spills over.
    pub fn geometry(&self, camera: &Camera, rays: &Tensor<3>) -> Result<GeometryMaps, ModelError> {
        let read = |model: &Model| -> Result<GeometryMaps, ModelError> {
            match self.depth_crossing {
                Some(t) => model.render_depth_crossing(camera, rays, t),
                None => model.render_depth(camera, rays),
            }
        };
        let maps = read(&self.model)?;
        Ok(match &self.outlines {
            Some(plane) => maps.with_farther(read(plane)?, camera.fx, self.outline_gap_footprints),
            None => maps,
        })
    }

    /// [`Readout::geometry`] on the host, with the rays.
    pub fn host_geometry(
        &self,
        camera: &Camera,
        rays: &Tensor<3>,
    ) -> Result<HostGeometry, ModelError> {
        let g = self.geometry(camera, rays)?;
        Ok(HostGeometry {
            normal: host_vec(g.normal),
            rays: host_vec(rays.clone()),
            depth: host_vec(g.depth),
            coverage: host_vec(g.coverage),
            plane: host_vec(g.plane),
        })
    }
}

/// A C_SH render as an image: its values on the host, clamped to `[0, 1]` as the images are.
pub fn rendered_image(c_sh: Tensor<3>) -> Vec<f32> {
    host_vec(c_sh).iter().map(|x| x.clamp(0.0, 1.0)).collect()
}
