//! The surface set's starting points: sampled inside the masks' hull, or in a ball.

use rand::{RngExt, rngs::StdRng};

use crate::config::{Init, TrainConfig};
use crate::error::ModelError;
use crate::views::ViewTensors;

use super::*;

fn uniform_ball(rng: &mut StdRng, radius: f64) -> [f32; 3] {
    loop {
        let p: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        if p.iter().map(|v| v * v).sum::<f64>() <= 1.0 {
            return p.map(|v| (v * radius) as f32);
        }
    }
}

fn project_host(cam: &gtsr_render_kernels::Camera, p: [f32; 3]) -> Option<(f64, f64)> {
    let pc: [f64; 3] = std::array::from_fn(|i| {
        (0..3)
            .map(|j| cam.rotation[i][j] * f64::from(p[j]))
            .sum::<f64>()
            + cam.translation[i]
    });
    (pc[2] > cam.near).then(|| {
        (
            cam.fx * pc[0] / pc[2] + cam.cx,
            cam.fy * pc[1] / pc[2] + cam.cy,
        )
    })
}

/// Whether `p` projects inside every training mask that sees it (views without a mask, or
/// that `p` projects outside of or lies behind, do not count).
fn inside_masks(masks: &[(&gtsr_render_kernels::Camera, Option<&Vec<f32>>)], p: [f32; 3]) -> bool {
    masks
        .iter()
        .all(|(cam, m)| match (m, project_host(cam, p)) {
            (Some(m), Some((u, v))) => {
                let (w, h) = (cam.width as f64, cam.height as f64);
                if u < 0.0 || v < 0.0 || u >= w || v >= h {
                    true
                } else {
                    m[(v as usize) * cam.width as usize + u as usize] >= 0.5
                }
            }
            _ => true,
        })
}

/// Marching steps per init radius when [`Init::HullSurface`] walks out to the hull's boundary.
const HULL_MARCH_STEPS: f64 = 200.0;

/// Initial surface points: uniform in a ball; (mask-carved) only those whose projection lies
/// inside every training mask that sees them; or (hull-surface) on the boundary of that
/// carved volume, the masks' visual hull: from each carved point, a walk along a random
/// direction in steps of `HULL_MARCH_STEPS`-ths (200) of the init radius to the first point
/// outside some mask, then 12 bisections. `views` and `hosts` are the same views, on the
/// device and on the host (the masks are read from the host views).
pub fn initial_points(
    config: &TrainConfig,
    views: &[ViewTensors],
    hosts: &[gtsr_data::View],
) -> Result<Vec<[f32; 3]>, ModelError> {
    let masks: Vec<(&gtsr_render_kernels::Camera, Option<&Vec<f32>>)> = views
        .iter()
        .zip(hosts)
        .map(|(v, h)| (&v.camera, h.mask.as_ref()))
        .collect();
    let mut rng = step_rng(config.seed, 0, RNG_INIT);
    let n = config.init_surface;
    if config.init == Init::Random {
        return Ok((0..n)
            .map(|_| uniform_ball(&mut rng, config.init_radius))
            .collect());
    }
    let name = match config.init {
        Init::HullSurface => "hull-surface",
        _ => "mask-carved",
    };
    if masks.iter().all(|(_, m)| m.is_none()) {
        return Err(ModelError::Config(format!(
            "{name} initialisation needs masks; the data has none"
        )));
    }
    let mut pts = Vec::with_capacity(n);
    let mut tries = 0usize;
    let step = config.init_radius / HULL_MARCH_STEPS;
    while pts.len() < n && tries < n * 200 {
        tries += 1;
        let p = uniform_ball(&mut rng, config.init_radius);
        if !inside_masks(&masks, p) {
            continue;
        }
        if config.init != Init::HullSurface {
            pts.push(p);
            continue;
        }
        let d = {
            let u = uniform_ball(&mut rng, 1.0);
            let l = u.iter().map(|x| x * x).sum::<f32>().sqrt();
            if l < 1e-3 {
                continue;
            }
            u.map(|x| x / l)
        };
        let at = |t: f64| -> [f32; 3] { std::array::from_fn(|k| p[k] + (t as f32) * d[k]) };
        // Walk out (the hull is bounded by the cameras' masks; give up past two radii).
        let (mut lo, mut hi) = (0.0, step);
        while hi < 2.0 * config.init_radius && inside_masks(&masks, at(hi)) {
            lo = hi;
            hi += step;
        }
        if hi >= 2.0 * config.init_radius {
            continue;
        }
        for _ in 0..12 {
            let mid = 0.5 * (lo + hi);
            if inside_masks(&masks, at(mid)) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        pts.push(at(lo));
    }
    if pts.len() < n / 10 {
        return Err(ModelError::Data(format!(
            "{name} initialisation found only {} of {n} points inside the masks within radius {}",
            pts.len(),
            config.init_radius
        )));
    }
    Ok(pts)
}
