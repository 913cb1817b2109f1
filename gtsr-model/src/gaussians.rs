//! The two Gaussian sets as Burn tensors, their activations, and a host-side copy used for
//! densification, checkpoints and export.
//!
//! Every parameter is a `[N, width]` tensor so that densification, pruning and the optimiser
//! state treat them alike. Activations: `scale = exp(log_scale)`, `opacity = logistic(logit)`
//! (for the surface set, optionally above a floor: [`floored_logistic`]),
//! `base = logistic(logit)`, `roughness = logistic(logit)`; quaternions `(w, x, y, z)` are
//! normalised where they are used.

use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

/// Which set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum SetKind {
    /// Flat surface Gaussians: geometry, surface colour, PBR material.
    Surface,
    /// Interior Gaussians: scattering colour.
    Interior,
}

impl SetKind {
    /// Lower-case name.
    pub fn name(&self) -> &'static str {
        match self {
            SetKind::Surface => "surface",
            SetKind::Interior => "interior",
        }
    }
}

/// One parameter tensor of a set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ParamKind {
    /// `[N, 3]` world-space means.
    Means,
    /// `[N, 4]` quaternions `(w, x, y, z)`.
    Rotations,
    /// `[N, 3]` log standard deviations.
    LogScales,
    /// `[N, 1]` opacity logits.
    Opacity,
    /// `[N, 3]` SH DC coefficients.
    ShDc,
    /// `[N, (K - 1) * 3]` higher SH coefficients, coefficient-major.
    ShRest,
    /// `[N, 3]` base-colour logits (surface set with PBR).
    BaseColour,
    /// `[N, 1]` roughness logits (surface set with PBR).
    Roughness,
}

impl ParamKind {
    /// Every parameter kind.
    pub const ALL: [ParamKind; 8] = [
        ParamKind::Means,
        ParamKind::Rotations,
        ParamKind::LogScales,
        ParamKind::Opacity,
        ParamKind::ShDc,
        ParamKind::ShRest,
        ParamKind::BaseColour,
        ParamKind::Roughness,
    ];

    /// Name used in checkpoints and reports.
    pub fn name(&self) -> &'static str {
        match self {
            ParamKind::Means => "means",
            ParamKind::Rotations => "rotations",
            ParamKind::LogScales => "log_scales",
            ParamKind::Opacity => "opacity_logits",
            ParamKind::ShDc => "sh_dc",
            ParamKind::ShRest => "sh_rest",
            ParamKind::BaseColour => "base_colour_logits",
            ParamKind::Roughness => "roughness_logits",
        }
    }
}

/// A set of Gaussians: named `[N, width]` parameter tensors (autodiff leaves while training).
#[derive(Clone, Debug)]
pub struct GaussianSet {
    /// Surface or interior.
    pub kind: SetKind,
    /// The parameters, in a fixed order.
    pub params: Vec<(ParamKind, Tensor<2>)>,
}

/// Copies a float tensor of any rank to the host as `f32` values (row-major).
pub fn host_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .into_vec()
        .expect("float tensor data converts to f32")
}

/// Numerically careful logistic (Burn's `sigmoid` rounds through f32 on NdArray f64).
pub fn logistic<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    (x.neg().exp() + 1.0).recip()
}

/// `floor + (1 - floor) logistic(x)`: an opacity that never falls below `floor` (`[0, 1)`; 0
/// is the plain logistic).
pub fn floored_logistic<const D: usize>(x: Tensor<D>, floor: f64) -> Tensor<D> {
    if floor > 0.0 {
        logistic(x) * (1.0 - floor) + floor
    } else {
        logistic(x)
    }
}

/// The plain logit of the opacity that `logit` gives under `floor` ([`floored_logistic`]):
/// what a reader that applies the plain logistic (a splat viewer, the interior set) must be
/// handed for the same opacity.
pub fn unfloored_logit(logit: f32, floor: f64) -> f32 {
    if floor > 0.0 {
        let o = 1.0 / (1.0 + (-f64::from(logit)).exp());
        self::logit(floor + (1.0 - floor) * o) as f32
    } else {
        logit
    }
}

/// Inverse of the logistic.
pub fn logit(p: f64) -> f64 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

impl GaussianSet {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.params[0].1.dims()[0]
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The parameter tensor of `kind`, if the set has it.
    pub fn get(&self, kind: ParamKind) -> Option<&Tensor<2>> {
        self.params.iter().find(|(k, _)| *k == kind).map(|(_, t)| t)
    }

    /// The parameter tensor of `kind`; panics if absent (a programming error: every set has
    /// means, rotations, scales, opacities and SH DC).
    pub fn req(&self, kind: ParamKind) -> &Tensor<2> {
        self.get(kind)
            .unwrap_or_else(|| panic!("{} set has no {}", self.kind.name(), kind.name()))
    }

    /// `[N, 3]` scales.
    pub fn scales(&self) -> Tensor<2> {
        self.req(ParamKind::LogScales).clone().exp()
    }

    /// `[N]` opacities, at least `floor` ([`floored_logistic`]; 0: the plain logistic).
    pub fn opacities(&self, floor: f64) -> Tensor<1> {
        let n = self.len();
        floored_logistic(self.req(ParamKind::Opacity).clone(), floor).reshape([n])
    }

    /// Marks every parameter as requiring gradient (autodiff leaves).
    pub fn require_grad(mut self) -> Self {
        for (_, t) in self.params.iter_mut() {
            *t = t.clone().detach().require_grad();
        }
        self
    }

    /// Copies the set to the host.
    pub fn to_host(&self) -> HostSet {
        HostSet {
            kind: self.kind,
            n: self.len(),
            columns: self
                .params
                .iter()
                .map(|(k, t)| {
                    let w = t.dims()[1];
                    (*k, w, host_vec(t.clone().detach()))
                })
                .collect(),
        }
    }
}

/// A host copy of a set: per parameter `(kind, width, row-major values)`.
#[derive(Clone, Debug, PartialEq)]
pub struct HostSet {
    /// Surface or interior.
    pub kind: SetKind,
    /// Number of Gaussians.
    pub n: usize,
    /// The parameters.
    pub columns: Vec<(ParamKind, usize, Vec<f32>)>,
}

impl HostSet {
    /// The values of `kind` and its width.
    pub fn column(&self, kind: ParamKind) -> Option<(&[f32], usize)> {
        self.columns
            .iter()
            .find(|(k, _, _)| *k == kind)
            .map(|(_, w, v)| (v.as_slice(), *w))
    }

    /// Rewrites the opacity logits of a set trained with opacity `floor` as the plain logits of
    /// the same opacities ([`unfloored_logit`]).
    pub fn unfloor_opacity(&mut self, floor: f64) {
        if let Some(v) = self.column_mut(ParamKind::Opacity) {
            for l in v.iter_mut() {
                *l = unfloored_logit(*l, floor);
            }
        }
    }

    /// Mutable values of `kind`.
    pub fn column_mut(&mut self, kind: ParamKind) -> Option<&mut Vec<f32>> {
        self.columns
            .iter_mut()
            .find(|(k, _, _)| *k == kind)
            .map(|(_, _, v)| v)
    }

    /// Uploads to `device` (leaves requiring gradient when `device` is an autodiff device).
    pub fn to_device(&self, device: &Device) -> GaussianSet {
        GaussianSet {
            kind: self.kind,
            params: self
                .columns
                .iter()
                .map(|(k, w, v)| {
                    let t =
                        Tensor::<2>::from_data(TensorData::new(v.clone(), [self.n, *w]), device);
                    (
                        *k,
                        if device.is_autodiff() {
                            t.require_grad()
                        } else {
                            t
                        },
                    )
                })
                .collect(),
        }
    }

    /// Keeps rows `keep` (in that order) and appends `extra` (a host set of the same layout).
    pub fn reindex(&self, keep: &[usize], extra: Option<&HostSet>) -> HostSet {
        let columns = self
            .columns
            .iter()
            .map(|(k, w, v)| {
                let mut out = Vec::with_capacity((keep.len() + extra.map_or(0, |e| e.n)) * w);
                for &i in keep {
                    out.extend_from_slice(&v[i * w..(i + 1) * w]);
                }
                if let Some(e) = extra {
                    let (ev, ew) = e.column(*k).expect("same layout");
                    assert_eq!(ew, *w);
                    out.extend_from_slice(ev);
                }
                (*k, *w, out)
            })
            .collect();
        HostSet {
            kind: self.kind,
            n: keep.len() + extra.map_or(0, |e| e.n),
            columns,
        }
    }

    /// An empty set with the same layout.
    pub fn empty_like(&self) -> HostSet {
        HostSet {
            kind: self.kind,
            n: 0,
            columns: self
                .columns
                .iter()
                .map(|(k, w, _)| (*k, *w, Vec::new()))
                .collect(),
        }
    }

    /// Appends one row given per-parameter slices (same order as `columns`).
    pub fn push_row(&mut self, row: &[Vec<f32>]) {
        for ((_, w, v), r) in self.columns.iter_mut().zip(row) {
            assert_eq!(r.len(), *w);
            v.extend_from_slice(r);
        }
        self.n += 1;
    }

    /// Row `i` of every parameter.
    pub fn row(&self, i: usize) -> Vec<Vec<f32>> {
        self.columns
            .iter()
            .map(|(_, w, v)| v[i * w..(i + 1) * w].to_vec())
            .collect()
    }
}

/// Layout of a new set: which parameters and their widths.
pub fn layout(kind: SetKind, sh_coeffs: usize, material: bool) -> Vec<(ParamKind, usize)> {
    let mut l = vec![
        (ParamKind::Means, 3),
        (ParamKind::Rotations, 4),
        (ParamKind::LogScales, 3),
        (ParamKind::Opacity, 1),
        (ParamKind::ShDc, 3),
    ];
    if sh_coeffs > 1 {
        l.push((ParamKind::ShRest, (sh_coeffs - 1) * 3));
    }
    if kind == SetKind::Surface && material {
        l.push((ParamKind::BaseColour, 3));
        l.push((ParamKind::Roughness, 1));
    }
    l
}

/// Builds a host set from positions with isotropic scales from the mean distance to the
/// three nearest neighbours (3DGS), random rotations, the given opacity and grey colour
/// (SH DC 0 is grey 0.5 after the +0.5 offset), base colour 0.5 and roughness 0.5.
pub fn host_set_from_points(
    kind: SetKind,
    points: &[[f32; 3]],
    sh_coeffs: usize,
    material: bool,
    opacity: f64,
    rng: &mut impl rand::RngExt,
) -> HostSet {
    let lay = layout(kind, sh_coeffs, material);
    let scales = knn_scales(points);
    let mut set = HostSet {
        kind,
        n: 0,
        columns: lay.iter().map(|(k, w)| (*k, *w, Vec::new())).collect(),
    };
    let op = logit(opacity) as f32;
    for (p, s) in points.iter().zip(&scales) {
        let q = random_quat(rng);
        let ls = s.max(1e-7).ln();
        let row: Vec<Vec<f32>> = lay
            .iter()
            .map(|(k, w)| match k {
                ParamKind::Means => p.to_vec(),
                ParamKind::Rotations => q.to_vec(),
                ParamKind::LogScales => vec![ls; 3],
                ParamKind::Opacity => vec![op],
                ParamKind::ShDc
                | ParamKind::ShRest
                | ParamKind::BaseColour
                | ParamKind::Roughness => {
                    vec![0.0; *w]
                }
            })
            .collect();
        set.push_row(&row);
    }
    set
}

/// A uniformly random unit quaternion.
pub fn random_quat(rng: &mut impl rand::RngExt) -> [f32; 4] {
    loop {
        let q: [f32; 4] = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
        let n2: f32 = q.iter().map(|v| v * v).sum();
        if n2 > 1e-4 && n2 <= 1.0 {
            let n = n2.sqrt();
            return q.map(|v| v / n);
        }
    }
}

/// Mean distance to the three nearest neighbours of each point (k-d tree).
pub fn knn_scales(points: &[[f32; 3]]) -> Vec<f32> {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    if points.len() < 2 {
        return vec![0.01; points.len()];
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(points);
    let four = std::num::NonZero::new(4).expect("non-zero");
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let found: Vec<f32> = tree
                .nearest_n::<SquaredEuclidean>(p, four)
                .into_iter()
                .filter(|n| n.item as usize != i)
                .take(3)
                .map(|n| n.distance.sqrt())
                .collect();
            if found.is_empty() {
                0.01
            } else {
                found.iter().sum::<f32>() / found.len() as f32
            }
        })
        .collect()
}
