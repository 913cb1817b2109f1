//! The arithmetic that the projection and its VJP are written in, so that one source serves a
//! scalar (`f32`, `f64`) and 16 Gaussians at once ([`F32x16`], which the compiler turns into
//! vector code when built for AVX2 or AVX-512).
//!
//! Every operation is the same IEEE operation in both forms (no fused multiply-add, no
//! reassociation), so a Gaussian's results are bit-identical whichever form computed them.

use std::ops::{Add, Div, Mul, Neg, Sub};

use crate::scalar::Real;

/// Numbers of the projection: a scalar, or lanes of scalars with per-lane masks.
pub(crate) trait Arith:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A per-lane boolean (`bool` for a scalar).
    type Mask: Copy;
    /// The constant `v` (rounded to the precision).
    fn c(v: f64) -> Self;
    fn sqrt(self) -> Self;
    fn min(self, o: Self) -> Self;
    fn max(self, o: Self) -> Self;
    /// Where `self != o`.
    fn ne(self, o: Self) -> Self::Mask;
    /// `a` where `m`, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
}

impl<F: Real> Arith for F {
    type Mask = bool;
    #[inline(always)]
    fn c(v: f64) -> Self {
        <F as Real>::c(v)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        num_traits::Float::sqrt(self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        num_traits::Float::min(self, o)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        num_traits::Float::max(self, o)
    }
    #[inline(always)]
    fn ne(self, o: Self) -> bool {
        self != o
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m { a } else { b }
    }
}

/// Lane count of [`F32x16`].
pub(crate) const WIDTH: usize = 16;

/// Sixteen f32 lanes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct F32x16(pub [f32; WIDTH]);

macro_rules! lanewise {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for F32x16 {
            type Output = F32x16;
            #[inline(always)]
            fn $method(self, o: F32x16) -> F32x16 {
                F32x16(std::array::from_fn(|l| self.0[l] $op o.0[l]))
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Neg for F32x16 {
    type Output = F32x16;
    #[inline(always)]
    fn neg(self) -> F32x16 {
        F32x16(self.0.map(|v| -v))
    }
}

impl F32x16 {
    #[inline(always)]
    fn zip(self, o: F32x16, f: impl Fn(f32, f32) -> f32) -> F32x16 {
        F32x16(std::array::from_fn(|l| f(self.0[l], o.0[l])))
    }
}

impl Arith for F32x16 {
    type Mask = [bool; WIDTH];
    #[inline(always)]
    fn c(v: f64) -> Self {
        F32x16([v as f32; WIDTH])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F32x16(self.0.map(f32::sqrt))
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.zip(o, f32::min)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.zip(o, f32::max)
    }
    #[inline(always)]
    fn ne(self, o: Self) -> [bool; WIDTH] {
        std::array::from_fn(|l| self.0[l] != o.0[l])
    }
    #[inline(always)]
    fn select(m: [bool; WIDTH], a: Self, b: Self) -> Self {
        F32x16(std::array::from_fn(|l| if m[l] { a.0[l] } else { b.0[l] }))
    }
}
