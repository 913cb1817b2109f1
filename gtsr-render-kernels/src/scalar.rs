//! The floating-point type the CPU kernels are written over (`f32` or `f64`).

use core::fmt::Debug;

/// `f32` or `f64`: the CPU kernels are generic over it so that the same code serves training
/// (f32) and the f64 reference used by the finite-difference tests.
pub trait Real: num_traits::Float + Send + Sync + Debug + Default + 'static {
    /// Converts from `f64` (rounding for `f32`).
    fn c(v: f64) -> Self;
    /// Widens to `f64`.
    fn f64(self) -> f64;
    /// The slice itself when `Self` is `f32` (routes f32 to the SIMD blend), else `None`.
    fn slice_as_f32(s: &[Self]) -> Option<&[f32]>;
    /// [`Real::slice_as_f32`] for a mutable slice.
    fn slice_as_f32_mut(s: &mut [Self]) -> Option<&mut [f32]>;
    /// An `f32` slice as `&[Self]` when `Self` is `f32` (borrows a tensor's data), else `None`.
    fn slice_from_f32(s: &[f32]) -> Option<&[Self]>;
    /// An `f64` slice as `&[Self]` when `Self` is `f64`, else `None`.
    fn slice_from_f64(s: &[f64]) -> Option<&[Self]>;
}

impl Real for f32 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn f64(self) -> f64 {
        f64::from(self)
    }
    #[inline(always)]
    fn slice_as_f32(s: &[Self]) -> Option<&[f32]> {
        Some(s)
    }
    #[inline(always)]
    fn slice_as_f32_mut(s: &mut [Self]) -> Option<&mut [f32]> {
        Some(s)
    }
    #[inline(always)]
    fn slice_from_f32(s: &[f32]) -> Option<&[Self]> {
        Some(s)
    }
    #[inline(always)]
    fn slice_from_f64(_: &[f64]) -> Option<&[Self]> {
        None
    }
}

impl Real for f64 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn slice_as_f32(_: &[Self]) -> Option<&[f32]> {
        None
    }
    #[inline(always)]
    fn slice_as_f32_mut(_: &mut [Self]) -> Option<&mut [f32]> {
        None
    }
    #[inline(always)]
    fn slice_from_f32(_: &[f32]) -> Option<&[Self]> {
        None
    }
    #[inline(always)]
    fn slice_from_f64(s: &[f64]) -> Option<&[Self]> {
        Some(s)
    }
}
