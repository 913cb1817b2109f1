//! The model's formulas against direct per-pixel / per-Gaussian evaluations in f64.

use burn::tensor::{Bool, Device, Tensor, TensorData};
use gtsr_model::config::Components;
use gtsr_model::gaussians::{HostSet, ParamKind, SetKind, host_vec, layout, logit};
use gtsr_model::geometry::pixel_rays;
use gtsr_model::losses;
use gtsr_model::model::{GeometryMaps, Model, RenderOptions};
use gtsr_model::pbr::{self, GBuffer, ShadingParams};
use gtsr_model::sh;
use gtsr_render_kernels::cpu::HostGaussians;
use gtsr_render_kernels::reference::render_reference;
use gtsr_render_kernels::{AlphaCutoff, Camera, SplatConfig, SplatInputs, render};
use rand::{RngExt, SeedableRng, rngs::StdRng};

const SHADING: ShadingParams = ShadingParams {
    f0: 0.04,
    gamma: 0.3,
    min_roughness: 0.08,
    scatter_lambert: false,
    scatter_srgb: false,
};

fn camera() -> Camera {
    Camera::look_at([0.3, -0.2, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.7, 40, 32).unwrap()
}

fn random_set(
    kind: SetKind,
    n: usize,
    components: &Components,
    rng: &mut StdRng,
    flat: bool,
) -> HostSet {
    let lay = layout(kind, components.sh_coeffs(), components.pbr);
    let mut set = HostSet {
        kind,
        n: 0,
        columns: lay.iter().map(|(k, w)| (*k, *w, Vec::new())).collect(),
    };
    for _ in 0..n {
        let row: Vec<Vec<f32>> = lay
            .iter()
            .map(|(k, w)| match k {
                ParamKind::Means => (0..3).map(|_| rng.random_range(-0.6..0.6)).collect(),
                ParamKind::LogScales => {
                    let mut s: Vec<f32> = (0..3).map(|_| rng.random_range(-2.5f32..-1.2)).collect();
                    if flat {
                        s[rng.random_range(0..3)] = -6.0;
                    }
                    s
                }
                ParamKind::Opacity => vec![rng.random_range(-1.0..2.0)],
                _ => (0..*w).map(|_| rng.random_range(-0.8..0.8)).collect(),
            })
            .collect();
        set.push_row(&row);
    }
    set
}

fn quat_matrix(q: &[f64]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Per Gaussian: opacity (times Fresnel for surface ones) and SH colour, in f64 on the host.
fn direct_inputs(set: &HostSet, cam: &Camera, degree: u32, fresnel: bool) -> (Vec<f64>, Vec<f64>) {
    let c = cam.centre();
    let col = |k| {
        set.column(k)
            .map(|(v, w)| (v.iter().map(|x| f64::from(*x)).collect::<Vec<_>>(), w))
    };
    let (means, _) = col(ParamKind::Means).unwrap();
    let (rot, _) = col(ParamKind::Rotations).unwrap();
    let (ls, _) = col(ParamKind::LogScales).unwrap();
    let (op, _) = col(ParamKind::Opacity).unwrap();
    let (dc, _) = col(ParamKind::ShDc).unwrap();
    let rest = col(ParamKind::ShRest);
    let mut opac = Vec::new();
    let mut colours = Vec::new();
    for i in 0..set.n {
        let mu = &means[3 * i..3 * i + 3];
        let d: Vec<f64> = (0..3).map(|k| mu[k] - c[k]).collect();
        let len = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        let dir = [d[0] / len, d[1] / len, d[2] / len];
        let basis = sh::basis_host(dir, degree);
        for ch in 0..3 {
            let mut v = basis[0] * dc[3 * i + ch] + 0.5;
            for (j, b) in basis.iter().enumerate().skip(1) {
                let (r, w) = rest.as_ref().unwrap();
                v += b * r[i * w + (j - 1) * 3 + ch];
            }
            colours.push(v.max(0.0));
        }
        let mut o = 1.0 / (1.0 + (-op[i]).exp());
        if fresnel {
            let r = quat_matrix(&rot[4 * i..4 * i + 4]);
            let s = &ls[3 * i..3 * i + 3];
            let a = (0..3).min_by(|x, y| s[*x].total_cmp(&s[*y])).unwrap();
            let n = [r[0][a], r[1][a], r[2][a]];
            let cos = -(0..3).map(|k| n[k] * dir[k]).sum::<f64>();
            let cos = cos.abs(); // the normal is flipped to face the camera
            o *= 0.04 + 0.96 * (1.0 - cos).powi(5);
        }
        opac.push(o);
    }
    (opac, colours)
}

/// The full model (SH degree 3, light 3 in log) over two host sets.
fn full_model(surf: &HostSet, int: &HostSet, device: &Device) -> Model {
    Model {
        components: Components::FULL,
        surface: surf.to_device(device),
        interior: Some(int.to_device(device)),
        log_light: Some(Tensor::from_data(
            TensorData::new(vec![3.0f32], [1, 1]),
            device,
        )),
        sh_degree: 3,
        blur_px2: gtsr_render_kernels::PIXEL_BOX_BLUR_PX2,
        compensate_blur: false,
        surface_opacity_floor: 0.0,
        plane_blur_px2: 0.0,
    }
}

#[test]
fn c_sh_matches_direct_evaluation() {
    let device = Device::ndarray();
    let comps = Components::FULL;
    let mut rng = StdRng::seed_from_u64(7);
    let surf = random_set(SetKind::Surface, 24, &comps, &mut rng, true);
    let int = random_set(SetKind::Interior, 12, &comps, &mut rng, false);
    let model = full_model(&surf, &int, &device);
    let cam = camera();
    let rays = pixel_rays(&cam, &device);
    let opts = RenderOptions {
        stage2: true,
        geometry: true,
        track_offsets: false,
        shading: SHADING,
        pbr_srgb: false,
        spread: false,
    };
    let r = model.render(&cam, &rays, opts).unwrap();
    assert_eq!(r.passes, 3, "C_SH, geometry, scattering");

    let (mut o, mut f) = direct_inputs(&surf, &cam, 3, true);
    let (oi, fi) = direct_inputs(&int, &cam, 3, false);
    o.extend(oi);
    f.extend(fi);
    let cat = |k| {
        let mut v: Vec<f64> = surf
            .column(k)
            .unwrap()
            .0
            .iter()
            .map(|x| f64::from(*x))
            .collect();
        v.extend(int.column(k).unwrap().0.iter().map(|x| f64::from(*x)));
        v
    };
    let means = cat(ParamKind::Means);
    let quats = cat(ParamKind::Rotations);
    let scales: Vec<f64> = cat(ParamKind::LogScales).iter().map(|v| v.exp()).collect();
    let offsets = vec![0.0; o.len() * 2];
    let g = HostGaussians {
        means: &means,
        quats: &quats,
        scales: &scales,
        opacities: &o,
        features: &f,
        xy_offsets: &offsets,
    };
    let cfg = SplatConfig {
        camera: cam.clone(),
        background: vec![0.0; 3],
        cutoff: AlphaCutoff::Hard,
        blur_px2: model.blur_px2,
        compensate_blur: model.compensate_blur,
    };
    let direct = render_reference(&g, &cfg);
    let got = host_vec(r.c_sh);
    let mut worst: f64 = 0.0;
    for p in 0..(40 * 32) {
        for c in 0..3 {
            worst = worst.max((f64::from(got[p * 3 + c]) - direct[p * 4 + c]).abs());
        }
    }
    assert!(
        worst < 2e-4,
        "C_SH differs from the direct evaluation by {worst}"
    );
    let energy: f64 = direct.iter().map(|v| v.abs()).sum();
    assert!(energy > 1.0, "the scene must cover pixels");
}

/// Lit as a diffuse lobe, the scattering map is the interior set's degree-0 colour: the
/// same as the paper's map of a set without its higher SH coefficients, and not the paper's
/// map of the set itself.
#[test]
fn the_lit_scattering_map_takes_the_interior_sets_degree_zero_colour() {
    let device = Device::ndarray();
    let comps = Components::FULL;
    let mut rng = StdRng::seed_from_u64(9);
    let surf = random_set(SetKind::Surface, 24, &comps, &mut rng, true);
    let int = random_set(SetKind::Interior, 12, &comps, &mut rng, false);
    let mut int_dc = int.clone();
    int_dc
        .column_mut(ParamKind::ShRest)
        .unwrap()
        .iter_mut()
        .for_each(|v| *v = 0.0);
    let model = |int: &HostSet| full_model(&surf, int, &device);
    let cam = camera();
    let rays = pixel_rays(&cam, &device);
    let scatter = |m: &Model, scatter_lambert: bool| {
        let opts = RenderOptions {
            stage2: true,
            geometry: true,
            track_offsets: false,
            shading: ShadingParams {
                scatter_lambert,
                ..SHADING
            },
            pbr_srgb: false,
            spread: false,
        };
        host_vec(m.render(&cam, &rays, opts).unwrap().scatter.unwrap())
    };
    let worst = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let lit = scatter(&model(&int), true);
    assert!(worst(&lit, &scatter(&model(&int_dc), false)) < 1e-6);
    let paper = scatter(&model(&int), false);
    assert!(
        worst(&lit, &paper) > 1e-2,
        "the higher coefficients should show in the paper's map"
    );
}

#[test]
fn unbiased_depth_is_the_ray_plane_intersection() {
    let device = Device::ndarray();
    let cam = camera();
    let rays = pixel_rays(&cam, &device);
    // One large, flat, nearly opaque Gaussian, tilted.
    let (a, b) = (0.4f64, 0.3f64);
    let q = [
        (a / 2.0).cos(),
        (a / 2.0).sin() * b.cos(),
        (a / 2.0).sin() * b.sin(),
        0.0,
    ];
    let mean = [0.1f32, -0.05, 0.2];
    let model = surface_only_model(
        &[Splat {
            mean,
            quat: q.map(|v| v as f32),
            scales: [2.0, 2.0, 1e-4],
            opacity: 0.999,
        }],
        gtsr_render_kernels::BLUR_PX2,
        &device,
    );
    let g = model.render_depth(&cam, &rays).unwrap();
    let depth = host_vec(g.depth);
    let cov = host_vec(g.coverage);
    // Plane in camera space: normal = R * (third rotation column), point = R mean + t.
    let r = quat_matrix(&q);
    let nw = [r[0][2], r[1][2], r[2][2]];
    let nc: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| cam.rotation[i][j] * nw[j]).sum());
    let pc: [f64; 3] = std::array::from_fn(|i| {
        (0..3)
            .map(|j| cam.rotation[i][j] * f64::from(mean[j]))
            .sum::<f64>()
            + cam.translation[i]
    });
    let mut checked = 0;
    for j in 0..32usize {
        for i in 0..40usize {
            let p = j * 40 + i;
            if cov[p] < 0.9 {
                continue;
            }
            let ray = [
                (i as f64 + 0.5 - cam.cx) / cam.fx,
                (j as f64 + 0.5 - cam.cy) / cam.fy,
                1.0,
            ];
            let num: f64 = (0..3).map(|k| nc[k] * pc[k]).sum();
            let den: f64 = (0..3).map(|k| nc[k] * ray[k]).sum();
            let z = num / den;
            let rel = (f64::from(depth[p]) - z).abs() / z;
            assert!(
                rel < 1e-4,
                "pixel ({i}, {j}): depth {} vs plane {z}",
                depth[p]
            );
            checked += 1;
        }
    }
    assert!(checked > 300, "only {checked} covered pixels");
}

/// A splat thinner than a pixel covers less of its image without the blur, and a copy with
/// the training's own blur renders exactly as the model does.
#[test]
fn the_readout_blur_changes_what_a_thin_splat_covers() {
    let device = Device::ndarray();
    let cam = camera();
    let rays = pixel_rays(&cam, &device);
    let model = surface_only_model(
        &[Splat {
            mean: [0.0, 0.0, 0.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            scales: [0.6, 0.004, 1e-4],
            opacity: 0.9,
        }],
        gtsr_render_kernels::PIXEL_BOX_BLUR_PX2,
        &device,
    );
    let coverage = |m: &Model| host_vec(m.render_depth(&cam, &rays).unwrap().coverage);
    let trained = coverage(&model);
    let same = coverage(&model.detached_with_blur(model.blur_px2));
    assert_eq!(trained, same);
    let sharp = coverage(&model.detached_with_blur(0.0));
    let (sum_trained, sum_sharp): (f32, f32) = (trained.iter().sum(), sharp.iter().sum());
    assert!(
        sum_trained > 1.0,
        "the thin splat covers {sum_trained} pixels"
    );
    assert!(
        sum_sharp < 0.9 * sum_trained,
        "coverage without the blur {sum_sharp}, with it {sum_trained}"
    );
}

/// The blur moved into each splat's plane covers what the screen-space blur covers for a
/// splat that faces the camera, and does not widen a splat seen edge-on.
#[test]
fn the_plane_blur_keeps_a_facing_splat_and_leaves_an_edge_on_one_thin() {
    let device = Device::ndarray();
    let cam = camera();
    let rays = pixel_rays(&cam, &device);
    let coverage = |splat: Splat, plane: bool| -> f32 {
        let model = surface_only_model(&[splat], gtsr_render_kernels::BLUR_PX2, &device);
        let model = if plane {
            model.detached_with_plane_blur(model.blur_px2)
        } else {
            model
        };
        host_vec(model.render_depth(&cam, &rays).unwrap().coverage)
            .iter()
            .sum()
    };
    // Normal along the view axis, a third of a pixel wide (a footprint is about 0.073 here).
    let facing = Splat {
        mean: [0.0, 0.0, 0.0],
        quat: [1.0, 0.0, 0.0, 0.0],
        scales: [0.025, 0.02, 1e-4],
        opacity: 0.9,
    };
    let (screen, plane) = (coverage(facing, false), coverage(facing, true));
    assert!(screen > 0.5, "the facing splat covers {screen} pixels");
    assert!(
        (plane / screen - 1.0).abs() < 0.1,
        "facing splat: {plane} pixels with the plane's blur, {screen} with the screen's"
    );
    // Normal along y: the camera looks along the splat's plane, which projects to a line.
    let edge_on = Splat {
        mean: [0.0, 0.0, 0.0],
        quat: [1.0, 0.0, 0.0, 0.0],
        scales: [0.6, 1e-4, 0.05],
        opacity: 0.9,
    };
    let (screen, plane) = (coverage(edge_on, false), coverage(edge_on, true));
    assert!(screen > 2.0, "the edge-on splat covers {screen} pixels");
    assert!(
        plane < 0.5 * screen,
        "edge-on splat: {plane} pixels with the plane's blur, {screen} with the screen's"
    );
}

/// `with_farther` takes the other maps only where they are a surface lying more than the gap
/// behind, and keeps these maps everywhere else.
#[test]
fn with_farther_takes_only_the_surfaces_beyond_the_gap() {
    let device = Device::ndarray();
    let maps = |depth: [f32; 4], coverage: [f32; 4], normal_z: f32| {
        let t2 = |v: [f32; 4]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [2, 2]), &device);
        GeometryMaps {
            normal: Tensor::<3>::from_data(
                TensorData::new(
                    (0..4)
                        .flat_map(|_| [0.0, 0.0, normal_z])
                        .collect::<Vec<f32>>(),
                    [2, 2, 3],
                ),
                &device,
            ),
            plane: t2(depth.map(|d| -d)),
            coverage: t2(coverage),
            depth: t2(depth),
            base: None,
            roughness: None,
            spread: None,
            tile_splats: 1,
        }
    };
    // Focal 100 at depth 2: a footprint is 0.02, three of them 0.06.
    let near = maps([2.0; 4], [1.0; 4], -1.0);
    let farther = maps([2.05, 2.5, 2.5, 1.0], [1.0, 1.0, 0.3, 1.0], 1.0);
    let merged = near.with_farther(farther, 100.0, 3.0);
    // Pixel 0: 2.5 footprints behind, kept; 1: taken; 2: not a surface there; 3: in front.
    assert_eq!(host_vec(merged.depth), vec![2.0, 2.5, 2.0, 2.0]);
    assert_eq!(host_vec(merged.plane), vec![-2.0, -2.5, -2.0, -2.0]);
    assert_eq!(host_vec(merged.coverage), vec![1.0; 4]);
    let nz: Vec<f32> = host_vec(merged.normal).chunks(3).map(|n| n[2]).collect();
    assert_eq!(nz, vec![-1.0, 1.0, -1.0, -1.0]);
    assert_eq!(merged.tile_splats, 2);
}

/// The crossing depth takes one layer of a stack where the blended depth averages them.
#[test]
fn crossing_depth_is_one_layer_of_a_stack() {
    let device = Device::ndarray();
    // Three facing layers of opacity 0.5 at z-depths 3.8, 4.0, 4.2: the transmittance after
    // each is just above 0.5, 0.25, 0.125.
    let (model, cam) = facing_stack(&[-0.2, 0.0, 0.2], &device);
    let rays = pixel_rays(&cam, &device);
    let blended = host_vec(model.render_depth(&cam, &rays).unwrap().depth);
    for (threshold, want) in [(0.9, 3.8), (0.5, 4.0), (0.2, 4.2)] {
        let g = model.render_depth_crossing(&cam, &rays, threshold).unwrap();
        let depth = host_vec(g.depth);
        assert!(host_vec(g.coverage).iter().all(|c| *c == 1.0));
        for (p, d) in depth.iter().enumerate() {
            assert!(
                (f64::from(*d) - want).abs() < 1e-4,
                "threshold {threshold}, pixel {p}: depth {d}, want {want}"
            );
        }
    }
    // The blend sits between the layers, nearer the front: (0.5 3.8 + 0.25 4 + 0.125 4.2) / 0.875.
    for d in &blended {
        assert!((f64::from(*d) - 3.9143).abs() < 1e-3, "blended depth {d}");
    }
    // Nothing crosses a threshold below the final transmittance.
    let g = model.render_depth_crossing(&cam, &rays, 0.1).unwrap();
    assert!(host_vec(g.coverage).iter().all(|c| *c == 0.0));
}

/// With a surface opacity floor every surface splat hides what lies behind it by at least the
/// floor, and the set's plain logits (export, demotion) give the same opacities.
#[test]
fn a_surface_opacity_floor_raises_every_surface_opacity_alike() {
    let device = Device::ndarray();
    // Two facing layers of logistic part 0.5 at z-depths 3.9 and 4.1; with floor 0.8 each has
    // opacity 0.8 + 0.2 * 0.5 = 0.9.
    let (mut model, cam) = facing_stack(&[-0.1, 0.1], &device);
    let rays = pixel_rays(&cam, &device);
    let plain = model.render_depth(&cam, &rays).unwrap();
    model.surface_opacity_floor = 0.8;
    let floored = model.render_depth(&cam, &rays).unwrap();
    let want_depth = (0.9 * 3.9 + 0.09 * 4.1) / 0.99;
    for (c, d) in host_vec(floored.coverage)
        .iter()
        .zip(host_vec(floored.depth))
    {
        assert!((f64::from(*c) - 0.99).abs() < 1e-4, "coverage {c}");
        assert!((f64::from(d) - want_depth).abs() < 1e-3, "depth {d}");
    }
    for c in host_vec(plain.coverage) {
        assert!(
            (f64::from(c) - 0.75).abs() < 1e-4,
            "coverage without the floor {c}"
        );
    }
    let opacities = host_vec(model.opacities(&model.surface));
    assert!(opacities.iter().all(|o| (f64::from(*o) - 0.9).abs() < 1e-6));
    let mut host = model.surface.to_host();
    host.unfloor_opacity(model.surface_opacity_floor);
    let (logits, _) = host.column(ParamKind::Opacity).unwrap();
    for l in logits {
        assert!((f64::from(*l) - logit(0.9)).abs() < 1e-4, "plain logit {l}");
    }
    // Without a floor the logits are left alone.
    let mut same = model.surface.to_host();
    same.unfloor_opacity(0.0);
    assert_eq!(same, model.surface.to_host());
}

/// Facing discs (normal along the view axis) at world `z` values `zs`, opacity 0.5, seen
/// head-on from `(0, 0, -4)`: their plane distances are `4 + z`.
fn facing_stack(zs: &[f32], device: &Device) -> (Model, Camera) {
    let discs: Vec<([f32; 3], [f32; 4])> = zs
        .iter()
        .map(|&z| ([0.0, 0.0, z], [1.0, 0.0, 0.0, 0.0]))
        .collect();
    disc_model(&discs, device)
}

/// One surface Gaussian of [`surface_only_model`].
#[derive(Clone, Copy)]
struct Splat {
    mean: [f32; 3],
    quat: [f32; 4],
    /// Standard deviations.
    scales: [f32; 3],
    opacity: f64,
}

/// A model of surface Gaussians alone (no interior set, Fresnel or PBR; SH degree 0, black).
fn surface_only_model(splats: &[Splat], blur_px2: f64, device: &Device) -> Model {
    let lay = layout(SetKind::Surface, 1, false);
    let mut set = HostSet {
        kind: SetKind::Surface,
        n: 0,
        columns: lay.iter().map(|(k, w)| (*k, *w, Vec::new())).collect(),
    };
    for g in splats {
        set.push_row(&[
            g.mean.to_vec(),
            g.quat.to_vec(),
            g.scales.iter().map(|s| s.ln()).collect(),
            vec![logit(g.opacity) as f32],
            vec![0.0; 3],
        ]);
    }
    Model {
        components: Components {
            interior: false,
            fresnel: false,
            pbr: false,
            sh_degree: 0,
            ..Components::FULL
        },
        surface: set.to_device(device),
        interior: None,
        log_light: None,
        sh_degree: 0,
        blur_px2,
        compensate_blur: false,
        surface_opacity_floor: 0.0,
        plane_blur_px2: 0.0,
    }
}

/// Wide flat discs `(mean, quaternion)`, opacity 0.5, and the camera at `(0, 0, -4)` facing +z.
fn disc_model(discs: &[([f32; 3], [f32; 4])], device: &Device) -> (Model, Camera) {
    let splats: Vec<Splat> = discs
        .iter()
        .map(|&(mean, quat)| Splat {
            mean,
            quat,
            scales: [100.0, 100.0, 1e-4],
            opacity: 0.5,
        })
        .collect();
    let model = surface_only_model(&splats, gtsr_render_kernels::PIXEL_BOX_BLUR_PX2, device);
    let cam = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.7, 24, 24).unwrap();
    (model, cam)
}

#[test]
fn layer_spread_is_the_weighted_variance_of_the_ray_crossing_depths() {
    let device = Device::ndarray().autodiff();
    let opts = RenderOptions {
        stage2: false,
        geometry: true,
        track_offsets: false,
        shading: SHADING,
        pbr_srgb: false,
        spread: true,
    };
    let centre = 12 * 24 + 12;
    // Two layers at depths z1 < z2: blend weights 0.5 and 0.25 (the discs are so wide, about
    // 800 px standard deviation on screen, that their Gaussian is above 0.9997 at every pixel),
    // so at every pixel the inverse depths 1/z1 and 1/z2 have the variance
    // (2/3) (1/3) (1/z1 - 1/z2)^2.
    let two = |z1: f64, z2: f64| 2.0 / 9.0 * (1.0 / z1 - 1.0 / z2).powi(2);
    for (zs, want) in [
        (vec![-0.1f32, 0.1], two(3.9, 4.1)),
        (vec![0.3f32, 0.5], two(4.3, 4.5)),
        (vec![0.0f32], 0.0),
        (vec![0.2f32, 0.2], 0.0),
    ] {
        let (model, cam) = facing_stack(&zs, &device);
        let rays = pixel_rays(&cam, &device);
        let r = model.render(&cam, &rays, opts).unwrap();
        let g = r.geometry.expect("geometry maps");
        let spread = g.spread.clone().expect("asked for the spread");
        let v = host_vec(spread.clone());
        for (p, x) in v.iter().enumerate() {
            assert!(
                (f64::from(*x) - want).abs() < 1e-3 * want + 1e-9,
                "layers {zs:?}: spread {x} at pixel {p}, want {want}"
            );
        }
        // The loss: the depth spread z^2 sqrt(var) in pixel footprints z / f, softened by e.
        let valid = g.coverage.clone().detach().greater_elem(0.1);
        let loss = losses::layer_spread(&spread, &g.depth, cam.fx, &valid);
        let z = f64::from(host_vec(g.depth.clone())[centre]);
        let e = losses::regular::LAYER_SPREAD_EPS_PX;
        let px = want.sqrt() * z * cam.fx;
        let expect = (px * px + e * e).sqrt() - e;
        let got = loss.clone().into_scalar::<f64>();
        assert!(
            (got - expect).abs() < 1e-3 * expect.max(1e-3),
            "layers {zs:?}: loss {got}, want {expect}"
        );
        // Its gradient reaches the layers' positions and opacities, finite also at 0 spread.
        let grads = loss.backward();
        for k in [ParamKind::Means, ParamKind::Opacity] {
            let gr = model.surface.req(k).grad(&grads).expect("a gradient");
            let gv = host_vec(gr);
            assert!(gv.iter().all(|x| x.is_finite()), "{k:?}: {gv:?}");
            if zs.len() == 2 && want > 0.0 && k == ParamKind::Means {
                // Pulling the layers together lowers the loss: the front one moves back (+z),
                // the back one forward.
                assert!(gv[2] < 0.0 && gv[5] > 0.0, "layers {zs:?}: dL/dz {gv:?}");
            }
        }
    }
    // One tilted plane made of two discs whose centres lie at different depths: the splats
    // cross every ray at the same depth, so the spread is 0 (where a spread of centre depths
    // would not be).
    let (a, h) = (0.6f32, 0.3f32);
    let q = [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0];
    let in_plane = |v: f32| [0.0, v * a.cos(), v * a.sin()];
    let (model, cam) = disc_model(&[(in_plane(-h), q), (in_plane(h), q)], &device);
    let rays = pixel_rays(&cam, &device);
    let g = model.render(&cam, &rays, opts).unwrap().geometry.unwrap();
    let v = host_vec(g.spread.unwrap());
    let worst = v.iter().fold(0.0f32, |m, x| m.max(*x));
    // Centre depths 4 -/+ 0.3 sin(0.6) with these weights would give (2/9)(1/z1 - 1/z2)^2 = 1e-4.
    assert!(worst < 1e-8, "one tilted plane: spread up to {worst}");

    // Without the option the map is absent and the pass keeps its channels.
    let (model, cam) = facing_stack(&[0.0], &device);
    let rays = pixel_rays(&cam, &device);
    let r = model
        .render(
            &cam,
            &rays,
            RenderOptions {
                spread: false,
                ..opts
            },
        )
        .unwrap();
    assert!(r.geometry.unwrap().spread.is_none());
}

#[test]
fn pbr_matches_per_pixel_evaluation_and_stays_finite_at_extremes() {
    let device = Device::ndarray().autodiff();
    let (h, w) = (3usize, 4usize);
    let mut rng = StdRng::seed_from_u64(11);
    let mut normal = Vec::new();
    let mut depth = Vec::new();
    let mut cov = Vec::new();
    let mut base = Vec::new();
    let mut rough = Vec::new();
    let mut scatter = Vec::new();
    let mut rays = Vec::new();
    for p in 0..h * w {
        let ray = [
            rng.random_range(-0.3..0.3f32),
            rng.random_range(-0.3..0.3f32),
            1.0,
        ];
        let mut n = [
            rng.random_range(-0.5..0.5f32),
            rng.random_range(-0.5..0.5f32),
            -rng.random_range(0.3..1.0f32),
        ];
        let c = rng.random_range(0.2..1.0f32);
        let mut d = rng.random_range(2.0..5.0f32);
        let mut r = rng.random_range(0.1..0.9f32) * c;
        match p {
            0 => r = 0.0,                    // roughness 0
            1 => n = [ray[1], -ray[0], 0.0], // normal perpendicular to the ray: grazing
            2 => d = 0.0,                    // depth 0
            3 => n = [0.0, 0.0, 0.0],        // no surface
            _ => {}
        }
        normal.extend(n.map(|v| v * c));
        depth.push(d);
        cov.push(c);
        base.extend((0..3).map(|_| rng.random_range(0.0..1.0f32) * c));
        rough.push(r);
        if p == 4 {
            // A black, a negative and an over-bright scattering colour (SH colours are not
            // bounded above).
            scatter.extend([0.0, -0.3, 3.0]);
        } else {
            scatter.extend((0..3).map(|_| rng.random_range(0.0..1.0f32)));
        }
        rays.extend(ray);
    }
    // The paper's scattering map, the same lit as a diffuse lobe, each taken as linear or
    // decoded from sRGB.
    for (scatter_lambert, scatter_srgb) in
        [(false, false), (true, false), (false, true), (true, true)]
    {
        let shading = ShadingParams {
            scatter_lambert,
            scatter_srgb,
            ..SHADING
        };
        let leaf3 = |v: &Vec<f32>| {
            Tensor::<3>::from_data(TensorData::new(v.clone(), [h, w, 3]), &device).require_grad()
        };
        let leaf2 = |v: &Vec<f32>| {
            Tensor::<2>::from_data(TensorData::new(v.clone(), [h, w]), &device).require_grad()
        };
        let gb = GBuffer {
            normal: leaf3(&normal),
            depth: leaf2(&depth),
            coverage: leaf2(&cov),
            base: leaf3(&base),
            roughness: leaf2(&rough),
            scatter: Some(leaf3(&scatter)),
            rays: Tensor::from_data(TensorData::new(rays.clone(), [h, w, 3]), &device),
        };
        let light =
            Tensor::<2>::from_data(TensorData::new(vec![12.0f32], [1, 1]), &device).require_grad();
        let out = pbr::shade(&gb, light.clone(), shading);
        let got = host_vec(out.colour.clone());
        for p in 0..h * w {
            let f = |v: &Vec<f32>, k: usize| f64::from(v[3 * p + k]);
            let want = pbr::shade_pixel(
                [f(&normal, 0), f(&normal, 1), f(&normal, 2)],
                f64::from(depth[p]),
                f64::from(cov[p]),
                [f(&base, 0), f(&base, 1), f(&base, 2)],
                f64::from(rough[p]),
                Some([f(&scatter, 0), f(&scatter, 1), f(&scatter, 2)]),
                [f(&rays, 0), f(&rays, 1), f(&rays, 2)],
                12.0,
                shading,
            );
            for k in 0..3 {
                let g = f64::from(got[3 * p + k]);
                assert!(
                    (g - want[k]).abs() <= 1e-4 * want[k].abs().max(1.0),
                    "lambert {scatter_lambert}, srgb {scatter_srgb}, pixel {p} channel {k}: {g} vs {}",
                    want[k]
                );
            }
        }
        let grads = out.colour.sum().backward();
        for (name, g) in [
            ("normal", gb.normal.grad(&grads).map(|g| g.into_data())),
            ("base", gb.base.grad(&grads).map(|g| g.into_data())),
            (
                "scatter",
                gb.scatter
                    .as_ref()
                    .unwrap()
                    .grad(&grads)
                    .map(|g| g.into_data()),
            ),
        ] {
            let v: Vec<f32> = g.unwrap().convert::<f32>().into_vec().unwrap();
            assert!(
                v.iter().all(|x| x.is_finite()),
                "{name} gradient not finite: {v:?}"
            );
        }
        for (name, g) in [
            ("depth", gb.depth.grad(&grads)),
            ("coverage", gb.coverage.grad(&grads)),
            ("roughness", gb.roughness.grad(&grads)),
        ] {
            let v = host_vec(g.unwrap());
            assert!(
                v.iter().all(|x| x.is_finite()),
                "{name} gradient not finite: {v:?}"
            );
        }
        let gl: f32 = light.grad(&grads).unwrap().into_scalar();
        assert!(gl.is_finite() && gl > 0.0);
    }
}

#[test]
fn schlick_and_srgb_endpoints() {
    let device = Device::ndarray();
    let c = Tensor::<1>::from_data(
        TensorData::new(vec![0.0f32, 1.0, 0.5, -0.2, 1.5], [5]),
        &device,
    );
    let f = host_vec(pbr::schlick(c, 0.04));
    assert!((f[0] - 1.0).abs() < 1e-6 && (f[1] - 0.04).abs() < 1e-6);
    assert!((f[2] - (0.04 + 0.96 / 32.0)).abs() < 1e-6);
    assert!(
        (f[3] - 1.0).abs() < 1e-6 && (f[4] - 0.04).abs() < 1e-6,
        "clamped outside [0, 1]"
    );
    let x = Tensor::<1>::from_data(
        TensorData::new(vec![0.0f32, 0.001, 0.18, 1.0, 2.0], [5]),
        &device,
    );
    let s = host_vec(pbr::linear_to_srgb(x.clone()));
    assert!((s[0]).abs() < 1e-7 && (s[1] - 0.01292).abs() < 1e-6);
    assert!((s[2] - 0.461_356).abs() < 1e-4, "{}", s[2]);
    assert!((s[3] - 1.0).abs() < 1e-6 && (s[4] - 1.0).abs() < 1e-6);
    // Decoding undoes the encoding on [0, 1], matches the host version, and extends past 1.
    let back = host_vec(pbr::srgb_to_linear(pbr::linear_to_srgb(x.clone())));
    for (b, want) in back.iter().zip([0.0f32, 0.001, 0.18, 1.0, 1.0]) {
        assert!(
            (b - want).abs() < 1e-5 * want.max(1e-3) + 1e-7,
            "{b} vs {want}"
        );
    }
    let dec = host_vec(pbr::srgb_to_linear(x));
    for (d, v) in dec.iter().zip([0.0f64, 0.001, 0.18, 1.0, 2.0]) {
        let want = gtsr_data::image_io::srgb_to_linear_f64(v);
        assert!(
            (f64::from(*d) - want).abs() < 1e-5 * want.max(1.0),
            "{d} vs {want}"
        );
    }
    assert!(dec[4] > 4.0, "past 1 by the same power: {}", dec[4]);
    assert_eq!(
        host_vec(pbr::srgb_to_linear(Tensor::<1>::from_data(
            TensorData::new(vec![-0.5f32], [1]),
            &device
        )))[0],
        0.0
    );
}

#[test]
fn sh_colours_match_the_host_basis() {
    let device = Device::ndarray();
    let mut rng = StdRng::seed_from_u64(5);
    let n = 20;
    let dirs: Vec<f32> = (0..n)
        .flat_map(|_| {
            let v: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let l = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / l)
        })
        .collect();
    let dc: Vec<f32> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
    let rest: Vec<f32> = (0..n * 45).map(|_| rng.random_range(-0.5..0.5)).collect();
    let t = |v: &Vec<f32>, w| Tensor::<2>::from_data(TensorData::new(v.clone(), [n, w]), &device);
    for degree in 0..=3u32 {
        // Unit means seen from the origin: the directions are the means.
        let got = host_vec(sh::colours(
            &t(&dc, 3),
            Some(&t(&rest, 45)),
            &t(&dirs, 3),
            [0.0; 3],
            degree,
        ));
        for i in 0..n {
            let b = sh::basis_host(std::array::from_fn(|k| f64::from(dirs[3 * i + k])), degree);
            for c in 0..3 {
                let mut v = b[0] * f64::from(dc[3 * i + c]) + 0.5;
                for (j, bj) in b.iter().enumerate().skip(1) {
                    v += bj * f64::from(rest[i * 45 + (j - 1) * 3 + c]);
                }
                assert!(
                    (f64::from(got[3 * i + c]) - v.max(0.0)).abs() < 1e-5,
                    "degree {degree}"
                );
            }
        }
    }
}

#[test]
fn ssim_and_l1_behave() {
    let device = Device::ndarray();
    let mut rng = StdRng::seed_from_u64(9);
    let v: Vec<f32> = (0..24 * 20 * 3)
        .map(|_| rng.random_range(0.0..1.0))
        .collect();
    let a = Tensor::<3>::from_data(TensorData::new(v.clone(), [24, 20, 3]), &device);
    let s: f32 = losses::ssim(a.clone(), a.clone()).into_scalar();
    assert!(
        (s - 1.0).abs() < 1e-5,
        "SSIM of an image with itself is {s}"
    );
    let b = a.clone() * 0.5 + 0.2;
    let s2: f32 = losses::ssim(a.clone(), b.clone()).into_scalar();
    assert!(s2 < 0.95, "SSIM {s2}");
    let l: f32 = losses::l1(a.clone(), a.clone() + 0.1).into_scalar();
    assert!((l - 0.1).abs() < 1e-6);
}

#[test]
fn initial_scales_are_the_mean_three_neighbour_distance() {
    // A 5x5x5 grid of spacing 0.1: an inner point has six neighbours at 0.1.
    let pts: Vec<[f32; 3]> = (0..125)
        .map(|i| {
            [
                (i % 5) as f32 * 0.1,
                ((i / 5) % 5) as f32 * 0.1,
                (i / 25) as f32 * 0.1,
            ]
        })
        .collect();
    let s = gtsr_model::gaussians::knn_scales(&pts);
    assert!((s[62] - 0.1).abs() < 1e-5, "centre point scale {}", s[62]);
    assert!(
        s.iter().all(|v| (*v - 0.1).abs() < 1e-5),
        "every grid point has three neighbours at 0.1"
    );
}

/// Opacity logits from ordinary to far beyond f32's logistic range.
const EXTREME_LOGITS: [f64; 7] = [0.0, 2.0, -3.0, 80.0, -80.0, 1e4, -1e4];

/// `xs` as a differentiable `[n, 1]` column on the autodiff CPU device.
fn logit_column(xs: &[f64]) -> Tensor<2> {
    let data = TensorData::new(
        xs.iter().map(|x| *x as f32).collect::<Vec<_>>(),
        [xs.len(), 1],
    );
    Tensor::<2>::from_data(data, &Device::ndarray().autodiff()).require_grad()
}

#[test]
fn opacity_entropy_is_the_binary_entropy_and_stays_finite_at_extreme_logits() {
    let xs = EXTREME_LOGITS;
    let t = logit_column(&xs);
    let loss = losses::opacity_entropy(&t);
    let value = loss.clone().into_scalar::<f64>();
    let expected: f64 = xs
        .iter()
        .map(|&x| {
            let o = 1.0 / (1.0 + (-x).exp());
            let h = |p: f64| if p > 0.0 { -p * p.ln() } else { 0.0 };
            h(o) + h(1.0 - o)
        })
        .sum::<f64>()
        / xs.len() as f64;
    assert!(
        (value - expected).abs() < 1e-5,
        "{value} against {expected}"
    );
    let grads = loss.backward();
    let g = host_vec(t.grad(&grads).expect("a gradient"));
    for (x, g) in xs.iter().zip(&g) {
        assert!(g.is_finite(), "logit {x}: gradient {g}");
        // d/dx of the mean entropy: -x o (1 - o) / n; descent pushes away from 0.
        let o = 1.0 / (1.0 + (-x).exp());
        let want = -x * o * (1.0 - o) / xs.len() as f64;
        assert!(
            (*g as f64 - want).abs() < 1e-4,
            "logit {x}: {g} against {want}"
        );
    }
}

#[test]
fn opacity_l1_is_the_mean_opacity_and_stays_finite_at_extreme_logits() {
    let xs = EXTREME_LOGITS;
    let t = logit_column(&xs);
    let loss = losses::opacity_l1(&t);
    let sigmoid = |x: f64| 1.0 / (1.0 + (-x).exp());
    let expected = xs.iter().map(|&x| sigmoid(x)).sum::<f64>() / xs.len() as f64;
    let value = loss.clone().into_scalar::<f64>();
    assert!(
        (value - expected).abs() < 1e-6,
        "{value} against {expected}"
    );
    let g = host_vec(t.grad(&loss.backward()).expect("a gradient"));
    for (x, g) in xs.iter().zip(&g) {
        // d/dx of the mean opacity: o (1 - o) / n, never negative: descent only fades.
        let o = sigmoid(*x);
        let want = o * (1.0 - o) / xs.len() as f64;
        assert!(g.is_finite() && *g >= 0.0, "logit {x}: gradient {g}");
        assert!(
            (f64::from(*g) - want).abs() < 1e-6,
            "logit {x}: {g} against {want}"
        );
    }
    assert!(g[0] > 0.0, "the gradient at logit 0 is 1/(4n)");
}

#[test]
fn the_mask_deficit_counts_only_missing_coverage_inside_the_mask() {
    let device = Device::ndarray().autodiff();
    let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [2, 2]), &device);
    let alpha = t(vec![0.25, 0.75, 0.5, 0.125]).require_grad();
    let mask = t(vec![1.0, 1.0, 0.0, 0.0]);
    // Inside: 0.75 and 0.25 missing; outside: the 0.5 and 0.125 spills do not count.
    let loss = losses::mask_deficit(&alpha, &mask);
    assert!((loss.clone().into_scalar::<f64>() - 1.0 / 4.0).abs() < 1e-6);
    let g = host_vec(alpha.grad(&loss.backward()).expect("a gradient"));
    assert_eq!(g, vec![-0.25, -0.25, 0.0, 0.0]);
    // The L1 term counts both.
    let l1 = losses::mask_l1(&alpha, &mask).into_scalar::<f64>();
    assert!((l1 - 1.625 / 4.0).abs() < 1e-6);
}

#[test]
fn the_mask_edge_distance_counts_pixels_to_the_other_side_of_the_silhouette() {
    // A 3x3 square in a 9x9 image: the square's border and the ring around it touch the other
    // side (1), the square's centre and the next ring out are two away, the image's corners
    // three.
    let (w, h) = (9, 9);
    let mut mask = vec![0.0f32; w * h];
    for y in 3..6 {
        for x in 3..6 {
            mask[y * w + x] = 1.0;
        }
    }
    let d = gtsr_model::views::mask_edge_distance(&mask, w, h);
    let at = |x: usize, y: usize| d[y * w + x];
    assert_eq!(at(3, 3), 1.0);
    assert_eq!(at(2, 2), 1.0);
    assert_eq!(at(4, 4), 2.0);
    assert_eq!(at(1, 4), 2.0);
    assert_eq!(at(8, 8), 3.0);
    assert_eq!(at(0, 0), 3.0);
    // A mask with no silhouette is everywhere at the cap.
    let full = gtsr_model::views::mask_edge_distance(&vec![1.0; w * h], w, h);
    assert!(
        full.iter()
            .all(|&v| v == gtsr_model::config::MASK_EDGE_CAP as f32)
    );
}

#[test]
fn the_mask_band_leaves_out_the_pixels_beside_the_silhouette() {
    let device = Device::ndarray().autodiff();
    let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [1, 4]), &device);
    // One row: inside, inside | outside, outside; the two pixels beside the edge are 1 away.
    let mask = t(vec![1.0, 1.0, 0.0, 0.0]);
    let edge = t(vec![2.0, 1.0, 1.0, 2.0]);
    let alpha = t(vec![0.5, 0.25, 0.75, 0.125]).require_grad();
    let band = losses::mask_l1_outside_band(&alpha, &mask, &edge, 1.0);
    // Only the first and last pixels count: (0.5 + 0.125) / 4.
    assert!((band.clone().into_scalar::<f64>() - 0.625 / 4.0).abs() < 1e-6);
    let g = host_vec(alpha.grad(&band.backward()).expect("a gradient"));
    assert_eq!(g, vec![-0.25, 0.0, 0.0, 0.25]);
    // Band 0 is the plain L1 term.
    let none = losses::mask_l1_outside_band(&alpha, &mask, &edge, 0.0).into_scalar::<f64>();
    let l1 = losses::mask_l1(&alpha, &mask).into_scalar::<f64>();
    assert!((none - l1).abs() < 1e-7);
}

#[test]
fn the_band_hinge_asks_only_for_the_right_side_of_one_half() {
    let device = Device::ndarray().autodiff();
    let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [1, 6]), &device);
    // Three pixels inside the mask, three outside; with band 2 the middle four (edge
    // distance 1 or 2) are in the band and only the two ends keep the L1 term.
    let mask = t(vec![1.0, 1.0, 0.75, 0.25, 0.0, 0.0]);
    let edge = t(vec![3.0, 2.0, 1.0, 1.0, 2.0, 3.0]);
    // In the band: 0.375 inside (0.125 short of 0.5), 0.875 inside (fine), 0.625 outside
    // (0.125 over), 0.25 outside (fine). Outside the band: L1 0.5 and 0.125.
    let alpha = t(vec![0.5, 0.375, 0.875, 0.625, 0.25, 0.125]).require_grad();
    let term = losses::mask_l1_band_hinge(&alpha, &mask, &edge, 2.0);
    let want = (0.5 + 0.125 + 0.0 + 0.125 + 0.0 + 0.125) / 6.0;
    assert!((term.clone().into_scalar::<f64>() - want).abs() < 1e-6);
    let g = host_vec(alpha.grad(&term.backward()).expect("a gradient"));
    let s = 1.0 / 6.0;
    assert_eq!(g, vec![-s as f32, -s as f32, 0.0, s as f32, 0.0, s as f32]);
    // A rendered edge wider than the mask's but crossing 0.5 at the same place costs nothing
    // in the band.
    let wide = t(vec![1.0, 0.55, 0.52, 0.48, 0.45, 0.0]);
    let zero = losses::mask_l1_band_hinge(&wide, &mask, &edge, 2.0).into_scalar::<f64>();
    assert!(zero.abs() < 1e-7, "{zero}");
}

#[test]
fn the_photometric_band_leaves_out_the_pixels_it_is_told_to() {
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(7);
    let (h, w) = (6, 9);
    let mut img = || {
        let v: Vec<f32> = (0..h * w * 3).map(|_| rng.random::<f32>()).collect();
        Tensor::<3>::from_data(TensorData::new(v, [h, w, 3]), &device)
    };
    let (render, target) = (img(), img());
    let lambda = 0.2;
    let ones = Tensor::<2>::ones([h, w], &device);
    let full = losses::photometric(render.clone(), target.clone(), lambda).into_scalar::<f64>();
    let all = losses::photometric_masked(render.clone(), target.clone(), lambda, &ones)
        .into_scalar::<f64>();
    assert!((full - all).abs() < 1e-6, "{full} against {all}");
    // Leave out pixel (2, 4): the mean loses exactly that pixel's L1 and 1 - SSIM share.
    let mut k = vec![1f32; h * w];
    let p = 2 * w + 4;
    k[p] = 0.0;
    let keep = Tensor::<2>::from_data(TensorData::new(k, [h, w]), &device);
    let part = losses::photometric_masked(render.clone(), target.clone(), lambda, &keep)
        .into_scalar::<f64>();
    let (rv, tv) = (host_vec(render.clone()), host_vec(target.clone()));
    let l1_px = (0..3)
        .map(|c| f64::from((rv[3 * p + c] - tv[3 * p + c]).abs()))
        .sum::<f64>()
        / 3.0;
    let ssim_px = f64::from(host_vec(losses::ssim_map(render, target))[p]);
    let want = full - (lambda * l1_px + (1.0 - lambda) * (1.0 - ssim_px)) / (h * w) as f64;
    assert!((part - want).abs() < 1e-6, "{part} against {want}");
}

/// On an autodiff device: three facing layers of opacity 0.5 at z-depths 3.8, 4.0, 4.2
/// ([`facing_stack`]), their depth render (the blend lies at 3.914) and the pixels it covers.
fn blended_stack() -> (Device, Model, Camera, GeometryMaps, Tensor<2, Bool>) {
    let device = Device::ndarray().autodiff();
    let (model, cam) = facing_stack(&[-0.2, 0.0, 0.2], &device);
    let rays = pixel_rays(&cam, &device);
    let g = model.render_depth(&cam, &rays).unwrap();
    let valid = g.coverage.clone().greater_equal_elem(0.5);
    (device, model, cam, g, valid)
}

/// The gradient of the surface set's `kind` parameter on the host.
fn surface_grad(model: &Model, kind: ParamKind, grads: &burn::tensor::Gradients) -> Vec<f32> {
    host_vec(model.surface.req(kind).grad(grads).expect("a gradient"))
}

#[test]
fn the_front_depth_term_makes_the_front_layer_opaque_and_moves_nothing() {
    let device = Device::ndarray().autodiff();
    // Three facing layers of opacity 0.5 at z-depths 3.8, 4.0, 4.2: the blend lies at 3.914, the
    // transmittance first falls to 0.9 at the front layer (3.8).
    let (model, cam) = facing_stack(&[-0.2, 0.0, 0.2], &device);
    let rays = pixel_rays(&cam, &device);
    let front = model
        .render_depth_crossing(&cam, &rays, losses::FRONT_TRANSMITTANCE)
        .unwrap();
    let weights = model.render_depth_weights(&cam, &rays).unwrap();
    let valid = front.coverage.clone().greater_equal_elem(0.5);
    let loss = losses::front_depth(&weights.depth, &front.depth, cam.fx, &valid);
    let want = (3.9143 - 3.8) * cam.fx / 3.8;
    let got = loss.clone().into_scalar::<f64>();
    assert!((got - want).abs() < 1e-2 * want, "{got} against {want}");
    let grads = loss.backward();
    // Descent raises the front layer's opacity most and fades the back layer (the middle one
    // rises a little: it takes weight from the back one).
    let g_logit = surface_grad(&model, ParamKind::Opacity, &grads);
    assert!(
        g_logit[0] < 0.0 && g_logit[0] < g_logit[1] && g_logit[2] > 0.0,
        "{g_logit:?}"
    );
    // No position, rotation or scale changes.
    for kind in [ParamKind::Means, ParamKind::Rotations, ParamKind::LogScales] {
        let g = model.surface.req(kind).grad(&grads);
        assert!(
            g.is_none_or(|g| host_vec(g).iter().all(|v| *v == 0.0)),
            "{kind:?} has a gradient"
        );
    }
    // A pixel without a usable front does not count.
    let none = losses::front_depth(
        &weights.depth,
        &front.depth.clone().mul_scalar(f32::NAN),
        cam.fx,
        &valid,
    );
    assert_eq!(none.into_scalar::<f64>(), 0.0);
}

#[test]
fn the_hull_depth_term_pulls_the_blend_onto_a_near_bound_and_ignores_a_far_one() {
    let (device, model, cam, g, valid) = blended_stack();
    let (w, h) = (cam.width as usize, cam.height as usize);
    // The bound at the front layer on the left half (0.99 footprints in front of the blend),
    // 10 footprints in front on the right half (a concavity: left out), none on the top row.
    let hull: Vec<f32> = (0..w * h)
        .map(|p| match (p % w, p / w) {
            (_, 0) => 0.0,
            (x, _) if x < w / 2 => 3.8,
            _ => 3.0,
        })
        .collect();
    let hull = Tensor::<2>::from_data(TensorData::new(hull, [h, w]), &device);
    let loss = losses::hull_depth(&g.depth, &hull, None, cam.fx, &valid);
    let blend = host_vec(g.depth.clone())[12 * w + 4];
    let want = f64::from(blend - 3.8) * cam.fx / 3.8;
    let got = loss.clone().into_scalar::<f64>();
    assert!(
        (0.5..3.0).contains(&want) && (got - want).abs() < 1e-3 * want,
        "{got} against {want} (blend {blend})"
    );
    let grads = loss.backward();
    // Descent moves the layers towards the camera (-z) and makes the front one more opaque.
    let g_means = surface_grad(&model, ParamKind::Means, &grads);
    assert!((0..3).all(|i| g_means[3 * i + 2] > 0.0), "{g_means:?}");
    let g_logit = surface_grad(&model, ParamKind::Opacity, &grads);
    assert!(g_logit[0] < 0.0 && g_logit[2] > 0.0, "{g_logit:?}");
    // Only the far bound: nothing counts.
    let far = losses::hull_depth(&g.depth, &hull.clone().clamp_max(3.0), None, cam.fx, &valid);
    assert_eq!(far.into_scalar::<f64>(), 0.0);
}

#[test]
fn the_interior_front_term_pulls_a_surface_floating_over_the_medium_down_to_it() {
    let (device, model, cam, g, valid) = blended_stack();
    let (w, h) = (cam.width as usize, cam.height as usize);
    // Without an interior set there is no front.
    assert!(model.render_interior_front(&cam, 0.5).unwrap().is_none());
    // The stack itself as the medium: its front is one of its layers, in front of the blend
    // or within the band of it, so nothing counts.
    let mut medium = model.clone();
    medium.interior = Some(model.surface.clone());
    let front = medium
        .render_interior_front(&cam, losses::INTERIOR_FRONT_TRANSMITTANCE)
        .unwrap()
        .unwrap();
    let at = host_vec(front.clone())[12 * w + 4];
    assert!((3.79..=4.01).contains(&at), "{at}");
    let none = losses::interior_front(&g.depth, &front, cam.fx, &valid);
    assert_eq!(none.into_scalar::<f64>(), 0.0);
    // A medium far behind on the left half (at 5), within the band on the right half (one
    // footprint behind the blend), none on the top row.
    let blend = host_vec(g.depth.clone())[12 * w + 4];
    let footprint = blend / cam.fx as f32;
    let far: Vec<f32> = (0..w * h)
        .map(|p| match (p % w, p / w) {
            (_, 0) => 0.0,
            (x, _) if x < w / 2 => 5.0,
            _ => blend + footprint,
        })
        .collect();
    let far = Tensor::<2>::from_data(TensorData::new(far, [h, w]), &device);
    let loss = losses::interior_front(&g.depth, &far, cam.fx, &valid);
    let want = f64::from(5.0 - blend) * cam.fx / 5.0;
    let got = loss.clone().into_scalar::<f64>();
    assert!(
        want > losses::INTERIOR_FRONT_BAND && (got - want).abs() < 1e-2 * want,
        "{got} against {want} (blend {blend})"
    );
    // Descent moves the layers away from the camera (+z), towards the medium.
    let grads = loss.backward();
    let g_means = surface_grad(&model, ParamKind::Means, &grads);
    assert!((0..3).all(|i| g_means[3 * i + 2] < 0.0), "{g_means:?}");
    // A NaN front does not count.
    let nan = losses::interior_front(&g.depth, &far.mul_scalar(f32::NAN), cam.fx, &valid);
    assert_eq!(nan.into_scalar::<f64>(), 0.0);
}

#[test]
fn the_hull_depth_term_pulls_a_surface_that_spills_past_an_occluding_edge_back() {
    let (device, model, cam, g, valid) = blended_stack();
    let (w, h) = (cam.width as usize, cam.height as usize);
    // The bound places every pixel far behind the blend (at 5), beyond the band; the left half
    // lies just behind an occluding edge whose nearer side the bound puts at 3.9, where the
    // blend is: there the blend has spilled past the edge.
    let hull = Tensor::<2>::from_data(TensorData::new(vec![5.0f32; w * h], [h, w]), &device);
    let occ: Vec<f32> = (0..w * h)
        .map(|p| if p % w < w / 2 { 3.9 } else { 0.0 })
        .collect();
    let occ = Tensor::<2>::from_data(TensorData::new(occ, [h, w]), &device);
    let without = losses::hull_depth(&g.depth, &hull, None, cam.fx, &valid);
    assert_eq!(without.into_scalar::<f64>(), 0.0);
    let loss = losses::hull_depth(&g.depth, &hull, Some(&occ), cam.fx, &valid);
    let blend = host_vec(g.depth.clone())[12 * w + 4];
    // Counted against the pixel's own bound, not the occluder's depth.
    let want = f64::from(5.0 - blend) * cam.fx / 5.0;
    let got = loss.clone().into_scalar::<f64>();
    assert!(
        want > 3.0 && (got - want).abs() < 1e-3 * want,
        "{got} against {want} (blend {blend})"
    );
    // Descent moves the layers away from the camera (+z) and makes the front one fainter.
    let grads = loss.backward();
    let g_means = surface_grad(&model, ParamKind::Means, &grads);
    assert!((0..3).all(|i| g_means[3 * i + 2] < 0.0), "{g_means:?}");
    let g_logit = surface_grad(&model, ParamKind::Opacity, &grads);
    assert!(g_logit[0] > 0.0, "{g_logit:?}");
    // An occluder the blend does not read (far from it) adds nothing.
    let elsewhere = losses::hull_depth(&g.depth, &hull, Some(&(occ * 0.5)), cam.fx, &valid);
    assert_eq!(elsewhere.into_scalar::<f64>(), 0.0);
}

#[test]
fn a_compensated_model_splats_each_opacity_times_the_blur_compensation() {
    let device = Device::ndarray();
    // Small splats, one seen nearly edge-on: thin on screen, where the factor is far below 1.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let splats = [
        Splat {
            mean: [0.1, 0.0, 0.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            scales: [0.01, 0.02, 1e-4],
            opacity: 0.8,
        },
        Splat {
            mean: [-0.1, 0.05, 0.2],
            quat: [h, 0.0, h, 0.0],
            scales: [0.05, 0.05, 1e-4],
            opacity: 0.9,
        },
    ];
    let mut model = surface_only_model(&splats, gtsr_render_kernels::PIXEL_BOX_BLUR_PX2, &device);
    let cam = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.7, 24, 24).unwrap();
    let rays = pixel_rays(&cam, &device);
    let plain = host_vec(model.render_depth(&cam, &rays).unwrap().coverage);
    model.compensate_blur = true;
    let got = host_vec(model.render_depth(&cam, &rays).unwrap().coverage);
    // The kernels asked for the compensation directly, on the same Gaussians.
    let set = &model.surface;
    let means = set.req(ParamKind::Means).clone();
    let inputs = SplatInputs {
        features: means.clone(),
        means,
        quats: set.req(ParamKind::Rotations).clone(),
        scales: set.scales(),
        opacities: model.opacities(set),
        xy_offsets: None,
    };
    let cfg = SplatConfig {
        blur_px2: model.blur_px2,
        compensate_blur: true,
        ..SplatConfig::new(cam.clone(), 3)
    };
    let want = host_vec(render(inputs, &cfg).unwrap().alpha);
    let worst = got
        .iter()
        .zip(&want)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-6, "{worst}");
    // Thin splats cover less once compensated.
    let sum = |v: &[f32]| v.iter().sum::<f32>();
    assert!(
        sum(&got) < 0.9 * sum(&plain),
        "{} vs {}",
        sum(&got),
        sum(&plain)
    );
}

/// A textured plane `z = 0` seen by `cam`: the grey image, and the z-depth and camera-space
/// normal (facing the camera) of every pixel.
fn textured_plane(cam: &Camera) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let tex = |x: f64, y: f64| {
        0.5 + 0.2 * (9.0 * x + 1.0).sin() * (7.0 * y).cos() + 0.1 * (17.0 * y - 5.0 * x).sin()
    };
    let r = cam.rotation;
    let c = cam.centre();
    let (mut grey, mut depth, mut normal) = (Vec::new(), Vec::new(), Vec::new());
    for j in 0..cam.height {
        for i in 0..cam.width {
            let ray = [
                (i as f64 + 0.5 - cam.cx) / cam.fx,
                (j as f64 + 0.5 - cam.cy) / cam.fy,
                1.0,
            ];
            // World direction R^T ray; its parameter at the plane is the camera z.
            let d: Vec<f64> = (0..3)
                .map(|k| (0..3).map(|l| r[l][k] * ray[l]).sum())
                .collect();
            let t = -c[2] / d[2];
            grey.push(tex(c[0] + t * d[0], c[1] + t * d[1]) as f32);
            depth.push(t as f32);
            // R (0, 0, -1): the plane's normal towards the cameras (at z < 0).
            normal.extend((0..3).map(|l| -r[l][2] as f32));
        }
    }
    (grey, depth, normal)
}

#[test]
fn the_multi_view_ncc_term_is_least_on_the_true_plane_and_pulls_towards_it() {
    let device = Device::ndarray().autodiff();
    let cam_r =
        Camera::look_at([0.2, -0.1, -3.0], [0.0; 3], [0.0, -1.0, 0.0], 0.7, 64, 48).unwrap();
    let cam_n =
        Camera::look_at([0.9, 0.25, -2.9], [0.0; 3], [0.0, -1.0, 0.0], 0.7, 64, 48).unwrap();
    let (w, h) = (64, 48);
    let (grey_r, depth_r, normal_r) = textured_plane(&cam_r);
    let (grey_n, _, _) = textured_plane(&cam_n);
    let image = |v: &[f32]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [h, w]), &device);
    let normal = Tensor::<3>::from_data(TensorData::new(normal_r.clone(), [h, w, 3]), &device);
    let pixels: Vec<(usize, f32)> = (0..w * h).map(|k| (k, 1.0)).collect();
    // The loss at the depth scaled by 1 + eps, and its derivative in eps.
    let at = |eps: f32| {
        let scaled: Vec<f32> = depth_r.iter().map(|d| d * (1.0 + eps)).collect();
        let depth = image(&scaled).require_grad();
        let term = losses::multi_view_ncc(
            &depth,
            &normal,
            &image(&grey_r),
            &cam_r,
            &image(&grey_n),
            &cam_n,
            &pixels,
        );
        let value = term.loss.clone().into_scalar::<f64>();
        let g = host_vec(depth.grad(&term.loss.backward()).expect("a gradient"));
        assert!(
            g.iter().all(|x| x.is_finite()),
            "eps {eps}: a gradient not finite"
        );
        let slope: f64 = g.iter().zip(&depth_r).map(|(g, d)| f64::from(g * d)).sum();
        (value, slope, term.patches)
    };
    let (l0, _, kept) = at(0.0);
    assert!(kept > 500, "{kept} patches kept");
    assert!(l0 < 0.01, "on the true plane: {l0}");
    for eps in [-0.05f32, 0.05] {
        let (l, slope, _) = at(eps);
        assert!(
            l > 5.0 * l0 + 0.01,
            "eps {eps}: {l} against {l0} on the plane"
        );
        // Descent moves the depth back towards the plane.
        assert!(slope * f64::from(eps) > 0.0, "eps {eps}: slope {slope}");
    }
}

/// The facing normal is the rotation's column of the smallest scale, flipped towards the
/// camera centre (against a direct evaluation), and its gradient in the quaternions matches
/// central differences in f64.
#[test]
fn facing_normals_are_the_smallest_axis_towards_the_camera_with_their_gradient() {
    use burn::tensor::DType::F64;
    use gtsr_model::geometry::{facing_normals, quat_to_matrix};
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(11);
    let n = 40;
    let mut draw = |k: usize, lo: f64, hi: f64| -> Vec<f64> {
        (0..k).map(|_| rng.random_range(lo..hi)).collect()
    };
    let (q, ls, means, w) = (
        draw(4 * n, -1.0, 1.0),
        draw(3 * n, -4.0, -1.0),
        draw(3 * n, -0.8, 0.8),
        draw(3 * n, -1.0, 1.0),
    );
    let centre = [0.3, -0.2, -4.0];
    let t = |v: &[f64], c: usize| {
        Tensor::<2>::from_data(TensorData::new(v.to_vec(), [n, c]), (&device, F64))
    };
    // The loss sum(w * normal) at quaternions `q`, and its gradient.
    let eval = |q: &[f64]| {
        let qt = t(q, 4).require_grad();
        let normal = facing_normals(&quat_to_matrix(&qt), &t(&ls, 3), &t(&means, 3), centre);
        let values: Vec<f64> = normal.clone().into_data().to_vec::<f64>().unwrap();
        let loss = (normal * t(&w, 3)).sum();
        let value = loss.clone().into_scalar::<f64>();
        let grad: Vec<f64> = qt
            .grad(&loss.backward())
            .expect("a gradient")
            .into_data()
            .to_vec::<f64>()
            .unwrap();
        (values, value, grad)
    };
    let (values, _, grad) = eval(&q);
    for i in 0..n {
        let r = quat_matrix(&q[4 * i..4 * i + 4]);
        let s = &ls[3 * i..3 * i + 3];
        let a = (0..3).min_by(|x, y| s[*x].total_cmp(&s[*y])).unwrap();
        let to_cam: Vec<f64> = (0..3).map(|k| centre[k] - means[3 * i + k]).collect();
        let side: f64 = (0..3).map(|k| r[k][a] * to_cam[k]).sum();
        let sign = if side >= 0.0 { 1.0 } else { -1.0 };
        for k in 0..3 {
            let want = sign * r[k][a];
            let got = values[3 * i + k];
            assert!(
                (got - want).abs() < 1e-9,
                "Gaussian {i}, {k}: {got} against {want}"
            );
        }
    }
    let h = 1e-6;
    for (j, g) in grad.iter().enumerate() {
        let mut qp = q.clone();
        qp[j] += h;
        let mut qm = q.clone();
        qm[j] -= h;
        let fd = (eval(&qp).1 - eval(&qm).1) / (2.0 * h);
        assert!(
            (g - fd).abs() < 1e-6 * (1.0 + fd.abs()),
            "q[{j}]: {g} against {fd}"
        );
    }
}
