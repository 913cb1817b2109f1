//! The refinement of a mesh by its shading normals, each vertex held by its slack on the hull.

use super::*;

/// Steps per [`ShadingRefinement::slack_reference`] in the search for a vertex's slack.
const SLACK_STEPS: usize = 32;
/// The shortest anchor the slack gives a vertex, as a share of the anchor (a vertex the
/// hull holds exactly still has a positive anchor length).
const SLACK_FLOOR: f32 = 1e-3;
/// The power of the slack in the anchor length.
const SLACK_POWER: f32 = 4.0;
/// The largest slack, as a share of the reference, of the vertices of the faces the
/// scattering's model is fitted on ([`scatter_held_faces`]).
pub const SCATTER_HELD_SLACK: f32 = 0.25;

/// Per vertex, the factor on the refinement's anchor weight ([`crate::refine::refine_anchored`])
/// that holds it by its slack (any length unit, the same for `reference`): the anchor length is
/// the anchor times `min(1, slack / reference)^power`, at least a thousandth of it, and the
/// weight goes as one over the length squared.
pub fn slack_anchor_scale(slack: &[f32], reference: f32, power: f32) -> Vec<f32> {
    slack
        .iter()
        .map(|s| {
            let m = (s / reference).min(1.0).powf(power).max(SLACK_FLOOR);
            1.0 / (m * m)
        })
        .collect()
}

/// Per face of `mesh`, the sine of the largest tilt the refinement trusts
/// ([`crate::refine::refine_anchored`]), by how much room the masks leave it: a face whose
/// least vertex slack (any length unit, the same for the positive `reference`) is at most
/// `reference` gets `base` (a sine), one whose slack reaches twice `reference` gets `steep`,
/// and the angle ramps linearly between. Where the hull lies tight on the object a steep
/// target can only be the shading's error; over a concavity the masks cannot see, the
/// object's walls may be steep.
pub fn slack_tilt_limits(
    mesh: &TriMesh,
    slack: &[f32],
    reference: f32,
    base: f32,
    steep: f32,
) -> Vec<f32> {
    let (a0, a1) = (base.clamp(0.0, 1.0).asin(), steep.clamp(0.0, 1.0).asin());
    mesh.triangles
        .iter()
        .map(|t| {
            let s = t
                .iter()
                .map(|i| slack.get(*i as usize).copied().unwrap_or(0.0))
                .fold(f32::INFINITY, f32::min);
            let share = ((s - reference) / reference).clamp(0.0, 1.0);
            (a0 + share * (a1 - a0))
                .sin()
                .clamp(1e-6, MAX_TRUSTED_TILT_SINE)
        })
        .collect()
}

/// Per face of `mesh`, whether the masks' hull holds it: every vertex's slack (any length
/// unit, the same for `reference`) at most [`SCATTER_HELD_SLACK`] of `reference`. There the
/// mesh is right, and [`refine_by_shading`] fits the scattering's model on those faces
/// ([`crate::scatter::unscatter`]). A vertex without a slack counts as held.
pub fn scatter_held_faces(mesh: &TriMesh, slack: &[f32], reference: f32) -> Vec<bool> {
    (mesh.triangles.iter())
        .map(|t| {
            t.iter().all(|v| {
                slack
                    .get(*v as usize)
                    .is_none_or(|s| *s <= SCATTER_HELD_SLACK * reference)
            })
        })
        .collect()
}

/// The largest tilt limit [`slack_tilt_limits`] gives (a sine below 1: a target at a right
/// angle to its face has no slope).
const MAX_TRUSTED_TILT_SINE: f32 = 0.999;

/// The shading normals of `mesh` in `images` ([`shading_normals`]): each image sees the faces
/// that `caster` (built on `mesh`) hits first, and with `settings.interreflection` the light
/// of the surroundings is modelled from `rays` rays a face. Also returns the casts' z-depths,
/// one map per image.
pub(crate) fn observe_shading(
    mesh: &TriMesh,
    caster: &crate::raycast::MeshRaycaster,
    images: &[ShadingImage<'_>],
    settings: &ShadingSettings,
    rays: usize,
) -> Result<(ShadingFit, Vec<Vec<f32>>)> {
    let depths: Vec<Vec<f32>> = images
        .iter()
        .map(|v| caster.render(v.camera).depth)
        .collect();
    let views: Vec<ShadingView<'_>> = images
        .iter()
        .zip(&depths)
        .map(|(v, d)| ShadingView {
            camera: v.camera,
            radiance: v.radiance,
            mask: v.mask,
            mesh_depth: d,
        })
        .collect();
    let around = settings
        .interreflection
        .then(|| surroundings_cast(mesh, caster, rays));
    let fit = shading_normals(mesh, &views, around.as_ref(), settings)?;
    Ok((fit, depths))
}

/// Settings of [`refine_by_shading`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingRefinement {
    /// How the normals are solved (the interreflection is modelled when
    /// `ShadingSettings::interreflection` is set).
    pub shading: ShadingSettings,
    /// The length over which the displacements return to zero where the shading says nothing
    /// (scene units; [`RefineSettings::anchor`]).
    pub anchor: f32,
    /// The farthest a vertex may move outward (scene units).
    pub max_outward: f32,
    /// Rays cast per face for the surroundings the interreflection reads.
    pub surrounding_rays: usize,
    /// Observe-and-refine rounds: each observes the normals on the last round's mesh (the
    /// first on `mesh`) and refines `mesh` by them, so that the faces of a sunken lid are seen
    /// where they now are (at least 1; fewer run when a round leaves the mesh it observed
    /// where it was).
    pub rounds: usize,
    /// Hold each vertex by its slack on the hull of the images' masks
    /// ([`crate::hull::hull_slack`]): the anchor length is [`ShadingRefinement::anchor`] times
    /// `min(1, slack / reference)^4` (at least a thousandth of it), so that only where the
    /// masks leave room (over a concavity they cannot see) the normals move the mesh far;
    /// scene units (`None`: one anchor for all). Needs the images' masks.
    pub slack_reference: Option<f32>,
    /// With [`ShadingRefinement::slack_reference`]: the sine of the largest tilt of a target
    /// normal trusted on the faces whose slack reaches twice the reference
    /// ([`slack_tilt_limits`], from [`RefineSettings::max_tilt`] at the reference and below).
    pub steep_tilt: f32,
    /// Invert the light scattered under the surface in the images before the shading fit
    /// ([`crate::scatter::unscatter`]), its model fitted on `mesh`'s faces that the masks'
    /// hull holds within a quarter of [`ShadingRefinement::slack_reference`] (on every face
    /// without it).
    pub unscatter: bool,
}

impl Default for ShadingRefinement {
    fn default() -> Self {
        ShadingRefinement {
            shading: ShadingSettings {
                interreflection: true,
                shrink: true,
                ..ShadingSettings::default()
            },
            anchor: 0.01,
            max_outward: 0.0,
            surrounding_rays: 32,
            rounds: 1,
            slack_reference: None,
            steep_tilt: crate::refine::MAX_TILT_SINE,
            unscatter: false,
        }
    }
}

/// What [`refine_by_shading`] returns.
#[derive(Clone, Debug)]
pub struct ShadingRefined {
    /// The refined mesh (same triangles, moved vertices).
    pub mesh: TriMesh,
    /// Per vertex, the displacement along its normal (scene units, negative: inward).
    pub moves: Vec<f32>,
    /// Faces whose normal the shading solved.
    pub solved: usize,
    /// The interreflection constant used (0: not modelled).
    pub interreflection: f32,
    /// The mean share of the solved faces' corrections kept ([`ShadingFit::confidence`]).
    pub confidence: f32,
    /// Per vertex, its slack on the masks' hull (scene units, at most twice the reference) when
    /// [`ShadingRefinement::slack_reference`] is set.
    pub slack: Option<Vec<f32>>,
    /// Per round after the first, how much it changed the vertices' moves: the root mean
    /// square of the difference from the round before (scene units). Shorter than
    /// `rounds - 1` when a round left the mesh it observed unmoved (a fixed point).
    pub round_changes: Vec<f32>,
    /// The scattering model inverted in the images ([`ShadingRefinement::unscatter`]).
    pub scatter: Option<crate::scatter::Scatter>,
}

/// Normal maps that share each face's target normal with the shading's in
/// [`refine_by_shading`] (a trained model's rendered normals, say).
#[derive(Clone, Copy)]
pub struct NormalPrior<'a> {
    /// One camera and its camera-space normal map (3 per pixel, zero where nothing was
    /// rendered) per view.
    pub views: &'a [(&'a Camera, &'a [f32])],
    /// The share in `[0, 1]` of each face's target taken from these maps where they observe
    /// it ([`crate::refine::observed_normals`]); the rest is the shading's.
    pub share: f32,
}

/// Per face, `(1 - share) a + share b` of the two weighted normals, renormalised, with the
/// weights mixed alike; a face only one of them observes keeps that one's at its share.
pub fn blend_face_normals(a: &FaceNormals, b: &FaceNormals, share: f32) -> FaceNormals {
    let mut out = FaceNormals {
        normal: Vec::with_capacity(a.normal.len()),
        weight: Vec::with_capacity(a.normal.len()),
    };
    for f in 0..a.normal.len() {
        let (wa, wb) = ((1.0 - share) * a.weight[f], share * b.weight[f]);
        let m = wa * a.normal[f] + wb * b.normal[f];
        let n = m.normalize_or_zero();
        out.normal.push(n);
        out.weight.push(if n == Vec3::ZERO { 0.0 } else { wa + wb });
    }
    out
}

/// Refines `mesh` (a mesh around the object, such as the masks') by the normals its faces'
/// shading explains in `images` ([`shading_normals`], with the light the rest of the object
/// sends each face when `settings.shading.interreflection` is set): the vertices move along
/// their normals so that the faces' normals follow the shading's ([`crate::refine`]), within
/// `settings.anchor` of where they were, and, with `depth`, each face's mean displacement
/// pulled towards an observed offset ([`crate::refine::refine`]). With `prior`, each face's
/// target is the shading's normal blended with the prior's maps' ([`blend_face_normals`]).
pub fn refine_by_shading(
    mesh: &TriMesh,
    images: &[ShadingImage<'_>],
    depth: Option<&DepthTargets>,
    prior: Option<NormalPrior<'_>>,
    settings: &ShadingRefinement,
) -> Result<ShadingRefined> {
    if let Some(p) = prior
        && !(p.share.is_finite() && (0.0..=1.0).contains(&p.share))
    {
        return Err(MeshError::InvalidArgument(format!(
            "shading refinement: the prior normals' share must lie in [0, 1], got {}",
            p.share
        )));
    }
    let valid = settings.anchor.is_finite()
        && settings.anchor > 0.0
        && settings.max_outward.is_finite()
        && settings.max_outward >= 0.0
        && settings.surrounding_rays > 0
        && settings.rounds > 0
        && settings
            .slack_reference
            .is_none_or(|r| r.is_finite() && r > 0.0)
        && settings.steep_tilt > 0.0
        && settings.steep_tilt < 1.0;
    if !valid {
        return Err(MeshError::InvalidArgument(format!(
            "shading refinement: the anchor and the slack's reference must be positive, the \
             outward bound non-negative, at least one surrounding ray cast and one round run, \
             the steep tilt a sine in (0, 1) (got {}, {:?}, {}, {}, {}, {})",
            settings.anchor,
            settings.slack_reference,
            settings.max_outward,
            settings.surrounding_rays,
            settings.rounds,
            settings.steep_tilt
        )));
    }
    let slack = match settings.slack_reference {
        Some(reference) => {
            let masks: Vec<(Camera, &[f32])> = images
                .iter()
                .filter_map(|v| v.mask.map(|m| (*v.camera, m)))
                .collect();
            if masks.is_empty() {
                return Err(MeshError::InvalidArgument(
                    "shading refinement: holding the vertices by their slack needs the masks"
                        .into(),
                ));
            }
            // Up to twice the reference: the anchor is whole from the reference, the
            // trusted tilt from twice it.
            Some(crate::hull::hull_slack(
                &masks,
                &mesh.positions,
                reference / SLACK_STEPS as f32,
                2.0 * reference,
            )?)
        }
        None => None,
    };
    let unscattered = if settings.unscatter {
        let held: Option<Vec<bool>> = (slack.as_ref().zip(settings.slack_reference))
            .map(|(s, r)| scatter_held_faces(mesh, s, r));
        Some(crate::scatter::unscatter(
            mesh,
            held.as_deref(),
            images,
            settings.shading.min_cos,
        )?)
    } else {
        None
    };
    let owned: Vec<ShadingImage<'_>>;
    let images = match &unscattered {
        Some(u) if u.model.blurs() => {
            owned = (images.iter().zip(&u.radiance))
                .map(|(v, r)| ShadingImage { radiance: r, ..*v })
                .collect();
            &owned[..]
        }
        _ => images,
    };
    let refine_settings = RefineSettings {
        anchor: settings.anchor,
        max_outward: settings.max_outward,
        ..RefineSettings::default()
    };
    let scale: Option<Vec<f32>> = (slack.as_ref().zip(settings.slack_reference))
        .map(|(s, r)| slack_anchor_scale(s, r, SLACK_POWER));
    let tilt: Option<Vec<f32>> = (slack.as_ref().zip(settings.slack_reference))
        .filter(|_| settings.steep_tilt != refine_settings.max_tilt)
        .map(|(s, r)| slack_tilt_limits(mesh, s, r, refine_settings.max_tilt, settings.steep_tilt));
    // A round observes the normals on `on` (the last round's mesh) and refines `mesh` by them.
    let round = |on: &TriMesh| -> Result<(TriMesh, Vec<f32>, ShadingFit)> {
        let caster = crate::raycast::MeshRaycaster::new(on, "the mesh to refine")?;
        let (fit, depths) = observe_shading(
            on,
            &caster,
            images,
            &settings.shading,
            settings.surrounding_rays,
        )?;
        let targets = match prior {
            Some(p) => {
                // A prior view at an image's camera reads that image's ray cast.
                let own = |c: &Camera| images.iter().position(|v| v.camera == c);
                let maps: Vec<Option<Vec<f32>>> = (p.views.iter())
                    .map(|(c, _)| own(c).is_none().then(|| caster.render(c).depth))
                    .collect();
                let nv: Vec<NormalView<'_>> = (p.views.iter().zip(&maps))
                    .map(|((camera, normal), cast)| NormalView {
                        camera,
                        normal,
                        mesh_depth: match cast {
                            Some(d) => d,
                            None => &depths[own(camera).expect("an image's camera")],
                        },
                    })
                    .collect();
                let seen = observed_normals(on, &nv, 1, settings.shading.min_cos)?;
                blend_face_normals(&fit.normals, &seen, p.share)
            }
            None => fit.normals.clone(),
        };
        let (refined, moves) = refine_anchored(
            mesh,
            &targets,
            depth,
            &refine_settings,
            scale.as_deref(),
            tilt.as_deref(),
        )?;
        Ok((refined, moves, fit))
    };
    let (mut refined, mut moves, mut fit) = round(mesh)?;
    let mut round_changes = Vec::with_capacity(settings.rounds.saturating_sub(1));
    // The moves of the mesh the last round observed (`mesh` itself: none).
    let mut last = vec![0.0; moves.len()];
    for _ in 1..settings.rounds {
        // A round that leaves the mesh it observed where it was has reached a fixed point:
        // the next would observe the same mesh and return the same.
        if moves == last {
            break;
        }
        last = moves;
        (refined, moves, fit) = round(&refined)?;
        round_changes.push(rms_difference(&moves, &last));
    }
    Ok(ShadingRefined {
        mesh: refined,
        moves,
        solved: fit.solved(),
        interreflection: fit.interreflection,
        confidence: fit.mean_confidence(),
        slack,
        round_changes,
        scatter: unscattered.map(|u| u.model),
    })
}

/// The root mean square of `a - b` (0 when empty).
fn rms_difference(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len()).max(1);
    let sum: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    (sum / n as f64).sqrt() as f32
}
