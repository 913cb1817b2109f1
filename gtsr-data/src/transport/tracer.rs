//! CPU Monte Carlo path tracer for a closed triangle mesh filled with a homogeneous
//! scattering medium behind a rough dielectric boundary, lit by one point light at the
//! camera centre, black world (optionally a constant environment, for furnace tests).
//!
//! Estimator (unbiased apart from a safety cap of 100 000 scattering events and 256 boundary
//! events per path, which real paths never reach):
//! * camera paths; at every boundary vertex, next-event estimation to the point light with
//!   the rough dielectric BSDF (reflection outside, transmission from inside) and a shadow
//!   ray; the point light cannot be hit by BSDF sampling, so there is nothing to combine by
//!   MIS; inside the medium the light is only reachable through the boundary, so no NEE
//!   there;
//! * boundary: BSDF sampling (pbrt-v4 rough dielectric, radiance mode including the
//!   `1/eta^2` radiance scaling);
//! * medium: free-flight sampling with a uniformly chosen RGB channel and the one-sample
//!   MIS (balance heuristic) weight over channels ("hero"/spectral MIS), HG phase sampling;
//!   Russian roulette on the throughput after 16 scattering events;
//! * the free-flight query uses the [`SafeGrid`] lower bounds at both ends of the sampled
//!   segment to skip the BVH when the segment cannot reach the boundary.
//!
//! Pixel `(i, j)` of view `v` uses its own random stream keyed by `(seed, v, j * W + i)`,
//! so images do not depend on the number of threads. Sub-pixel positions follow the R2
//! low-discrepancy sequence with a random per-pixel shift (box filter over the pixel).

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::ply::TriMesh;
use crate::transport::bvh::{Bvh, SafeGrid};
use crate::transport::material::{Boundary, Interface, Material, sample_hg};
use crate::transport::rng::Rng;

/// Offset of ray origins from the surface, world units (objects have radius 1).
const EPS: f32 = 5e-5;
const MAX_SCATTER: u32 = 100_000;
const MAX_BOUNDARY: u32 = 256;
const RR_AFTER: u32 = 4;
const RR_LEVEL: f32 = 0.1;

/// Russian roulette: when the throughput (times `scale`, which undoes the `1/eta^2`
/// radiance compression inside the object) falls below [`RR_LEVEL`], the path survives with
/// probability `max / RR_LEVEL` and is then re-weighted to that level, so roulette never
/// lifts a path above the level (no fireflies from revived long paths). Returns whether the
/// path survives.
#[inline]
fn roulette(throughput: &mut Vec3, scale: f32, rng: &mut Rng) -> bool {
    let m = throughput.max_element() * scale;
    if m >= RR_LEVEL {
        return true;
    }
    if m <= 0.0 || rng.next_f32() * RR_LEVEL >= m {
        return false;
    }
    *throughput *= RR_LEVEL / m;
    true
}

/// Lighting of a render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Radiant intensity (W/sr, per RGB channel equal) of the point light at the camera centre.
    pub point_intensity: f32,
    /// Constant environment radiance seen by escaping rays (0 = black world).
    pub environment: f32,
}

/// A rendered view: linear radiance premultiplied by coverage (i.e. over a black
/// background) and coverage (fraction of samples whose camera ray hit the object).
#[derive(Clone, Debug)]
pub struct Rendered {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` linear values (premultiplied; environment included when > 0).
    pub rgb: Vec<f32>,
    /// `width * height` coverage values in `[0, 1]`.
    pub alpha: Vec<f32>,
}

/// Geometry shared between tracers of the same mesh.
struct Geometry {
    bvh: Bvh,
    grid: SafeGrid,
    /// The mesh is a convex polyhedron: a ray leaving its surface outward never meets it
    /// again, so exit rays and shadow rays from the surface need no query (exact).
    convex: bool,
    /// Bounding sphere `(centre, radius^2)`: camera rays that miss it skip the BVH.
    bound: (Vec3, f32),
}

/// Whether the ray `o + t d` (`d` unit, `t > 0`) certainly misses the sphere `(c, r^2)`.
#[inline]
fn misses_sphere(o: Vec3, d: Vec3, (c, r2): (Vec3, f32)) -> bool {
    let oc = c - o;
    let t = oc.dot(d);
    let d2 = oc.length_squared() - t * t;
    d2 > r2 || (t < 0.0 && oc.length_squared() > r2)
}

/// Whether a closed mesh is convex: every edge's two triangles bend outward (the far vertex
/// of each neighbour lies on or behind the triangle's plane).
fn is_convex(mesh: &TriMesh) -> bool {
    use std::collections::HashMap;
    let mut edge_tri: HashMap<(u32, u32), usize> = HashMap::with_capacity(mesh.triangles.len() * 3);
    for (k, t) in mesh.triangles.iter().enumerate() {
        for e in 0..3 {
            edge_tri.insert((t[e], t[(e + 1) % 3]), k);
        }
    }
    let p = |i: u32| mesh.positions[i as usize];
    for t in &mesh.triangles {
        let n = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        for e in 0..3 {
            // The neighbour across edge (a, b) owns the directed edge (b, a).
            let Some(&nb) = edge_tri.get(&(t[(e + 1) % 3], t[e])) else {
                return false;
            };
            let other = mesh.triangles[nb];
            let far = other
                .iter()
                .copied()
                .find(|&v| v != t[e] && v != t[(e + 1) % 3])
                .unwrap_or(other[0]);
            if n.dot(p(far) - p(t[0])) > 1e-7 * n.length() {
                return false;
            }
        }
    }
    true
}

/// The tracer for one mesh and material.
pub struct Tracer {
    geo: std::sync::Arc<Geometry>,
    material: Material,
    bsdf: Interface,
    sigma_t: Vec3,
    sigma_s: Vec3,
    /// Undoes the radiance compression inside for Russian roulette (eta^2 for the
    /// refractive boundary, 1 for diffuse transmission).
    rr_scale: f32,
}

impl Tracer {
    /// Builds the BVH and the safe-distance grid.
    pub fn new(mesh: &TriMesh, material: Material) -> Tracer {
        let bvh = Bvh::new(mesh);
        let grid = SafeGrid::new(&bvh, 64);
        let convex = is_convex(mesh);
        let (lo, hi) = mesh.bounds();
        let centre = 0.5 * (lo + hi);
        let r2 = mesh
            .positions
            .iter()
            .map(|p| (*p - centre).length_squared())
            .fold(0.0f32, f32::max)
            * 1.0001
            + 1e-6;
        Self::with_geometry(
            std::sync::Arc::new(Geometry {
                bvh,
                grid,
                convex,
                bound: (centre, r2),
            }),
            material,
        )
    }

    fn with_geometry(geo: std::sync::Arc<Geometry>, material: Material) -> Tracer {
        Tracer {
            geo,
            material,
            bsdf: Interface::new(&material),
            sigma_t: material.sigma_t(),
            sigma_s: Vec3::from(material.sigma_s),
            rr_scale: match material.boundary {
                Boundary::Refractive => material.ior * material.ior,
                Boundary::DiffuseTransmission => 1.0,
            },
        }
    }

    /// The same geometry (shared, not rebuilt) with another material.
    pub fn with_material(&self, material: Material) -> Tracer {
        Self::with_geometry(self.geo.clone(), material)
    }

    /// The material.
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// Renders `camera` with `spp` samples per pixel; `view_key` and `seed` select the
    /// random streams. Parallel over rows.
    pub fn render(
        &self,
        camera: &Camera,
        lighting: Lighting,
        spp: u32,
        seed: u64,
        view_key: u64,
    ) -> Rendered {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let rows: Vec<(Vec<f32>, Vec<f32>)> = (0..h)
            .into_par_iter()
            .map(|j| {
                let mut rgb = vec![0.0f32; 3 * w];
                let mut alpha = vec![0.0f32; w];
                for i in 0..w {
                    let (sum, hits) = self.pixel_sum(camera, i, j, lighting, spp, seed, view_key);
                    let inv = 1.0 / spp.max(1) as f32;
                    rgb[3 * i..3 * i + 3].copy_from_slice(&(sum * inv).to_array());
                    alpha[i] = hits as f32 * inv;
                }
                (rgb, alpha)
            })
            .collect();
        let mut out = Rendered {
            width: camera.width,
            height: camera.height,
            rgb: Vec::with_capacity(3 * w * h),
            alpha: Vec::with_capacity(w * h),
        };
        for (r, a) in rows {
            out.rgb.extend(r);
            out.alpha.extend(a);
        }
        out
    }

    /// Pixel `(i, j)` of `camera` as [`Tracer::render`] renders it: the sum of `spp` paths'
    /// radiance (R2 sub-pixel positions with the pixel's random shift, the pixel's own
    /// stream keyed by `(seed, view_key, j * width + i)`) and how many hit the mesh.
    #[allow(clippy::too_many_arguments)]
    pub fn pixel_sum(
        &self,
        camera: &Camera,
        i: usize,
        j: usize,
        lighting: Lighting,
        spp: u32,
        seed: u64,
        view_key: u64,
    ) -> (Vec3, u32) {
        let c2w = camera.camera_to_world();
        let origin = Vec3::from(c2w.translation);
        let mut rng = Rng::new(seed, view_key, (j * camera.width as usize + i) as u64, 0);
        let shift = Vec2::new(rng.next_f32(), rng.next_f32());
        let mut sum = Vec3::ZERO;
        let mut hits = 0u32;
        for k in 0..spp {
            let s = (shift + Vec2::new(0.754_877_7, 0.569_840_3) * k as f32).fract();
            let dir = c2w
                .transform_vector3(camera.camera_direction(i as f32 + s.x, j as f32 + s.y))
                .normalize();
            let (l, hit) = self.sample_path(origin, dir, origin, lighting, &mut rng);
            sum += l;
            hits += hit as u32;
        }
        (sum, hits)
    }

    /// Contribution of the point light at a boundary vertex.
    #[inline]
    fn next_event(
        &self,
        x: Vec3,
        n: Vec3,
        wo: Vec3,
        light: Vec3,
        intensity: f32,
        known_visible: bool,
    ) -> f32 {
        let to = light - x;
        let d2 = to.length_squared();
        let dist = d2.sqrt();
        let wi = to / dist;
        let (t, b) = n.any_orthonormal_pair();
        let local = |v: Vec3| Vec3::new(v.dot(t), v.dot(b), v.dot(n));
        let (wo_l, wi_l) = (local(wo), local(wi));
        let f = self.bsdf.f(wo_l, wi_l);
        if f <= 0.0 {
            return 0.0;
        }
        let o = x + n * (EPS * wi_l.z.signum());
        // On a convex mesh, a light on the outer side of the surface is never blocked.
        let visible = known_visible || (self.geo.convex && wi_l.z > 0.0);
        if !visible && self.geo.bvh.occluded(o, wi, dist - 2.0 * EPS) {
            return 0.0;
        }
        f * wi_l.z.abs() * intensity / d2
    }

    /// One camera path: returns (radiance, whether the camera ray hit the object).
    pub fn sample_path(
        &self,
        o: Vec3,
        d: Vec3,
        light: Vec3,
        lighting: Lighting,
        rng: &mut Rng,
    ) -> (Vec3, bool) {
        let mut throughput = Vec3::ONE;
        let mut l = Vec3::ZERO;
        let (mut ro, mut rd) = (o, d);
        let mut inside = false;
        let mut primary = false;
        let mut scatters = 0u32;
        let st = self.sigma_t;
        let st_max = st.max_element();
        for bounce in 0..MAX_BOUNDARY {
            let hit = if inside && st_max > 0.0 {
                // Random walk to the boundary.
                loop {
                    let c = ((rng.next_f32() * 3.0) as usize).min(2);
                    let stc = st[c];
                    let t = if stc > 0.0 {
                        -(1.0 - rng.next_f32()).ln() / stc
                    } else {
                        f32::INFINITY
                    };
                    // The segment cannot meet the surface when the distance lower bounds at
                    // its ends add up to more than its length (a crossing point x would give
                    // t = |p - x| + |x - e| >= d(p) + d(e)).
                    let sp = self.geo.grid.safe(ro);
                    let found =
                        if t < sp || (t.is_finite() && t < sp + self.geo.grid.safe(ro + rd * t)) {
                            None
                        } else {
                            self.geo.bvh.intersect(ro, rd, t)
                        };
                    match found {
                        None => {
                            let tr = (-st * t).exp();
                            let pdf = (st * tr).dot(Vec3::ONE) / 3.0;
                            if pdf <= 0.0 {
                                return (l, primary);
                            }
                            throughput *= self.sigma_s * tr / pdf;
                            ro += rd * t;
                            rd = sample_hg(rd, self.material.g, rng.next_f32(), rng.next_f32());
                            scatters += 1;
                            if scatters > RR_AFTER && !roulette(&mut throughput, self.rr_scale, rng)
                            {
                                return (l, primary);
                            }
                            if scatters > MAX_SCATTER {
                                return (l, primary);
                            }
                        }
                        Some(h) => {
                            let tr = (-st * h.t).exp();
                            let p = tr.dot(Vec3::ONE) / 3.0;
                            if p <= 0.0 {
                                return (l, primary);
                            }
                            throughput *= tr / p;
                            break Some(h);
                        }
                    }
                }
            } else if inside || !self.geo.convex || bounce == 0 {
                if bounce == 0 && misses_sphere(ro, rd, self.geo.bound) {
                    None
                } else {
                    self.geo.bvh.intersect(ro, rd, f32::INFINITY)
                }
            } else {
                // Leaving a convex mesh outward: nothing more to hit.
                None
            };
            let Some(h) = hit else {
                l += throughput * lighting.environment;
                return (l, primary);
            };
            if bounce == 0 {
                primary = true;
            }
            let x = ro + rd * h.t;
            let n = h.normal;
            let wo = -rd;
            if lighting.point_intensity > 0.0 {
                // At the camera ray's first hit the light (at the camera centre) is visible
                // by construction when the path started at the light: skip the shadow ray.
                let visible = bounce == 0 && (o - light).length_squared() < 1e-12;
                l += throughput
                    * self.next_event(x, n, wo, light, lighting.point_intensity, visible);
            }
            let (t, b) = n.any_orthonormal_pair();
            let wo_l = Vec3::new(wo.dot(t), wo.dot(b), wo.dot(n));
            let uc = rng.next_f32();
            let u = Vec2::new(rng.next_f32(), rng.next_f32());
            let Some(s) = self.bsdf.sample(wo_l, uc, u) else {
                return (l, primary);
            };
            throughput *= s.weight;
            rd = (t * s.wi.x + b * s.wi.y + n * s.wi.z).normalize();
            let side = s.wi.z.signum();
            ro = x + n * (EPS * side);
            inside = side < 0.0;
            let scale = if inside { self.rr_scale } else { 1.0 };
            if bounce > 4 && !roulette(&mut throughput, scale, rng) {
                return (l, primary);
            }
        }
        (l, primary)
    }

    /// Number of triangles rendered.
    pub fn triangle_count(&self) -> usize {
        self.geo.bvh.len()
    }
}
