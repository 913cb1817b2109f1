//! The recipe ([`extract_mesh`]) that turns a model's depth maps and the masks into the mesh,
//! used by `gtsr-train` and the laboratory alike: the masks' bound, the carving by the depth
//! (with the hollow search), the TSDF fusion where there is no bound, and the shading
//! refinement.

use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;

use crate::carve::{CarvedRegions, DepthMap, carve_field, debias_depth, hull_offset};
use crate::config::*;
use crate::consistency::{DepthView, filter_consistent};
use crate::error::{MeshError, Result};
use crate::inputs::*;
use crate::marching::{Grid, marching_cubes};
use crate::masks::*;
use crate::mesh::face_centroid;
use crate::mesh::largest_component;
use crate::pixels::median_pixel_footprint;
use crate::raycast::MeshRaycaster;
use crate::raycast::SignedDistance;
use crate::refine::{debiased_depth_targets, observed_offsets};
use crate::shading::{
    NormalPrior, ShadingImage, ShadingRefinement, ShadingSettings, observe_shading, own_normals,
    refine_by_shading,
};
use crate::tsdf::{TsdfVolume, default_truncation, default_voxel, snap_to_hull};
use crate::visible::{faces_kept, faces_observed_among};
use rayon::prelude::*;

/// The mesh of `inputs` under `config`, and the lines worth reporting about how it was made.
///
/// With [`Fusion::Carve`] and the masks: the masks at the dataset's resolution carved by the
/// depth maps (with [`MeshConfig::carve_debias`] first moved forward by their median offset
/// from the bound, [`crate::carve::hull_offset`]) where [`MeshConfig::carve`] agrees ([`crate::carve::carve_mesh`]; the concavity gate
/// compares each depth map with the masks' mesh ray cast from the same camera), then, with
/// [`MeshConfig::cull_unobserved`], without the carved walls no depth map observes, and, with
/// [`MeshConfig::shading_anchor`] and [`MasksAlone::radiance`], refined by
/// the images' shading (and with [`MeshConfig::shading_depth`] the depth maps). Otherwise a
/// TSDF of the depth maps on the box (voxel: [`crate::tsdf::default_voxel`] unless set), with
/// the masks' hull kept in the volume when every view has a mask and
/// [`MeshConfig::silhouette_carving`] is on; then marching cubes and the largest connected
/// component.
pub fn extract_mesh(config: &MeshConfig, inputs: &FusionInputs) -> Result<(TriMesh, Vec<String>)> {
    config.validate()?;
    if config.shading_normals_rendered > 0.0
        && let Some(v) = (inputs.views.iter()).find(|v| v.normal.len() != 3 * v.mask.len())
    {
        return Err(MeshError::InvalidArgument(format!(
            "mesh.shading_normals_rendered needs a normal map on every fusion view (a {}x{} \
             view has {} values)",
            v.camera.width,
            v.camera.height,
            v.normal.len()
        )));
    }
    let mut notes = Vec::new();
    let (lo, hi) = inputs.bounds;
    if config.fusion == Fusion::Carve
        && inputs.masked
        && let Some(masks) = inputs.masks
    {
        let (_, bound_mesh) = carving_bound(config, masks);
        if !config.fuse_depth {
            return Ok((bound_mesh.clone(), notes));
        }
        let mut maps = consistent_maps(config, inputs, &mut notes)?;
        // The bound's own depth, for the concavity gate, the depth's offset and the silhouette
        // check: its mesh ray cast per view.
        let guard = config.carve_max_opened < 1.0;
        let spread_check = config.carve_max_spread > 0.0;
        let hull_maps: Vec<Vec<f32>> =
            if config.carve_concavity_gate > 0.0 || guard || config.carve_debias || spread_check {
                let caster = MeshRaycaster::new(bound_mesh, "the masks' mesh")?;
                inputs
                    .views
                    .iter()
                    .map(|v| caster.render(v.camera).depth)
                    .collect()
            } else {
                Vec::new()
            };
        // Without the bound's depth (no gate, guard, debias or spread check) there is no
        // offset to read.
        let offset = hull_offset(&depth_maps(inputs.views, &maps, &hull_maps, true));
        if let Some([q1, median, q3]) = offset {
            notes.push(format!(
                "the depth lies {median:+.2} footprints behind the masks' bound (median; \
                 quartiles {q1:+.2}, {q3:+.2})"
            ));
            if config.carve_debias && median > 0.0 {
                for (v, depth) in inputs.views.iter().zip(&mut maps) {
                    debias_depth(v.camera, depth, median);
                }
                notes.push(format!(
                    "carving: the depth maps moved {median:.2} footprints towards the cameras"
                ));
            }
        }
        if config.hollow_search {
            carve_hollow(inputs, masks, &mut maps, &mut notes)?;
        }
        let mut mesh =
            carve_inside_bound(config, inputs, masks, &maps, &hull_maps, offset, &mut notes)?;
        if config.shading_anchor > 0.0
            && let Some(images) = masks.shading_images()
        {
            let depth = (config.shading_depth > 0.0).then_some(DepthFrom {
                views: inputs.views,
                maps: &maps,
                length: config.shading_depth,
                threshold: config.shading_depth_threshold,
            });
            let share = config.shading_normals_rendered;
            let rendered: Vec<(&Camera, &[f32])> = (inputs.views.iter())
                .map(|v| (v.camera, v.normal))
                .collect();
            let prior = (share > 0.0).then_some(NormalPrior {
                views: &rendered,
                share,
            });
            mesh = shading_refined(mesh, masks, &images, depth, prior, config, &mut notes)?;
        }
        return Ok((mesh, notes));
    }
    let radius = 0.5 * (hi - lo).max_element();
    let footprint = || median_pixel_footprint(inputs.footprint_cameras, 0.5 * (lo + hi));
    let mut voxel = config
        .voxel
        .unwrap_or_else(|| default_voxel(radius, footprint()));
    if inputs.coarse {
        voxel *= 2.5;
    }
    let masked = inputs.masked;
    // Free-space votes from outside the masks: with carving they feed the hull field; without
    // carving on a masked scene (depth alone) there are none, as in PGSR's and 2DGS's TSDF
    // fusion (each would be +truncation on every voxel along the ray, pulling the surface
    // outward near the silhouettes). Without masks, the pixels the render leaves empty vote.
    let carving = config.silhouette_carving && masked;
    let free_space_votes = config.silhouette_carving || !masked;
    if !config.fuse_depth && !carving {
        return Err(MeshError::InvalidArgument(
            "fusing the masks alone needs a mask on every view and silhouette carving".into(),
        ));
    }
    let truncation = match (config.truncation, config.truncation_footprints) {
        (Some(t), _) => t,
        (None, Some(f)) => f * footprint(),
        (None, None) => default_truncation(radius, footprint(), free_space_votes),
    }
    .max(voxel);
    let mut tsdf = TsdfVolume::new(lo, hi, voxel, truncation)?;
    if carving {
        // The object lies inside every mask: the surface stays inside the masks' hull.
        tsdf = tsdf.with_silhouette_carving();
        if config.hull_inside_distance {
            tsdf = tsdf.with_hull_inside_distance();
        }
    }
    if !config.fuse_depth {
        for v in inputs.views {
            tsdf.integrate(v.camera, &vec![0.0; v.mask.len()], Some(v.mask))?;
        }
        return Ok((largest_component(&tsdf.extract_mesh()), notes));
    }
    let mut maps = consistent_maps(config, inputs, &mut notes)?;
    if let Some(f) = config.snap_to_hull {
        // The hull from every mask first (depth 0 measures nothing), then each view's depth
        // against it (validate: snapping needs carving, and here every view has a mask).
        if !carving {
            return Err(MeshError::InvalidArgument(
                "snapping the depth to the hull needs a mask on every view".into(),
            ));
        }
        for v in inputs.views {
            tsdf.integrate(v.camera, &vec![0.0; v.mask.len()], Some(v.mask))?;
        }
        let (mut snapped, mut samples) = (0, 0);
        for (v, depth) in inputs.views.iter().zip(maps.iter_mut()) {
            let hull = tsdf.hull_depth(v.camera).ok_or_else(|| {
                MeshError::InvalidArgument("the volume has no hull to snap to".into())
            })?;
            samples += depth.iter().filter(|d| **d > 0.0).count();
            snapped += snap_to_hull(depth, &hull, v.camera.fx, f)?;
        }
        notes.push(format!(
            "snapped to the hull (within {f} footprints): {snapped} of {samples} samples"
        ));
    }
    // After snapping the hull holds every mask already; a pixel outside its mask has no depth
    // and with carving casts no vote, so the masks need not come again.
    let masks_pending = config.snap_to_hull.is_none() && free_space_votes;
    for (v, depth) in inputs.views.iter().zip(&maps) {
        tsdf.integrate(v.camera, depth, masks_pending.then_some(v.mask))?;
    }
    Ok((largest_component(&tsdf.extract_mesh()), notes))
}

/// How much of the masks a carved mesh leaves uncovered ([`MeshConfig::carve_max_opened`]).
#[derive(Clone, Copy, Debug, Default)]
struct Opened {
    /// Pixels (mask at least 0.5) the bound covers and the carved mesh does not, all views.
    opened: usize,
    /// Pixels (mask at least 0.5) the bound covers, all views.
    covered: usize,
    /// The largest share of one view's covered pixels that is opened.
    worst_view: f64,
}

impl Opened {
    /// `opened / covered` (0 when nothing is covered).
    fn share(&self) -> f64 {
        self.opened as f64 / self.covered.max(1) as f64
    }
}

/// The pixels of each view's mask that its bound's depth (`bound_depth`, the bound ray cast
/// from that view, 0 on a miss) covers and `mesh` does not.
fn opened_silhouettes(
    mesh: &TriMesh,
    views: &[FusionView<'_>],
    bound_depth: &[Vec<f32>],
) -> Result<Opened> {
    let caster = MeshRaycaster::new(mesh, "the carved mesh")?;
    let mut total = Opened::default();
    for (v, bound) in views.iter().zip(bound_depth) {
        let own = caster.render(v.camera).depth;
        let (mut opened, mut covered) = (0usize, 0usize);
        for ((m, b), d) in v.mask.iter().zip(bound).zip(&own) {
            if *m >= 0.5 && *b > 0.0 {
                covered += 1;
                opened += usize::from(*d <= 0.0);
            }
        }
        total.opened += opened;
        total.covered += covered;
        total.worst_view = total.worst_view.max(opened as f64 / covered.max(1) as f64);
    }
    Ok(total)
}

/// The rendered depth maps a refinement reads ([`MeshConfig::shading_depth`]).
#[derive(Clone, Copy)]
struct DepthFrom<'a> {
    views: &'a [FusionView<'a>],
    maps: &'a [Vec<f32>],
    /// Footprints.
    length: f32,
    /// Footprints.
    threshold: f32,
}

/// [`MeshConfig::hollow_search`]: where the images read a hollow behind the masks' mesh, the
/// dark pixels' depth in `maps` is put that far behind it (the masks' mesh's own depth).
fn carve_hollow(
    inputs: &FusionInputs,
    masks: &MasksAlone,
    maps: &mut [Vec<f32>],
    notes: &mut Vec<String>,
) -> Result<()> {
    if masks.images.is_none() {
        notes.push("hollow search: the masks carry no images".into());
        return Ok(());
    }
    let native: Vec<&Camera> = masks.views.iter().map(|(c, _)| c).collect();
    let fusion: Vec<&Camera> = inputs.views.iter().map(|v| v.camera).collect();
    if !crate::hollow::same_poses(&native, &fusion) {
        notes.push("hollow search: the fusion views are not the masks' views".into());
        return Ok(());
    }
    let cached = masks.hollow.get().is_some();
    let Some(reading) = masks.hollow_reading()? else {
        return Ok(());
    };
    let when = if cached {
        format!("read once, {:.0} s", reading.seconds)
    } else {
        format!("{:.0} s", reading.seconds)
    };
    let [flush, band, dark] = reading.pixels;
    let Some((radius, depth)) = reading.pick else {
        let why = match reading.best {
            Some((r, d)) => format!(
                "; the best hollow, {r} fp to {d} fp, takes {:.0} % of the lid's error off the \
                 pixels beside the dark ones, under the {:.0} % asked",
                100.0 * reading.band_share,
                100.0 * crate::hollow::HollowSettings::default().min_band_share,
            ),
            None => String::new(),
        };
        notes.push(format!(
            "hollow search: none ({dark} dark pixels, {band} beside them, {flush} flush{why}; \
             {when})"
        ));
        return Ok(());
    };
    // The dark pixels in the fusion views (the masks' own where the two are the same size),
    // put `depth` of the masks' footprints behind the lid.
    let caster = MeshRaycaster::new(&masks.mesh, "the masks' mesh")?;
    let lid: Vec<Vec<f32>> = fusion.iter().map(|c| caster.render(c).depth).collect();
    let carried = crate::hollow::dark_in_views(&reading.dark, &native, &fusion);
    let moved = crate::hollow::hollow_depths(&lid, &carried, &native, depth);
    for ((map, d), m) in maps.iter_mut().zip(&carried).zip(&moved) {
        for p in (0..map.len()).filter(|&p| d[p] && m[p] > 0.0) {
            map[p] = m[p];
        }
    }
    let lid_row = reading.candidates[0];
    let best = (reading.candidates.iter())
        .find(|c| (c.radius, c.depth) == (radius, depth))
        .copied()
        .unwrap_or(lid_row);
    notes.push(format!(
        "hollow search: capsules of {radius} fp to {depth} fp behind the masks' mesh read \
         from {dark} dark pixels ({band} beside them, {flush} flush; grey material {:.2}, \
         mean free path {:.3}; error {:.1} % against the lid's {:.1} %, beside the dark \
         pixels {:.0} % less); their depth carves there ({when})",
        reading.material.0,
        reading.material.1,
        best.total,
        lid_row.total,
        100.0 * reading.band_share,
    ));
    Ok(())
}

/// The views and the mesh that bound the carving: the edge hull where the masks carry one
/// and the settings ask for it, else the masks.
fn carving_bound<'a>(
    config: &MeshConfig,
    masks: &'a MasksAlone,
) -> (Vec<(Camera, &'a [f32])>, &'a TriMesh) {
    if config.edge_hull {
        (masks.bound(), masks.bound_mesh())
    } else {
        (masks.borrowed(), &masks.mesh)
    }
}

/// The carving of [`extract_mesh`]: the depth maps (already moved by their offset) carve
/// inside the masks' bound where the concavity gate lets them, and the walls no map observes
/// are culled. The carving is refused (the bound instead) when the maps are not a surface
/// yet: their `offset` quartiles from the bound ([`hull_offset`]) spread wider than
/// [`MeshConfig::carve_max_spread`], or the carved mesh opens the silhouettes; the images'
/// shading refuses each carved region over which it finds the bound to be the surface
/// ([`MeshConfig::carve_min_lid_departure`]), and the bound is restored there.
fn carve_inside_bound(
    config: &MeshConfig,
    inputs: &FusionInputs,
    masks: &MasksAlone,
    maps: &[Vec<f32>],
    hull_maps: &[Vec<f32>],
    offset: Option<[f32; 3]>,
    notes: &mut Vec<String>,
) -> Result<TriMesh> {
    let (lo, hi) = inputs.bounds;
    let (bound, bound_mesh) = carving_bound(config, masks);
    let refused = |notes: &mut Vec<String>, why: String| {
        notes.push(format!(
            "carving refused: {why}, so the depth maps are not a surface yet; the mesh is the \
             masks' bound"
        ));
        Ok(bound_mesh.clone())
    };
    if let Some(spread) = offset
        .map(|[q1, _, q3]| q3 - q1)
        .filter(|s| config.carve_max_spread > 0.0 && *s > config.carve_max_spread)
    {
        return refused(
            notes,
            format!(
                "the depth's offsets from the masks' bound spread over {spread:.2} footprints \
                 between their quartiles, more than mesh.carve_max_spread ({})",
                config.carve_max_spread
            ),
        );
    }
    let depths = depth_maps(
        inputs.views,
        maps,
        hull_maps,
        config.carve_concavity_gate > 0.0,
    );
    let voxel = config.carve_voxel.unwrap_or(masks.voxel);
    let carve = config.carve();
    let carving = carve_field(&bound, &depths, lo, hi, voxel, &carve)?;
    if let Some(g) = carving.gate {
        notes.push(format!(
            "concavity gate: {} of {} depth samples lie more than {} footprints behind the \
             masks' hull",
            g.open, g.samples, carve.concavity_gate
        ));
    }
    let carved = culled_carving(config, masks, bound_mesh, &depths, &carving.grid, notes)?;
    if config.carve_max_opened < 1.0 {
        let opened = opened_silhouettes(&carved, inputs.views, hull_maps)?;
        let share = opened.share();
        notes.push(format!(
            "carving: the carved mesh leaves {} of the {} masked pixels the bound covers \
             uncovered ({:.3} %; most in one view {:.3} %)",
            opened.opened,
            opened.covered,
            100.0 * share,
            100.0 * opened.worst_view
        ));
        if share > f64::from(config.carve_max_opened) {
            return refused(
                notes,
                format!(
                    "it opens the silhouettes beyond mesh.carve_max_opened ({} %)",
                    100.0 * config.carve_max_opened
                ),
            );
        }
    }
    let t0 = std::time::Instant::now();
    let ratio = config.carve_min_lid_departure;
    let Some(images) = masks.shading_images().filter(|_| ratio > 0.0) else {
        return Ok(carved);
    };
    let regions = carving.regions();
    if regions.count == 0 {
        return Ok(carved);
    }
    let Some(d) = lid_departure(bound_mesh, &carved, masks, &images, &carving.grid, &regions)?
    else {
        return Ok(carved);
    };
    notes.push(format!(
        "carving: the images' shading departs {:.1} deg (median) from the masks' bound over the \
         carved volume ({} faces solved), {:.1} deg elsewhere ({} faces) ({:.1} s)",
        d.lid,
        d.lid_solved,
        d.rest,
        d.rest_solved,
        t0.elapsed().as_secs_f64()
    ));
    // Each region is judged by its own lid where the shading solves it, the others by the
    // whole lid.
    let whole_refused = d.lid <= ratio * d.rest;
    let region_refused: Vec<bool> = (d.regions.iter())
        .map(|r| r.map_or(whole_refused, |(median, _)| median <= ratio * d.rest))
        .collect();
    let judged = d.regions.iter().filter(|r| r.is_some()).count();
    let refused_count = region_refused.iter().filter(|r| **r).count();
    if regions.count > 1 {
        notes.push(format!(
            "carving: {} carved regions, {judged} judged by the shading over them (the others \
             by the whole lid): {refused_count} refused",
            regions.count
        ));
    }
    if refused_count == regions.count {
        return refused(
            notes,
            format!(
                "the images' shading finds the masks' bound over the carved volume no less the \
                 surface than elsewhere (mesh.carve_min_lid_departure {ratio})"
            ),
        );
    }
    if refused_count == 0 {
        return Ok(carved);
    }
    let kept = carving.restored(&regions, &region_refused);
    culled_carving(config, masks, bound_mesh, &depths, &kept, notes)
}

/// The mesh of a carved field: marching cubes, the largest component, and without the
/// carving's walls that no depth map observes ([`MeshConfig::cull_unobserved`]).
fn culled_carving(
    config: &MeshConfig,
    masks: &MasksAlone,
    bound_mesh: &TriMesh,
    depths: &[DepthMap],
    grid: &Grid,
    notes: &mut Vec<String>,
) -> Result<TriMesh> {
    let carved = largest_component(&marching_cubes(grid, 0.0));
    if config.cull_unobserved <= 0.0 {
        return Ok(carved);
    }
    // Only the carving's own walls (off the masks' mesh) must be seen by a depth map.
    let hull = SignedDistance::new(bound_mesh, "the masks' mesh")?;
    let walls: Vec<bool> = (carved.triangles.par_iter())
        .map(|t| hull.query(face_centroid(&carved, *t)).0.abs() > masks.voxel)
        .collect();
    let seen = faces_observed_among(&carved, depths, config.cull_unobserved, &walls)?;
    let keep: Vec<bool> = walls.iter().zip(&seen).map(|(w, s)| !w || *s).collect();
    let kept = faces_kept(&carved, &keep, "the culling left no face")?;
    notes.push(format!(
        "culled {} of {} faces: carved walls no depth map observes within {} footprints",
        carved.triangles.len() - kept.triangles.len(),
        carved.triangles.len(),
        config.cull_unobserved
    ));
    Ok(kept)
}

/// How far the images' shading normals lie from the masks' bound ([`lid_departure`]), in
/// degrees.
#[derive(Clone, Debug)]
struct LidDeparture {
    /// Median over the solved faces of the bound that lie above the carved volume.
    lid: f32,
    lid_solved: usize,
    /// Median over the bound's other solved faces.
    rest: f32,
    rest_solved: usize,
    /// Per carved region, the median over the solved lid faces above it and how many, where
    /// there are any.
    regions: Vec<Option<(f32, usize)>>,
}

/// The departure of the images' shading normals from the faces of `bound` (the masks' mesh)
/// that lie more than the masks' voxel from `carved` (the lid over what the carving took
/// away), over the whole lid and over the part above each carved region (the region of the
/// first carved-away grid point within three voxels under the face), and from its other
/// faces; the normals solved as the shading refinement solves them (the interreflection
/// modelled), without shrinking them towards the faces' own. `None` when the carving took
/// nothing away or the shading solves no face of the lid or none elsewhere.
fn lid_departure(
    bound: &TriMesh,
    carved: &TriMesh,
    masks: &MasksAlone,
    images: &[ShadingImage<'_>],
    grid: &Grid,
    regions: &CarvedRegions,
) -> Result<Option<LidDeparture>> {
    let carved_distance = SignedDistance::new(carved, "the carved mesh")?;
    let lid: Vec<bool> = (bound.triangles.par_iter())
        .map(|t| carved_distance.query(face_centroid(bound, *t)).0.abs() > masks.voxel)
        .collect();
    if !lid.iter().any(|l| *l) {
        return Ok(None);
    }
    let defaults = ShadingRefinement::default();
    let settings = ShadingSettings {
        shrink: false,
        ..defaults.shading
    };
    let caster = MeshRaycaster::new(bound, "the masks' mesh")?;
    let (fit, _) = observe_shading(bound, &caster, images, &settings, defaults.surrounding_rays)?;
    let own = own_normals(bound);
    let (mut over, mut rest) = (Vec::new(), Vec::new());
    let mut by_region = vec![Vec::new(); regions.count];
    for (f, on_lid) in lid.iter().enumerate() {
        if fit.normals.weight[f] <= 0.0 {
            continue;
        }
        let angle = (fit.normals.normal[f].dot(own.normal[f]))
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        if !*on_lid {
            rest.push(angle);
            continue;
        }
        over.push(angle);
        let centroid = face_centroid(bound, bound.triangles[f]);
        let region = (1..=6)
            .map(|half| centroid - own.normal[f] * (0.5 * half as f32 * grid.voxel))
            .find_map(|p| regions.at(grid, p));
        if let Some(r) = region {
            by_region[r as usize].push(angle);
        }
    }
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        quantile(v, 0.5)
    };
    let (Some(lid_median), Some(rest_median)) = (median(&mut over), median(&mut rest)) else {
        return Ok(None);
    };
    Ok(Some(LidDeparture {
        lid: lid_median,
        lid_solved: over.len(),
        rest: rest_median,
        rest_solved: rest.len(),
        regions: (by_region.iter_mut())
            .map(|v| median(v).map(|m| (m, v.len())))
            .collect(),
    }))
}

/// `mesh` refined by the shading of the masks' views ([`refine_by_shading`]) with the settings
/// of `config` ([`MeshConfig::shading_anchor`], `shading_shrink`, `shading_slack`,
/// `shading_rounds`, `shading_steep_tilt`) and, with
/// `depth`, by the offsets its depth maps observe; the anchor, the slack's reference, the
/// outward bound and the depth's length and threshold in the masks' pixel footprints at the
/// mesh's centre.
fn shading_refined(
    mesh: TriMesh,
    masks: &MasksAlone,
    images: &[ShadingImage<'_>],
    depth: Option<DepthFrom<'_>>,
    prior: Option<NormalPrior<'_>>,
    config: &MeshConfig,
    notes: &mut Vec<String>,
) -> Result<TriMesh> {
    let (anchor, slack) = (config.shading_anchor, config.shading_slack);
    let t0 = std::time::Instant::now();
    let (lo, hi) = mesh.bounds();
    let cameras: Vec<Camera> = masks.views.iter().map(|(c, _)| *c).collect();
    let footprint = median_pixel_footprint(&cameras, 0.5 * (lo + hi));
    let defaults = ShadingRefinement::default();
    let settings = ShadingRefinement {
        anchor: anchor * footprint,
        max_outward: if slack > 0.0 {
            0.0
        } else {
            SHADING_MAX_OUTWARD * footprint
        },
        slack_reference: (slack > 0.0).then_some(slack * footprint),
        rounds: config.shading_rounds,
        steep_tilt: config.shading_steep_tilt.to_radians().sin(),
        unscatter: config.shading_unscatter,
        shading: ShadingSettings {
            shrink: config.shading_shrink,
            ..defaults.shading
        },
        ..defaults
    };
    let targets = match depth {
        Some(d) => {
            let caster = MeshRaycaster::new(&mesh, "the mesh to refine")?;
            let own: Vec<Vec<f32>> = (d.views.iter())
                .map(|v| caster.render(v.camera).depth)
                .collect();
            let views: Vec<crate::refine::DepthView<'_>> = (d.views.iter().zip(d.maps).zip(&own))
                .map(|((v, depth), mesh_depth)| crate::refine::DepthView {
                    camera: v.camera,
                    depth,
                    mesh_depth,
                })
                .collect();
            let offsets = observed_offsets(&mesh, &views, settings.shading.min_cos)?;
            let (t, bias) = debiased_depth_targets(
                &offsets,
                DEPTH_MIN_VIEWS,
                d.threshold * footprint,
                d.length * footprint,
            );
            let mut dev: Vec<f32> = (offsets.offset.iter().zip(&offsets.views))
                .filter(|(_, v)| **v >= DEPTH_MIN_VIEWS)
                .map(|(o, _)| (o - bias).abs() / footprint)
                .collect();
            dev.sort_by(f32::total_cmp);
            let q = |p: f64| quantile(&dev, p).unwrap_or(0.0);
            notes.push(format!(
                "shading refinement: the depth's offsets on {} faces, bias {:+.5}, \
                 |offset - bias| quantiles 0.5/0.75/0.9/0.99 {:.3}/{:.3}/{:.3}/{:.3} footprints",
                t.weight.iter().filter(|w| **w > 0.0).count(),
                bias,
                q(0.5),
                q(0.75),
                q(0.9),
                q(0.99)
            ));
            Some(t)
        }
        None => None,
    };
    let refined = refine_by_shading(&mesh, images, targets.as_ref(), prior, &settings)?;
    if let Some(p) = prior {
        notes.push(format!(
            "shading refinement: {:.0} % of each face's normal from the rendered normal maps",
            100.0 * p.share
        ));
    }
    let moved = refined.moves.iter().map(|d| f64::from(*d)).sum::<f64>()
        / refined.moves.len().max(1) as f64;
    if let Some(s) = &refined.slack
        && !s.is_empty()
    {
        let mut s: Vec<f32> = s.iter().map(|v| v / footprint).collect();
        s.sort_by(f32::total_cmp);
        let q = |p: f64| quantile(&s, p).unwrap_or(0.0);
        notes.push(format!(
            "shading refinement: the vertices' slack on the masks' hull, quantiles \
             0.1/0.5/0.9/0.99 {:.2}/{:.2}/{:.2}/{:.2} footprints (the anchor is whole from \
             {slack}; tilts trusted up to {} degrees from {})",
            q(0.1),
            q(0.5),
            q(0.9),
            q(0.99),
            config.shading_steep_tilt,
            2.0 * slack
        ));
    }
    if let Some(m) = &refined.scatter {
        notes.push(if m.blurs() {
            format!(
                "shading refinement: the images' scattering inverted: I = {:.3} L + {:.3} \
                 (G * L), a Gaussian of {} pixels, L through a pixel filter of {} (not \
                 inverted; residual {:.5}, noise amplified up to {:.2}x)",
                m.sharp,
                m.blurred,
                m.sigma,
                m.pixel,
                m.residual,
                m.amplification()
            )
        } else {
            format!(
                "shading refinement: no scattering blur fits the images better than Lambert's \
                 law (residual {:.5}); the images as they are",
                m.residual
            )
        });
    }
    if !refined.round_changes.is_empty() {
        let changes: Vec<String> = (refined.round_changes.iter())
            .map(|c| format!("{:.3}", c / footprint))
            .collect();
        notes.push(format!(
            "shading refinement: each later round changed the moves by {} footprints (root \
             mean square)",
            changes.join(", ")
        ));
    }
    notes.push(format!(
        "shading refinement: normals solved on {} of {} faces (mean share kept {:.3}), \
         interreflection constant {:.4}, anchor {:.4}, {} round(s), mean move {:+.5} ({:.1} s)",
        refined.solved,
        mesh.triangles.len(),
        refined.confidence,
        refined.interreflection,
        settings.anchor,
        refined.round_changes.len() + 1,
        moved,
        t0.elapsed().as_secs_f64()
    ));
    Ok(refined.mesh)
}

/// The `p` quantile of the ascending `sorted` (the value at `floor((n - 1) p)`); `None` when
/// it is empty.
fn quantile(sorted: &[f32], p: f64) -> Option<f32> {
    let last = sorted.len().checked_sub(1)?;
    sorted.get((last as f64 * p) as usize).copied()
}

/// Every view's depth map, with the samples that fail [`MeshConfig::depth_consistency`] (when
/// set) zeroed; a note says how many.
fn consistent_maps(
    config: &MeshConfig,
    inputs: &FusionInputs,
    notes: &mut Vec<String>,
) -> Result<Vec<Vec<f32>>> {
    let maps: Vec<Vec<f32>> = inputs.views.iter().map(|v| v.depth.to_vec()).collect();
    let Some(c) = &config.depth_consistency else {
        return Ok(maps);
    };
    let views: Vec<DepthView> = inputs
        .views
        .iter()
        .zip(&maps)
        .map(|(v, depth)| DepthView {
            camera: v.camera,
            depth,
        })
        .collect();
    let (filtered, stats) = filter_consistent(&views, c)?;
    notes.push(format!(
        "depth consistency ({} of {} neighbours within {} footprints): dropped {} of {} samples",
        c.min_agree, c.neighbours, c.footprints, stats.dropped, stats.samples
    ));
    Ok(filtered)
}

#[cfg(test)]
mod tests;
