//! The Gaussians of one render on the host: borrowed slices ([`HostGaussians`], what the
//! kernels read) and owned buffers ([`HostBuffers`], also the layout of the gradients).

use crate::scalar::Real;

/// The Gaussians of one render as host slices (row-major, `N` rows).
#[derive(Clone, Copy, Debug)]
pub struct HostGaussians<'a, F> {
    /// `[N, 3]` world-space means.
    pub means: &'a [F],
    /// `[N, 4]` quaternions (w, x, y, z), normalised inside.
    pub quats: &'a [F],
    /// `[N, 3]` scales (standard deviations along the local axes).
    pub scales: &'a [F],
    /// `[N]` opacities.
    pub opacities: &'a [F],
    /// `[N, C]` features.
    pub features: &'a [F],
    /// `[N, 2]` screen-space offsets added to the projected means (zeros normally; their
    /// gradient is the screen-space positional gradient used for densification).
    pub xy_offsets: &'a [F],
}

impl<F: Real> HostGaussians<'_, F> {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    /// Whether one of Gaussian `i`'s `c` features is NaN or infinite (such a Gaussian is
    /// culled, status 2).
    pub(super) fn feature_not_finite(&self, i: usize, c: usize) -> bool {
        self.features[i * c..(i + 1) * c]
            .iter()
            .any(|f| !f.is_finite())
    }
}

/// Owned host buffers laid out as the raw splat inputs: the inputs themselves (borrowed as
/// [`HostGaussians`] by [`HostBuffers::host`]) or their gradients ([`HostGradients`]).
#[derive(Debug, Clone)]
pub struct HostBuffers<F> {
    /// `[N, 3]`
    pub means: Vec<F>,
    /// `[N, 4]`
    pub quats: Vec<F>,
    /// `[N, 3]`
    pub scales: Vec<F>,
    /// `[N]`
    pub opacities: Vec<F>,
    /// `[N, C]`
    pub features: Vec<F>,
    /// `[N, 2]`
    pub xy_offsets: Vec<F>,
}

impl<F> HostBuffers<F> {
    /// The buffers as kernel inputs.
    pub fn host(&self) -> HostGaussians<'_, F> {
        splat_fields!(HostGaussians, &self, |v| v.as_slice())
    }

    /// The six buffers in input order: means, quats, scales, opacities, features, offsets.
    pub fn into_parts(self) -> [Vec<F>; 6] {
        splat_fields!([], self, |v| v)
    }
}

/// Gradients of the raw inputs, laid out as the inputs.
pub type HostGradients<F> = HostBuffers<F>;
