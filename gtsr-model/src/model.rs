//! The GTSR model and its render passes.
//!
//! One step renders, for a camera:
//! 1. **C_SH**: surface and interior sets in one sorted blend; each surface Gaussian's opacity is
//!    multiplied by the Schlick Fresnel term of its normal and view direction.
//! 2. **Geometry**: the surface set alone, blending per Gaussian the camera-space normal, the
//!    plane distance and (with PBR) base colour and roughness; the unbiased depth follows.
//! 3. **Scattering**: the interior set alone, its SH colour (the scattering map of C_PBR).
//!
//! C_PBR is then shaded per pixel from these maps. When nothing but the surface set is blended
//! with its plain opacity (stage 1, or no interior set), passes 1 and 2 blend the same splats
//! with the same weights, so they are merged into one pass with more channels. A component that
//! is off allocates nothing and renders nothing; [`Renders::passes`] counts raster passes.

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_render_kernels::planes::gaussian_planes;
use gtsr_render_kernels::{AlphaCutoff, Camera, SplatConfig, SplatInputs, render};

use crate::config::Components;
use crate::error::ModelError;
use crate::gaussians::{GaussianSet, ParamKind, SetKind, host_vec, logistic};
use crate::geometry::{normal_axis, to_camera, unbiased_depth};
use crate::layout;
use crate::pbr::{self, GBuffer, ShadingParams};
use crate::sh;

/// The model: the surface set, the optional interior set and the light.
#[derive(Clone, Debug)]
pub struct Model {
    /// The switches this model was built with.
    pub components: Components,
    /// Surface Gaussians.
    pub surface: GaussianSet,
    /// Interior Gaussians (added at stage 2 when the component is on).
    pub interior: Option<GaussianSet>,
    /// `[1, 1]` log intensity of the co-located point light (with PBR).
    pub log_light: Option<Tensor<2>>,
    /// SH degree in use now (grows to `components.sh_degree`).
    pub sh_degree: u32,
    /// Screen-space blur of every render, pixels^2 ([`SplatConfig::blur_px2`]).
    pub blur_px2: f64,
    /// Whether every render scales the opacities by the blur's compensation
    /// ([`SplatConfig::compensate_blur`], applied by the kernels), as
    /// [`crate::config::TrainConfig::compensate_blur`].
    pub compensate_blur: bool,
    /// The least opacity of a surface Gaussian (`[0, 1)`; 0: the plain logistic), as
    /// [`crate::config::TrainConfig::surface_opacity_floor`].
    pub surface_opacity_floor: f64,
    /// Blur in each splat's own plane, in pixels^2 at the splat's depth: every render adds
    /// `plane_blur_px2 (z / fx)^2` to the variance along a Gaussian's two largest axes (`z` its
    /// depth in the camera, `z / fx` its pixel footprint). A splat facing the camera then
    /// covers what the screen-space blur [`Model::blur_px2`] would make it cover; one seen
    /// edge-on (at an occluding outline) does not grow across the outline. 0 in training; set
    /// for readouts by [`Model::detached_with_plane_blur`].
    pub plane_blur_px2: f64,
}

/// What a render should produce.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    /// Stage 2: interior set, Fresnel, PBR (as switched on).
    pub stage2: bool,
    /// Produce the geometry maps (normal, plane distance, depth).
    pub geometry: bool,
    /// Attach screen-space offset leaves so `dL/d mean2d` can be read for densification.
    pub track_offsets: bool,
    /// Shading constants for C_PBR.
    pub shading: ShadingParams,
    /// Encode C_PBR with the sRGB curve.
    pub pbr_srgb: bool,
    /// With `geometry`: also blend the plane moments of [`GeometryMaps::spread`]
    /// ([`SPREAD_CHANNELS`] more channels in the geometry pass).
    pub spread: bool,
}

/// Geometry and material maps of the surface set.
#[derive(Clone, Debug)]
pub struct GeometryMaps {
    /// `[H, W, 3]` camera-space normal (blended, premultiplied by coverage).
    pub normal: Tensor<3>,
    /// `[H, W]` plane distance (blended).
    pub plane: Tensor<2>,
    /// `[H, W]` surface coverage (alpha of the surface blend, without Fresnel).
    pub coverage: Tensor<2>,
    /// `[H, W]` unbiased z-depth.
    pub depth: Tensor<2>,
    /// `[H, W, 3]` base colour (premultiplied), with PBR.
    pub base: Option<Tensor<3>>,
    /// `[H, W]` roughness (premultiplied), with PBR.
    pub roughness: Option<Tensor<2>>,
    /// `[H, W]` when asked for ([`RenderOptions::spread`]): the variance, over the splats
    /// blended at each pixel and weighted by their blend weights, of the inverse depth at
    /// which each splat's plane crosses the pixel's ray (`E[u^2] - E[u]^2` with `u = 1 / t`,
    /// clamped at 0; inverse scene units squared). Zero for one layer of splats, however
    /// curved, large for a stack of faint layers one behind another: what 2DGS's depth
    /// distortion measures, from nine blended plane moments (`m = n / d` and its products, for
    /// a splat plane `n . x = -d`: the inverse depth along a ray `r` is `-(m . r)`).
    pub spread: Option<Tensor<2>>,
    /// Tile-splat pairs of the pass that rendered these maps (the blend's work: each pair is
    /// one 16x16 tile that one splat touches).
    pub tile_splats: u64,
}

/// Everything one render produced.
#[derive(Clone, Debug)]
pub struct Renders {
    /// `[H, W, 3]` C_SH.
    pub c_sh: Tensor<3>,
    /// `[H, W]` alpha of the C_SH blend.
    pub alpha_sh: Tensor<2>,
    /// Geometry maps when asked for.
    pub geometry: Option<GeometryMaps>,
    /// `[H, W, 3]` scattering map (interior set), with PBR and the interior set.
    pub scatter: Option<Tensor<3>>,
    /// `[H, W, 3]` C_PBR as compared with the images (sRGB-encoded when configured).
    pub c_pbr: Option<Tensor<3>>,
    /// Raster passes run.
    pub passes: usize,
    /// Tile-splat pairs summed over the passes (see [`GeometryMaps::tile_splats`]): with the
    /// pass count, what the render cost.
    pub tile_splats: u64,
    /// `[Ns]` screen radii of the surface set in the C_SH pass (0: not visible).
    pub surface_radii: Vec<f32>,
    /// `[Ni]` screen radii of the interior set.
    pub interior_radii: Vec<f32>,
    /// Offset leaves of the surface set (when tracked).
    pub surface_offsets: Option<Tensor<2>>,
    /// Offset leaves of the interior set (when tracked).
    pub interior_offsets: Option<Tensor<2>>,
}

/// Per-Gaussian quantities of one set for one camera.
struct Prepared {
    means: Tensor<2>,
    quats: Tensor<2>,
    scales: Tensor<2>,
    opacities: Tensor<1>,
    /// The SH colours for the camera; `None` where the caller splats other features.
    colours: Option<Tensor<2>>,
    /// `[N, 8]` each Gaussian's plane as the camera sees it
    /// ([`gtsr_render_kernels::planes::gaussian_planes`]: world normal, camera normal, plane
    /// distance, cosine to the camera); `None` where no normals are needed.
    planes: Option<Tensor<2>>,
    offsets: Option<Tensor<2>>,
}

impl Prepared {
    fn colours(&self) -> Tensor<2> {
        self.colours.clone().expect("colours prepared")
    }
}

/// The kernels' inputs for a prepared set with `opacities` and `features`.
fn splat_inputs(p: &Prepared, opacities: Tensor<1>, features: Tensor<2>) -> SplatInputs {
    SplatInputs {
        means: p.means.clone(),
        quats: p.quats.clone(),
        scales: p.scales.clone(),
        opacities,
        features,
        xy_offsets: p.offsets.clone(),
    }
}

impl GeometryMaps {
    /// These maps, with `farther`'s (the same camera's, read another way) at the pixels where
    /// `farther` is a surface (coverage at least 0.5) whose depth lies more than `gap`
    /// footprints (`depth / focal`) behind this depth. With `farther` read with the blur in
    /// each splat's plane ([`Model::detached_with_plane_blur`]) these are the pixels over which
    /// a nearer surface only spills past its outline. The optional maps (`base`, `roughness`,
    /// `spread`) are this one's.
    pub fn with_farther(self, farther: GeometryMaps, focal: f64, gap: f64) -> GeometryMaps {
        let [h, w] = self.depth.dims();
        let near = self.depth.clone().clamp_min(1e-12);
        let take = ((farther.depth.clone() - self.depth.clone()) * focal / near)
            .greater_elem(gap)
            .bool_and(farther.coverage.clone().greater_equal_elem(0.5));
        let take3 = take.clone().reshape([h, w, 1]).expand([h, w, 3]);
        GeometryMaps {
            normal: self.normal.mask_where(take3, farther.normal),
            plane: self.plane.mask_where(take.clone(), farther.plane),
            coverage: self.coverage.mask_where(take.clone(), farther.coverage),
            depth: self.depth.mask_where(take, farther.depth),
            tile_splats: self.tile_splats + farther.tile_splats,
            ..self
        }
    }
}

/// The depth-only [`GeometryMaps`] from `[H, W, 4]` maps of normal and plane distance.
fn depth_maps(
    maps: Tensor<3>,
    coverage: Tensor<2>,
    rays: &Tensor<3>,
    tile_splats: u64,
) -> GeometryMaps {
    let normal = layout::channels(&maps, 0..3);
    let plane = layout::channel(&maps, 3);
    let depth = unbiased_depth(&normal, &plane, rays);
    GeometryMaps {
        normal,
        plane,
        coverage,
        depth,
        base: None,
        roughness: None,
        spread: None,
        tile_splats,
    }
}

fn cat_prepared(a: &Prepared, b: &Prepared) -> Prepared {
    let cat2 = |x: &Tensor<2>, y: &Tensor<2>| Tensor::cat(vec![x.clone(), y.clone()], 0);
    Prepared {
        means: cat2(&a.means, &b.means),
        quats: cat2(&a.quats, &b.quats),
        scales: cat2(&a.scales, &b.scales),
        opacities: Tensor::cat(vec![a.opacities.clone(), b.opacities.clone()], 0),
        colours: a
            .colours
            .as_ref()
            .zip(b.colours.as_ref())
            .map(|(x, y)| cat2(x, y)),
        planes: None,
        offsets: match (&a.offsets, &b.offsets) {
            (Some(x), Some(y)) => Some(cat2(x, y)),
            _ => None,
        },
    }
}

/// Screen radii (column 0 of a render's `aux`) and tile-splat pairs (the sum of column 2), in
/// one read.
fn radii_and_tiles(aux: Tensor<2>) -> (Vec<f32>, u64) {
    let v = host_vec(aux);
    let rows = v.chunks_exact(4);
    (
        rows.clone().map(|r| r[0]).collect(),
        rows.map(|r| r[2].max(0.0) as u64).sum(),
    )
}

impl Model {
    /// The render settings of every pass: black background, 3DGS's hard cut-off, the model's
    /// blur and its compensation.
    fn splat_config(&self, camera: &Camera, channels: usize) -> SplatConfig {
        SplatConfig {
            camera: camera.clone(),
            background: vec![0.0; channels],
            cutoff: AlphaCutoff::Hard,
            blur_px2: self.blur_px2,
            compensate_blur: self.compensate_blur,
        }
    }

    /// One pass: the prepared set `p` with `opacities` and `features`, in `camera`.
    fn splat(
        &self,
        p: &Prepared,
        opacities: Tensor<1>,
        features: Tensor<2>,
        camera: &Camera,
    ) -> Result<gtsr_render_kernels::RenderOutput, ModelError> {
        let cfg = self.splat_config(camera, features.dims()[1]);
        Ok(render(splat_inputs(p, opacities, features), &cfg)?)
    }

    /// `[N]` opacities of `set`: the surface set's above [`Model::surface_opacity_floor`].
    pub fn opacities(&self, set: &GaussianSet) -> Tensor<1> {
        match set.kind {
            SetKind::Surface => set.opacities(self.surface_opacity_floor),
            SetKind::Interior => set.opacities(0.0),
        }
    }

    /// Device of the parameters.
    pub fn device(&self) -> Device {
        self.surface.req(ParamKind::Means).device()
    }

    /// Number of surface and interior Gaussians.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.surface.len(),
            self.interior.as_ref().map_or(0, |s| s.len()),
        )
    }

    /// A copy whose parameters do not require gradients: its renders record no backward
    /// steps. Evaluation and extraction render through it; with the training parameters each
    /// render would leave its graph (and the kernels' saved state) in memory, since no
    /// `backward` call consumes it. (`Tensor::detach` alone keeps a leaf's `require_grad`.)
    pub fn detached(&self) -> Model {
        let detach = |set: &GaussianSet| GaussianSet {
            kind: set.kind,
            params: set
                .params
                .iter()
                .map(|(k, t)| (*k, t.clone().set_require_grad(false)))
                .collect(),
        };
        Model {
            components: self.components,
            surface: detach(&self.surface),
            interior: self.interior.as_ref().map(detach),
            log_light: self
                .log_light
                .as_ref()
                .map(|l| l.clone().set_require_grad(false)),
            sh_degree: self.sh_degree,
            blur_px2: self.blur_px2,
            compensate_blur: self.compensate_blur,
            surface_opacity_floor: self.surface_opacity_floor,
            plane_blur_px2: self.plane_blur_px2,
        }
    }

    /// [`Model::detached`] with every render's blur moved from the screen into each splat's
    /// plane ([`Model::plane_blur_px2`]): the screen-space blur is 0 and the plane's is
    /// `blur_px2`. Geometry read so keeps the coverage the blur gives a splat that faces the
    /// camera, without the spill of a splat seen edge-on past an occluding outline (the mesh
    /// setting `readout_blur_in_plane`).
    pub fn detached_with_plane_blur(&self, blur_px2: f64) -> Model {
        Model {
            blur_px2: 0.0,
            plane_blur_px2: blur_px2,
            ..self.detached()
        }
    }

    /// [`Model::detached`] with every render's screen-space blur set to `blur_px2` (pixels^2)
    /// instead of the training's: geometry read where the splats themselves are, without the
    /// blur that stands for the images' pixel filter (the mesh setting `readout_blur_px2`).
    pub fn detached_with_blur(&self, blur_px2: f64) -> Model {
        Model {
            blur_px2,
            ..self.detached()
        }
    }

    /// Light intensity (with PBR).
    pub fn light(&self) -> Option<Tensor<2>> {
        self.log_light.as_ref().map(|l| l.clone().exp())
    }

    /// What the kernels need of `set` for `camera`: means, rotations, blurred scales and
    /// opacities always; world normals facing the camera with `normals`; SH colours in the
    /// camera's view directions with `colours` (depth-only renders splat other features);
    /// tracked screen offsets with `offsets` when the set's means are differentiable.
    fn prepare(
        &self,
        set: &GaussianSet,
        camera: &Camera,
        normals: bool,
        colours: bool,
        offsets: bool,
    ) -> Prepared {
        let means = set.req(ParamKind::Means).clone();
        let quats = set.req(ParamKind::Rotations).clone();
        let log_scales = set.req(ParamKind::LogScales).clone();
        let centre = camera.centre();
        let colours = colours.then(|| {
            sh::colours(
                set.req(ParamKind::ShDc),
                set.get(ParamKind::ShRest),
                &means,
                centre,
                self.sh_degree,
            )
        });
        let planes = normals
            .then(|| gaussian_planes(quats.clone(), log_scales.clone(), means.clone(), camera));
        let n = set.len();
        Prepared {
            opacities: self.opacities(set),
            scales: self.plane_blurred(log_scales.clone().exp(), &log_scales, &means, camera),
            means,
            quats,
            colours,
            planes,
            offsets: (offsets && set.req(ParamKind::Means).is_require_grad()).then(|| {
                Tensor::<2>::zeros(
                    [n, 2],
                    (
                        &set.req(ParamKind::Means).device(),
                        set.req(ParamKind::Means).dtype(),
                    ),
                )
                .require_grad()
            }),
        }
    }

    /// `scales` `[N, 3]` with [`Model::plane_blur_px2`] added along each Gaussian's two largest
    /// axes (the smallest of `log_scales` is its normal); `scales` itself when it is 0.
    fn plane_blurred(
        &self,
        scales: Tensor<2>,
        log_scales: &Tensor<2>,
        means: &Tensor<2>,
        camera: &Camera,
    ) -> Tensor<2> {
        if self.plane_blur_px2 <= 0.0 {
            return scales;
        }
        let z = layout::cols(&to_camera(means, camera), 2..3).clamp_min(camera.near);
        let added = (z / camera.fx).powi_scalar(2) * self.plane_blur_px2;
        let in_plane = normal_axis(log_scales).neg() + 1.0;
        (scales.powi_scalar(2) + in_plane * added).sqrt()
    }

    /// Geometry (and material) features `[N, 4 or 8]` of the surface set for `camera`; with
    /// `spread` [`SPREAD_CHANNELS`] more, from [`spread_features`].
    fn geometry_features(
        &self,
        p: &Prepared,
        camera: &Camera,
        material: bool,
        spread: bool,
    ) -> Tensor<2> {
        let n = p.means.dims()[0];
        let planes = p.planes.as_ref().expect("normals prepared");
        // The camera-space normal and the plane distance, side by side in the planes.
        let normal_plane = layout::cols(planes, 3..7);
        let spread_feats = spread.then(|| {
            spread_features(
                &layout::cols(&normal_plane, 0..3),
                &layout::cols(&normal_plane, 3..4),
                camera,
            )
        });
        let mut f = vec![normal_plane];
        if material {
            f.push(logistic(self.surface.req(ParamKind::BaseColour).clone()));
            f.push(logistic(self.surface.req(ParamKind::Roughness).clone()));
        }
        f.extend(spread_feats);
        let out = layout::cat_cols(f);
        debug_assert_eq!(out.dims()[0], n);
        out
    }

    /// Renders one camera. `rays` are the camera's `[H, W, 3]` pixel rays
    /// ([`crate::geometry::pixel_rays`]).
    pub fn render(
        &self,
        camera: &Camera,
        rays: &Tensor<3>,
        opts: RenderOptions,
    ) -> Result<Renders, ModelError> {
        let c = self.components;
        let interior = if opts.stage2 && c.interior {
            self.interior.as_ref()
        } else {
            None
        };
        let fresnel = c.fresnel && interior.is_some();
        let pbr = opts.stage2 && c.pbr && opts.geometry;
        let material = pbr && self.surface.get(ParamKind::BaseColour).is_some();
        let need_normals = opts.geometry || fresnel;
        let surf = self.prepare(
            &self.surface,
            camera,
            need_normals,
            true,
            opts.track_offsets,
        );
        let ns = self.surface.len();
        let mut passes = 0;
        let mut tile_splats = 0;
        let mut geometry_out: Option<(Tensor<3>, Tensor<2>, u64)> = None;

        // C_SH (merged with the geometry pass when they blend the same splats alike).
        let merged = interior.is_none() && !fresnel;
        let (c_sh, alpha_sh, surface_radii, interior_radii, int_prepared) = if merged {
            let mut feats = vec![surf.colours()];
            if opts.geometry {
                feats.push(self.geometry_features(&surf, camera, material, opts.spread));
            }
            let out = self.splat(
                &surf,
                surf.opacities.clone(),
                layout::cat_cols(feats),
                camera,
            )?;
            passes += 1;
            let (radii, tiles) = radii_and_tiles(out.aux);
            tile_splats += tiles;
            let ch = out.image.dims()[2];
            let c_sh = layout::channels(&out.image, 0..3);
            if opts.geometry {
                geometry_out = Some((
                    layout::channels(&out.image, 3..ch),
                    out.alpha.clone(),
                    tiles,
                ));
            }
            (c_sh, out.alpha, radii, Vec::new(), None)
        } else {
            let surf_op = if fresnel {
                let planes = surf.planes.as_ref().expect("normals prepared");
                let cos = layout::col(planes, 7);
                surf.opacities.clone() * pbr::schlick(cos, opts.shading.f0)
            } else {
                surf.opacities.clone()
            };
            let surf_w = Prepared {
                means: surf.means.clone(),
                quats: surf.quats.clone(),
                scales: surf.scales.clone(),
                opacities: surf_op,
                colours: surf.colours.clone(),
                planes: None,
                offsets: surf.offsets.clone(),
            };
            let (all, int_p) = match interior {
                Some(set) => {
                    let ip = self.prepare(set, camera, false, true, opts.track_offsets);
                    (cat_prepared(&surf_w, &ip), Some(ip))
                }
                None => (surf_w, None),
            };
            let out = self.splat(&all, all.opacities.clone(), all.colours(), camera)?;
            passes += 1;
            let (radii, tiles) = radii_and_tiles(out.aux);
            tile_splats += tiles;
            let (sr, ir) = (radii[..ns].to_vec(), radii[ns..].to_vec());
            (out.image, out.alpha, sr, ir, int_p)
        };

        if opts.geometry && geometry_out.is_none() {
            let feats = self.geometry_features(&surf, camera, material, opts.spread);
            let out = self.splat(&surf, surf.opacities.clone(), feats, camera)?;
            passes += 1;
            let (_, tiles) = radii_and_tiles(out.aux);
            tile_splats += tiles;
            geometry_out = Some((out.image, out.alpha, tiles));
        }
        let geometry = geometry_out.map(|(maps, coverage, tiles)| {
            let ch = maps.dims()[2];
            let spread = opts.spread.then(|| {
                let moments = layout::channels(&maps, ch - SPREAD_CHANNELS..ch);
                plane_spread(moments, &coverage, rays)
            });
            let (base, roughness) = if material {
                (
                    Some(layout::channels(&maps, 4..7)),
                    Some(layout::channel(&maps, 7)),
                )
            } else {
                (None, None)
            };
            GeometryMaps {
                base,
                roughness,
                spread,
                ..depth_maps(maps, coverage, rays, tiles)
            }
        });

        let scatter = match (&int_prepared, interior, pbr) {
            (Some(ip), Some(set), true) => {
                // A diffuse scattering lobe is lit by the shading, not by the view: its colour
                // is the interior set's degree-0 one.
                let colours = if opts.shading.scatter_lambert {
                    sh::dc_colours(set.req(ParamKind::ShDc))
                } else {
                    ip.colours()
                };
                let out = self.splat(ip, ip.opacities.clone(), colours, camera)?;
                passes += 1;
                tile_splats += radii_and_tiles(out.aux).1;
                Some(out.image)
            }
            _ => None,
        };

        let c_pbr = match (&geometry, pbr, self.light()) {
            (Some(g), true, Some(light)) => {
                let gb = GBuffer {
                    normal: g.normal.clone(),
                    depth: g.depth.clone(),
                    coverage: g.coverage.clone(),
                    base: g.base.clone().expect("material maps with PBR"),
                    roughness: g.roughness.clone().expect("material maps with PBR"),
                    scatter: scatter.clone(),
                    rays: rays.clone(),
                };
                Some(pbr::c_pbr(&gb, light, opts.shading, opts.pbr_srgb))
            }
            _ => None,
        };

        Ok(Renders {
            c_sh,
            alpha_sh,
            geometry,
            scatter,
            c_pbr,
            passes,
            tile_splats,
            surface_radii,
            interior_radii,
            surface_offsets: surf.offsets,
            interior_offsets: int_prepared.and_then(|p| p.offsets),
        })
    }

    /// Renders only the surface geometry (normal, plane distance, depth, coverage) of a camera:
    /// one pass of four channels. Used for the multi-view neighbour and for mesh extraction.
    pub fn render_depth(
        &self,
        camera: &Camera,
        rays: &Tensor<3>,
    ) -> Result<GeometryMaps, ModelError> {
        let surf = self.prepare(&self.surface, camera, true, false, false);
        let feats = self.geometry_features(&surf, camera, false, false);
        let out = self.splat(&surf, surf.opacities.clone(), feats, camera)?;
        let tiles = radii_and_tiles(out.aux).1;
        Ok(depth_maps(out.image, out.alpha, rays, tiles))
    }

    /// The surface set's blended depth ([`Model::render_depth`]) with only the opacities
    /// differentiable: positions, shapes and plane features enter as constants, so a loss on
    /// it changes how opaque each layer is, not where it lies ([`crate::losses::front_depth`]).
    pub fn render_depth_weights(
        &self,
        camera: &Camera,
        rays: &Tensor<3>,
    ) -> Result<GeometryMaps, ModelError> {
        let constant = |t: &Tensor<2>| t.clone().detach().set_require_grad(false);
        let surf = self.prepare(&self.surface, camera, true, false, false);
        let feats = constant(&self.geometry_features(&surf, camera, false, false));
        let fixed = Prepared {
            means: constant(&surf.means),
            quats: constant(&surf.quats),
            scales: constant(&surf.scales),
            opacities: surf.opacities.clone(),
            colours: None,
            planes: None,
            offsets: surf.offsets.as_ref().map(constant),
        };
        let out = self.splat(&fixed, surf.opacities.clone(), feats, camera)?;
        let tiles = radii_and_tiles(out.aux).1;
        Ok(depth_maps(out.image, out.alpha, rays, tiles))
    }

    /// Per surface Gaussian, whether it is blended at some pixel of `camera` while the
    /// transmittance in front of it is above `threshold` (the surface set alone with its plain
    /// opacity, as the geometry pass blends it). At 0.5 this is PGSR's observation test: a
    /// Gaussian that passes it in too few training views lies hidden behind the layers that
    /// decide the depth, and PGSR prunes it ([`crate::config::DensifyConfig::trim_every`]).
    /// Forward only, on the host kernels.
    pub fn observed_surface(
        &self,
        camera: &Camera,
        threshold: f64,
    ) -> Result<Vec<bool>, ModelError> {
        let set = &self.surface;
        let means = set.req(ParamKind::Means).clone();
        let inputs = SplatInputs {
            features: layout::cols(&means, 0..1).zeros_like(),
            means,
            quats: set.req(ParamKind::Rotations).clone(),
            scales: set.scales(),
            opacities: self.opacities(set),
            xy_offsets: None,
        };
        let cfg = self.splat_config(camera, 1);
        Ok(gtsr_render_kernels::render_crossing(inputs, &cfg, threshold)?.observed)
    }

    /// The interior set's front for `camera`: per pixel `[H, W]`, the camera depth of the centre
    /// of the interior splat at which the interior set's transmittance (its own blend, plain
    /// opacities) first falls to `threshold`; 0 where it stays above. `None` without an
    /// interior set. Not differentiable; runs the host kernels
    /// ([`gtsr_render_kernels::render_crossing`]).
    pub fn render_interior_front(
        &self,
        camera: &Camera,
        threshold: f64,
    ) -> Result<Option<Tensor<2>>, ModelError> {
        let Some(set) = &self.interior else {
            return Ok(None);
        };
        let means = set.req(ParamKind::Means).clone().detach();
        let z = layout::cols(&to_camera(&means, camera), 2..3);
        let log_scales = set.req(ParamKind::LogScales).clone().detach();
        let inputs = SplatInputs {
            features: z,
            scales: self.plane_blurred(log_scales.clone().exp(), &log_scales, &means, camera),
            means,
            quats: set.req(ParamKind::Rotations).clone().detach(),
            opacities: self.opacities(set).detach(),
            xy_offsets: None,
        };
        let cfg = self.splat_config(camera, 1);
        let out = gtsr_render_kernels::render_crossing(inputs, &cfg, threshold)?;
        let [h, w, _] = out.features.dims();
        Ok(Some(out.features.reshape([h, w]) * out.found))
    }

    /// Like [`Model::render_depth`], but each pixel takes the normal, plane and depth of the one
    /// surface splat at which the pixel's transmittance first falls to `threshold` (0.5: the
    /// median splat, as 2DGS's median depth) instead of their blend over every layer the ray
    /// crosses; `coverage` is 1 where the transmittance crossed it and 0 elsewhere. Not
    /// differentiable; runs the host kernels ([`gtsr_render_kernels::render_crossing`]). For
    /// mesh extraction.
    pub fn render_depth_crossing(
        &self,
        camera: &Camera,
        rays: &Tensor<3>,
        threshold: f64,
    ) -> Result<GeometryMaps, ModelError> {
        let surf = self.prepare(&self.surface, camera, true, false, false);
        let feats = self.geometry_features(&surf, camera, false, false);
        let cfg = self.splat_config(camera, feats.dims()[1]);
        let inputs = splat_inputs(&surf, surf.opacities.clone(), feats);
        let out = gtsr_render_kernels::render_crossing(inputs, &cfg, threshold)?;
        Ok(depth_maps(out.features, out.found, rays, 0))
    }
}

/// Feature channels the spread adds to the geometry pass (the plane moments of
/// [`GeometryMaps::spread`]).
pub const SPREAD_CHANNELS: usize = 9;

/// Lower clamp of the plane distance in the spread's plane moments, as a fraction of the
/// camera's distance to the origin: planes that pass closer to the camera than this (splats
/// seen nearly edge-on) enter with their inverse depth capped.
pub const SPREAD_MIN_PLANE: f64 = 0.1;

/// Per splat, the moments whose blend gives [`GeometryMaps::spread`]. A splat's plane
/// `n . x = -d` (camera space, `n` facing the camera) meets the pixel ray `t r` (`r_z = 1`) at
/// the inverse depth `1 / t = -(n / d) . r`, linear in `m = n / d`; so blending `m` and the six
/// products `m_a m_b` gives, for every pixel, the blend's mean and mean square of the inverse
/// depths at which its splats cross that pixel's ray. `m` is taken relative to the plane
/// `z = c` (`c` the camera's distance to the origin, about the scene's depth), which keeps the
/// blended squares small so that their difference does not cancel in f32.
fn spread_features(n_c: &Tensor<2>, plane: &Tensor<2>, camera: &Camera) -> Tensor<2> {
    let c = camera
        .centre()
        .iter()
        .map(|x| x * x)
        .sum::<f64>()
        .sqrt()
        .max(1e-6);
    let m = n_c.clone() / plane.clone().clamp_min(SPREAD_MIN_PLANE * c);
    let col = |k: usize| layout::cols(&m, k..k + 1);
    let (x, y, z) = (col(0), col(1), col(2) + 1.0 / c);
    layout::cat_cols(vec![
        x.clone(),
        y.clone(),
        z.clone(),
        x.clone().powi_scalar(2),
        y.clone().powi_scalar(2),
        z.clone().powi_scalar(2),
        x.clone() * y.clone(),
        x * z.clone(),
        y * z,
    ])
}

/// [`GeometryMaps::spread`] from the blended moments of [`spread_features`] `[H, W, 9]`
/// (premultiplied), the coverage and the pixel rays.
fn plane_spread(moments: Tensor<3>, coverage: &Tensor<2>, rays: &Tensor<3>) -> Tensor<2> {
    let ch = |k: usize| layout::channel(&moments, k);
    let rx = layout::channel(rays, 0);
    let ry = layout::channel(rays, 1);
    let cover = coverage.clone().clamp_min(crate::pbr::COVER_MIN);
    // E[m . r] and E[(m . r)^2] with r = (rx, ry, 1).
    let mean = (ch(0) * rx.clone() + ch(1) * ry.clone() + ch(2)) / cover.clone();
    let square = (ch(3) * rx.clone().powi_scalar(2)
        + ch(4) * ry.clone().powi_scalar(2)
        + ch(5)
        + (ch(6) * rx.clone() * ry.clone() + ch(7) * rx + ch(8) * ry) * 2.0)
        / cover;
    (square - mean.powi_scalar(2)).clamp_min(0.0)
}

/// A `[1, 1]` tensor holding `value`.
pub fn scalar_param(value: f64, device: &Device) -> Tensor<2> {
    let t = Tensor::<2>::from_data(TensorData::new(vec![value as f32], [1, 1]), device);
    if device.is_autodiff() {
        t.require_grad()
    } else {
        t
    }
}
