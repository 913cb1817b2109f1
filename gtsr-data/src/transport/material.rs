//! Translucent material: a homogeneous scattering medium (RGB scattering and absorption
//! coefficients, Henyey-Greenstein phase function) inside a dielectric boundary (Fresnel,
//! GGX/Trowbridge-Reitz rough specular reflection and transmission, Walter et al. 2007,
//! sampled through visible normals, Heitz 2018). The BSDF code follows pbrt-v4's
//! `DielectricBxDF` (radiance transport mode).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// Material parameters. Lengths are world units (the objects have bounding radius 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Scattering coefficient per RGB channel (1/length).
    pub sigma_s: [f32; 3],
    /// Absorption coefficient per RGB channel (1/length).
    pub sigma_a: [f32; 3],
    /// Henyey-Greenstein asymmetry in `(-1, 1)`.
    pub g: f32,
    /// Index of refraction of the object (outside is vacuum).
    pub ior: f32,
    /// GGX roughness `alpha` of the boundary (Blender's roughness is `sqrt(alpha)`). `0` is
    /// smooth (with [`Boundary::Refractive`] a point light is then only seen through glints
    /// of zero measure: use `> 0` with the point light).
    pub roughness: f32,
    /// How light crosses the boundary.
    #[serde(default)]
    pub boundary: Boundary,
}

/// How light crosses the object's boundary. Both have Fresnel and a GGX specular
/// reflection lobe on the outside.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Boundary {
    /// Fresnel-weighted diffuse transmission (as Blender/Cycles random-walk subsurface
    /// scattering, which rendered the development data): outside, GGX specular reflection
    /// with probability `F(cos)`, else transmission into the medium with the reciprocal
    /// kernel `f_t = F_t(cos_o) F_t(cos_i) / (pi (1 - F_dr))`; inside, mirror reflection with
    /// probability `F(cos)` else the same transmission out. Lossless for a smooth boundary;
    /// low variance with a point light. Default.
    #[default]
    DiffuseTransmission,
    /// Physically exact rough dielectric: GGX reflection and refraction (Walter et al. 2007)
    /// with total internal reflection. Caustics and refraction through clear media, but with
    /// a point light the images are much noisier (the light is seen through a glossy window).
    Refractive,
}

/// Named materials from opaque-like to very translucent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialPreset {
    /// Dense, absorbing white medium (mean free path 0.005): looks almost diffuse.
    Chalk,
    /// Dense, high-albedo white medium (mean free path 0.03).
    Marble,
    /// Warm wax, mean free path (0.25, 0.18, 0.12), like the `wax_knot` development scene.
    Wax,
    /// Green jade: red and blue absorbed, mean free path 0.3.
    Jade,
    /// Orange amber, blue strongly absorbed, mean free path 0.5.
    Amber,
    /// Very translucent: mean free path 3, nearly clear with a light haze.
    Glassy,
}

impl MaterialPreset {
    /// Every preset, from opaque-like to very translucent.
    pub const ALL: [MaterialPreset; 6] = [
        MaterialPreset::Chalk,
        MaterialPreset::Marble,
        MaterialPreset::Wax,
        MaterialPreset::Jade,
        MaterialPreset::Amber,
        MaterialPreset::Glassy,
    ];

    /// Command-line / metadata name.
    pub fn name(&self) -> &'static str {
        match self {
            MaterialPreset::Chalk => "chalk",
            MaterialPreset::Marble => "marble",
            MaterialPreset::Wax => "wax",
            MaterialPreset::Jade => "jade",
            MaterialPreset::Amber => "amber",
            MaterialPreset::Glassy => "glassy",
        }
    }

    /// The material parameters.
    pub fn material(&self) -> Material {
        // (mean free path, single-scattering albedo, g, roughness)
        let (mfp, albedo, g, roughness): ([f32; 3], [f32; 3], f32, f32) = match self {
            MaterialPreset::Chalk => ([0.005; 3], [0.9; 3], 0.0, 0.3),
            MaterialPreset::Marble => ([0.03; 3], [0.995, 0.99, 0.985], 0.0, 0.1),
            MaterialPreset::Wax => ([0.25, 0.18, 0.12], [0.995, 0.99, 0.96], 0.3, 0.2),
            MaterialPreset::Jade => ([0.3; 3], [0.85, 0.995, 0.9], 0.2, 0.08),
            MaterialPreset::Amber => ([0.5; 3], [0.99, 0.9, 0.5], 0.2, 0.05),
            MaterialPreset::Glassy => ([3.0; 3], [0.99; 3], 0.6, 0.05),
        };
        Material::from_mfp_albedo(mfp, albedo, g, 1.5, roughness)
    }
}

impl std::fmt::Display for MaterialPreset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for MaterialPreset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        MaterialPreset::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                format!("unknown material '{s}' (chalk, marble, wax, jade, amber, glassy)")
            })
    }
}

impl Material {
    /// From mean free path `1 / sigma_t` and single-scattering albedo `sigma_s / sigma_t`.
    pub fn from_mfp_albedo(
        mfp: [f32; 3],
        albedo: [f32; 3],
        g: f32,
        ior: f32,
        roughness: f32,
    ) -> Self {
        let st = mfp.map(|m| 1.0 / m);
        Material {
            sigma_s: [0, 1, 2].map(|c| st[c] * albedo[c]),
            sigma_a: [0, 1, 2].map(|c| st[c] * (1.0 - albedo[c])),
            g,
            ior,
            roughness,
            boundary: Boundary::DiffuseTransmission,
        }
    }

    /// Extinction coefficient `sigma_s + sigma_a`.
    pub fn sigma_t(&self) -> Vec3 {
        Vec3::from(self.sigma_s) + Vec3::from(self.sigma_a)
    }

    /// Checks ranges; returns a message on failure.
    pub fn validate(&self) -> Result<(), String> {
        let all = self.sigma_s.iter().chain(self.sigma_a.iter());
        if all.clone().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(format!(
                "coefficients must be finite and >= 0: sigma_s {:?}, sigma_a {:?}",
                self.sigma_s, self.sigma_a
            ));
        }
        if !(self.g > -1.0 && self.g < 1.0) {
            return Err(format!("g must be in (-1, 1), got {}", self.g));
        }
        if !(self.ior >= 1.0 && self.ior < 4.0) {
            return Err(format!("ior must be in [1, 4), got {}", self.ior));
        }
        if !(0.0..=1.0).contains(&self.roughness) {
            return Err(format!(
                "roughness must be in [0, 1], got {}",
                self.roughness
            ));
        }
        Ok(())
    }
}

/// Samples a direction from the Henyey-Greenstein phase function around `d`
/// (`g > 0`: forward). Returns a unit vector; the phase function is sampled exactly, so the
/// path weight is 1.
pub fn sample_hg(d: Vec3, g: f32, u1: f32, u2: f32) -> Vec3 {
    let cos_t = if g.abs() < 1e-3 {
        1.0 - 2.0 * u1
    } else {
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
    };
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    let (t, b) = d.any_orthonormal_pair();
    (t * (sin_t * phi.cos()) + b * (sin_t * phi.sin()) + d * cos_t).normalize()
}

/// Unpolarised Fresnel reflectance of a dielectric interface; `cos_i` measured against the
/// normal on the outside, `eta` = inside IOR / outside IOR (pbrt-v4 `FrDielectric`).
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let mut cos_i = cos_i.clamp(-1.0, 1.0);
    let mut eta = eta;
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
    }
    let sin2_i = 1.0 - cos_i * cos_i;
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_parl * r_parl + r_perp * r_perp)
}

/// Refraction of `wi` (pointing away from the surface) through normal `n`; `eta` relative
/// IOR (inside/outside, `n` outward). Returns the transmitted direction and the relative
/// IOR actually crossed (`eta` or `1/eta`), or `None` on total internal reflection
/// (pbrt-v4 `Refract`).
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<(Vec3, f32)> {
    let mut cos_i = n.dot(wi);
    let mut eta = eta;
    let mut n = n;
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
        n = -n;
    }
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    Some((-wi / eta + (cos_i / eta - cos_t) * n, eta))
}

/// Isotropic GGX (Trowbridge-Reitz) distribution in a local frame with the normal at +z.
#[derive(Clone, Copy, Debug)]
pub struct Ggx {
    /// Roughness alpha.
    pub alpha: f32,
}

#[inline]
fn tan2(w: Vec3) -> f32 {
    let c2 = w.z * w.z;
    (1.0 - c2).max(0.0) / c2
}

impl Ggx {
    /// Normal distribution `D(wm)`.
    pub fn d(&self, wm: Vec3) -> f32 {
        let t2 = tan2(wm);
        if !t2.is_finite() {
            return 0.0;
        }
        let cos4 = (wm.z * wm.z) * (wm.z * wm.z);
        if cos4 < 1e-16 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let e = t2 / a2;
        1.0 / (PI * a2 * cos4 * (1.0 + e) * (1.0 + e))
    }

    /// Smith `Lambda(w)`.
    pub fn lambda(&self, w: Vec3) -> f32 {
        let t2 = tan2(w);
        if !t2.is_finite() {
            return 0.0;
        }
        ((1.0 + self.alpha * self.alpha * t2).sqrt() - 1.0) / 2.0
    }

    /// Masking `G1(w)`.
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking-shadowing `G(wo, wi)`.
    pub fn g(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Density of visible normals `D_w(wm)` (pdf of [`Ggx::sample_wm`] over `wm`).
    pub fn pdf(&self, w: Vec3, wm: Vec3) -> f32 {
        self.g1(w) / w.z.abs() * self.d(wm) * w.dot(wm).abs()
    }

    /// Samples a visible normal for direction `w` (Heitz 2018), upper hemisphere.
    pub fn sample_wm(&self, w: Vec3, u: Vec2) -> Vec3 {
        let mut wh = Vec3::new(self.alpha * w.x, self.alpha * w.y, w.z).normalize();
        if wh.z < 0.0 {
            wh = -wh;
        }
        let t1 = if wh.z < 0.99999 {
            Vec3::Z.cross(wh).normalize()
        } else {
            Vec3::X
        };
        let t2 = wh.cross(t1);
        // Uniform disk (polar).
        let r = u.x.sqrt();
        let th = 2.0 * PI * u.y;
        let mut p = Vec2::new(r * th.cos(), r * th.sin());
        let h = (1.0 - p.x * p.x).max(0.0).sqrt();
        let s = (1.0 + wh.z) / 2.0;
        p.y = (1.0 - s) * h + s * p.y;
        let pz = (1.0 - p.length_squared()).max(0.0).sqrt();
        let nh = p.x * t1 + p.y * t2 + pz * wh;
        Vec3::new(self.alpha * nh.x, self.alpha * nh.y, nh.z.max(1e-6)).normalize()
    }
}

/// A sampled BSDF direction.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Local-frame direction (z = outward normal).
    pub wi: Vec3,
    /// `f * |cos| / pdf`.
    pub weight: f32,
}

/// The boundary BSDF of a [`Material`] (either model), local frame with z = outward normal.
#[derive(Clone, Copy, Debug)]
pub struct Interface {
    /// Model.
    pub model: Boundary,
    /// Rough dielectric (also gives the GGX reflection of the diffuse model).
    pub dielectric: Dielectric,
    /// `1 / (1 - F_dr)`, the normalisation of the diffuse transmission kernel.
    norm: f32,
}

/// External Fresnel transmittance `1 - F(cos)` for relative IOR `eta` (light arriving
/// from outside at `|cos|`).
#[inline]
fn ft(cos: f32, eta: f32) -> f32 {
    1.0 - fresnel_dielectric(cos.abs(), eta)
}

impl Interface {
    /// The interface of a material.
    pub fn new(m: &Material) -> Interface {
        // 1 - F_dr = 2 * integral_0^1 F_t(mu) mu dmu (midpoint rule).
        let n = 4096;
        let t: f64 = (0..n)
            .map(|k| {
                let mu = (k as f32 + 0.5) / n as f32;
                (ft(mu, m.ior) * mu) as f64
            })
            .sum::<f64>()
            * 2.0
            / n as f64;
        Interface {
            model: m.boundary,
            dielectric: Dielectric {
                eta: m.ior,
                ggx: Ggx { alpha: m.roughness },
            },
            norm: (1.0 / t) as f32,
        }
    }

    /// BSDF value (radiance transport), `wo` towards the viewer, `wi` towards the light.
    pub fn f(&self, wo: Vec3, wi: Vec3) -> f32 {
        match self.model {
            Boundary::Refractive => self.dielectric.f(wo, wi),
            Boundary::DiffuseTransmission => {
                let eta = self.dielectric.eta;
                if wo.z * wi.z < 0.0 {
                    self.norm * ft(wo.z, eta) * ft(wi.z, eta) / PI
                } else if wo.z > 0.0 && !self.dielectric.is_smooth() {
                    // GGX reflection on the outside (inside reflection is a mirror).
                    let wm = (wo + wi).normalize();
                    let g = self.dielectric.ggx;
                    fresnel_dielectric(wo.dot(wm), eta) * g.d(wm) * g.g(wo, wi)
                        / (4.0 * wo.z * wi.z)
                } else {
                    0.0
                }
            }
        }
    }

    /// Samples `wi` given `wo` (`uc`, `u` uniform); `None` when the path ends.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        match self.model {
            Boundary::Refractive => self.dielectric.sample(wo, uc, u),
            Boundary::DiffuseTransmission => {
                let eta = self.dielectric.eta;
                let fr = fresnel_dielectric(wo.z.abs(), eta);
                if uc < fr {
                    if wo.z < 0.0 || self.dielectric.is_smooth() {
                        return Some(BsdfSample {
                            wi: Vec3::new(-wo.x, -wo.y, wo.z),
                            weight: 1.0,
                        });
                    }
                    let g = self.dielectric.ggx;
                    let wm = g.sample_wm(wo, u);
                    let wi = -wo + 2.0 * wo.dot(wm) * wm;
                    if wi.z <= 0.0 {
                        return None;
                    }
                    // f cos / pdf with pdf = fr * D_wo(wm) / (4 |wo.wm|).
                    let weight = fresnel_dielectric(wo.dot(wm), eta) / fr * g.g(wo, wi) / g.g1(wo);
                    return Some(BsdfSample { wi, weight });
                }
                // Cosine-distributed transmission to the other side.
                let r = u.x.sqrt();
                let phi = 2.0 * PI * u.y;
                let z = (1.0 - u.x).max(0.0).sqrt();
                let mut wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                if wo.z > 0.0 {
                    wi.z = -wi.z;
                }
                if wi.z == 0.0 {
                    return None;
                }
                Some(BsdfSample {
                    wi,
                    weight: self.norm * ft(wi.z, eta),
                })
            }
        }
    }
}

/// Smoothness threshold below which the boundary is treated as perfectly smooth.
const SMOOTH: f32 = 1e-3;

/// Rough dielectric BSDF in the local frame (z = outward normal, `eta` = inside/outside).
#[derive(Clone, Copy, Debug)]
pub struct Dielectric {
    /// Relative IOR inside/outside.
    pub eta: f32,
    /// Microfacet distribution.
    pub ggx: Ggx,
}

impl Dielectric {
    /// Whether the BSDF is a delta (smooth) one.
    pub fn is_smooth(&self) -> bool {
        self.ggx.alpha < SMOOTH || self.eta == 1.0
    }

    /// BSDF value for radiance transport, `wo` towards the viewer, `wi` towards the light.
    /// Zero for a smooth boundary.
    pub fn f(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.is_smooth() {
            return 0.0;
        }
        let (co, ci) = (wo.z, wi.z);
        if co == 0.0 || ci == 0.0 {
            return 0.0;
        }
        let reflect = co * ci > 0.0;
        let etap = if reflect {
            1.0
        } else if co > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        };
        let wm = wi * etap + wo;
        if wm.length_squared() == 0.0 {
            return 0.0;
        }
        let mut wm = wm.normalize();
        if wm.z < 0.0 {
            wm = -wm;
        }
        if wm.dot(wi) * ci < 0.0 || wm.dot(wo) * co < 0.0 {
            return 0.0;
        }
        let fr = fresnel_dielectric(wo.dot(wm), self.eta);
        if reflect {
            self.ggx.d(wm) * self.ggx.g(wo, wi) * fr / (4.0 * ci * co).abs()
        } else {
            let denom = {
                let x = wi.dot(wm) + wo.dot(wm) / etap;
                x * x * ci * co
            };
            let ft = self.ggx.d(wm)
                * (1.0 - fr)
                * self.ggx.g(wo, wi)
                * (wi.dot(wm) * wo.dot(wm) / denom).abs();
            ft / (etap * etap)
        }
    }

    /// Samples `wi` given `wo`; `None` when the path is absorbed by the microfacet model
    /// (sampled direction below the surface).
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        if self.is_smooth() {
            let r = fresnel_dielectric(wo.z, self.eta);
            if uc < r {
                return Some(BsdfSample {
                    wi: Vec3::new(-wo.x, -wo.y, wo.z),
                    weight: 1.0,
                });
            }
            let (wi, etap) = refract(wo, Vec3::Z, self.eta)?;
            return Some(BsdfSample {
                wi,
                weight: 1.0 / (etap * etap),
            });
        }
        let wm = self.ggx.sample_wm(wo, u);
        let r = fresnel_dielectric(wo.dot(wm), self.eta);
        let pdf_wm = self.ggx.pdf(wo, wm);
        if pdf_wm <= 0.0 {
            return None;
        }
        if uc < r {
            let wi = -wo + 2.0 * wo.dot(wm) * wm;
            if wo.z * wi.z <= 0.0 {
                return None;
            }
            let pdf = pdf_wm / (4.0 * wo.dot(wm).abs()) * r;
            let f = self.ggx.d(wm) * self.ggx.g(wo, wi) * r / (4.0 * wi.z * wo.z).abs();
            Some(BsdfSample {
                wi,
                weight: f * wi.z.abs() / pdf,
            })
        } else {
            let (wi, etap) = refract(wo, wm, self.eta)?;
            if wo.z * wi.z >= 0.0 || wi.z == 0.0 {
                return None;
            }
            let t = 1.0 - r;
            let x = wi.dot(wm) + wo.dot(wm) / etap;
            let denom = x * x;
            let dwm_dwi = wi.dot(wm).abs() / denom;
            let pdf = pdf_wm * dwm_dwi * t;
            let ft = t
                * self.ggx.d(wm)
                * self.ggx.g(wo, wi)
                * (wi.dot(wm) * wo.dot(wm) / (wi.z * wo.z * denom)).abs()
                / (etap * etap);
            if pdf <= 0.0 {
                return None;
            }
            Some(BsdfSample {
                wi,
                weight: ft * wi.z.abs() / pdf,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::rng::Rng;

    /// The BSDF's sampling weights and its evaluation agree: E[weight] over BSDF samples
    /// equals the integral of f |cos| estimated with uniform sphere sampling, for both
    /// reflection and transmission, from outside and from inside.
    #[test]
    fn sampling_matches_evaluation() {
        for (alpha, boundary) in [0.1f32, 0.3, 0.6].into_iter().flat_map(|a| {
            [
                (a, Boundary::Refractive),
                (a, Boundary::DiffuseTransmission),
            ]
        }) {
            let m = Material {
                boundary,
                ..Material::from_mfp_albedo([1.0; 3], [1.0; 3], 0.0, 1.5, alpha)
            };
            let bsdf = Interface::new(&m);
            for &(ct, sign) in &[(0.9f32, 1.0f32), (0.5, 1.0), (0.9, -1.0), (0.8, -1.0)] {
                let st = (1.0 - ct * ct).sqrt();
                let wo = Vec3::new(st, 0.0, sign * ct);
                let mut rng = Rng::new(1, 2, 3, 4);
                let n = 400_000;
                let (mut rs, mut ts) = (0.0f64, 0.0f64);
                for _ in 0..n {
                    let (uc, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
                    if let Some(s) = bsdf.sample(wo, uc, Vec2::new(u1, u2)) {
                        // The diffuse model's inside reflection is a mirror (delta): skip it.
                        let delta = boundary == Boundary::DiffuseTransmission && wo.z < 0.0;
                        if s.wi.z * wo.z > 0.0 {
                            if !delta {
                                rs += s.weight as f64
                            }
                        } else {
                            ts += s.weight as f64
                        }
                    }
                }
                let (mut re, mut te) = (0.0f64, 0.0f64);
                for _ in 0..n {
                    let z = 1.0 - 2.0 * rng.next_f32();
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let phi = 2.0 * PI * rng.next_f32();
                    let wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                    let v = (bsdf.f(wo, wi) * wi.z.abs() * 4.0 * PI) as f64;
                    if wi.z * wo.z > 0.0 { re += v } else { te += v }
                }
                let n = n as f64;
                let (rs, ts, re, te) = (rs / n, ts / n, re / n, te / n);
                assert!(
                    (rs - re).abs() < 0.02 + 0.05 * re,
                    "{boundary:?} alpha {alpha} wo {wo}: reflection sampled {rs} vs evaluated {re}"
                );
                assert!(
                    (ts - te).abs() < 0.02 + 0.05 * te,
                    "{boundary:?} alpha {alpha} wo {wo}: transmission sampled {ts} vs evaluated {te}"
                );
            }
        }
    }
}
