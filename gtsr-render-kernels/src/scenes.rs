//! Seeded synthetic scenes for tests, benchmarks and the stability report.
//!
//! Everything is generated from a seed with `rand`'s `StdRng`, so a scene is the same on every
//! run of a given build.

use burn::tensor::{DType, Device, Tensor, TensorData};
use rand::{RngExt, SeedableRng, rngs::StdRng};

use crate::api::SplatInputs;
use crate::camera::Camera;
use crate::config::{AlphaCutoff, SplatConfig};
use crate::cpu::{HostBuffers, HostGaussians};

/// Gaussians and a camera on the host, in `f64`.
#[derive(Clone, Debug)]
pub struct HostScene {
    /// `[N, 3]`
    pub means: Vec<f64>,
    /// `[N, 4]` (w, x, y, z)
    pub quats: Vec<f64>,
    /// `[N, 3]`
    pub scales: Vec<f64>,
    /// `[N]`
    pub opacities: Vec<f64>,
    /// `[N, C]`
    pub features: Vec<f64>,
    /// `[N, 2]`
    pub xy_offsets: Vec<f64>,
    /// Feature channels `C`.
    pub channels: usize,
    /// The camera.
    pub camera: Camera,
    /// Background, `C` values.
    pub background: Vec<f64>,
}

impl HostScene {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    /// Whether the scene is empty.
    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    /// Host view for [`crate::cpu`] and [`crate::reference`].
    pub fn host(&self) -> HostGaussians<'_, f64> {
        splat_fields!(HostGaussians, &self, |v| v.as_slice())
    }

    /// The inputs rounded to f32, for the host kernels in f32 ([`HostBuffers::host`]).
    pub fn to_f32(&self) -> HostBuffers<f32> {
        let f = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        splat_fields!(HostBuffers, &self, |v| f(v))
    }

    /// The render configuration with the given cut-off.
    pub fn config(&self, cutoff: AlphaCutoff) -> SplatConfig {
        SplatConfig {
            camera: self.camera.clone(),
            background: self.background.clone(),
            cutoff,
            blur_px2: crate::BLUR_PX2,
            compensate_blur: false,
        }
    }

    /// Uploads the Gaussians as tensors of `dtype` on `device` (screen offsets included, so
    /// they can be differentiated too).
    pub fn inputs(&self, device: &Device, dtype: DType) -> SplatInputs {
        let n = self.len();
        let t2 = |v: &[f64], cols: usize| {
            Tensor::<2>::from_data(TensorData::new(v.to_vec(), [n, cols]), (device, dtype))
        };
        SplatInputs {
            means: t2(&self.means, 3),
            quats: t2(&self.quats, 4),
            scales: t2(&self.scales, 3),
            opacities: Tensor::<1>::from_data(
                TensorData::new(self.opacities.clone(), [n]),
                (device, dtype),
            ),
            features: t2(&self.features, self.channels),
            xy_offsets: Some(t2(&self.xy_offsets, 2)),
        }
    }

    /// Appends `other`'s Gaussians (same channel count).
    pub fn extend(&mut self, other: &HostScene) {
        assert_eq!(self.channels, other.channels);
        self.means.extend_from_slice(&other.means);
        self.quats.extend_from_slice(&other.quats);
        self.scales.extend_from_slice(&other.scales);
        self.opacities.extend_from_slice(&other.opacities);
        self.features.extend_from_slice(&other.features);
        self.xy_offsets.extend_from_slice(&other.xy_offsets);
    }
}

/// Parameters of [`random_scene`].
#[derive(Clone, Debug)]
pub struct RandomSceneSpec {
    /// Number of Gaussians.
    pub count: usize,
    /// Feature channels.
    pub channels: usize,
    /// Image width and height.
    pub size: (u32, u32),
    /// Means uniform in a ball of this radius around the origin.
    pub radius: f64,
    /// Scales log-uniform in this range.
    pub scale_range: (f64, f64),
    /// Opacities uniform in this range.
    pub opacity_range: (f64, f64),
    /// Camera distance from the origin (on a random direction).
    pub distance: f64,
    /// Horizontal field of view (radians).
    pub fov_x: f64,
}

impl RandomSceneSpec {
    /// The benchmark scene of the crate README: means uniform in a unit ball, camera at distance
    /// 4, horizontal fov 0.691 rad, scales log-uniform in [0.005, 0.03], opacities uniform in
    /// [0.1, 0.9], C = 3.
    pub fn bench(count: usize, width: u32, height: u32) -> Self {
        Self {
            count,
            channels: 3,
            size: (width, height),
            radius: 1.0,
            scale_range: (0.005, 0.03),
            opacity_range: (0.1, 0.9),
            distance: 4.0,
            fov_x: 0.691,
        }
    }
}

fn random_unit(rng: &mut StdRng) -> [f64; 3] {
    loop {
        let v: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        if n2 > 1e-4 && n2 <= 1.0 {
            let n = n2.sqrt();
            return v.map(|x| x / n);
        }
    }
}

fn random_quat(rng: &mut StdRng) -> [f64; 4] {
    // Not normalised on purpose: the kernels normalise.
    let s = rng.random_range(0.5..2.0);
    loop {
        let q: [f64; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let n2: f64 = q.iter().map(|v| v * v).sum();
        if n2 > 1e-2 && n2 <= 1.0 {
            let n = n2.sqrt();
            return q.map(|v| s * v / n);
        }
    }
}

/// A random scene; the camera looks at the origin from `distance` along a random direction.
pub fn random_scene(seed: u64, spec: &RandomSceneSpec) -> HostScene {
    let mut rng = StdRng::seed_from_u64(seed);
    let dir = random_unit(&mut rng);
    let eye = dir.map(|v| v * spec.distance);
    let up = if dir[1].abs() > 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let camera = Camera::look_at(eye, [0.0; 3], up, spec.fov_x, spec.size.0, spec.size.1)
        .expect("random scene camera is valid");
    let mut s = HostScene {
        means: Vec::with_capacity(3 * spec.count),
        quats: Vec::with_capacity(4 * spec.count),
        scales: Vec::with_capacity(3 * spec.count),
        opacities: Vec::with_capacity(spec.count),
        features: Vec::with_capacity(spec.channels * spec.count),
        xy_offsets: vec![0.0; 2 * spec.count],
        channels: spec.channels,
        camera,
        background: (0..spec.channels)
            .map(|_| rng.random_range(0.0..1.0))
            .collect(),
    };
    let (lo, hi) = (spec.scale_range.0.ln(), spec.scale_range.1.ln());
    for _ in 0..spec.count {
        let d = random_unit(&mut rng);
        let r = spec.radius * rng.random_range(0.0f64..1.0).cbrt();
        s.means.extend(d.map(|v| v * r));
        s.quats.extend(random_quat(&mut rng));
        for _ in 0..3 {
            s.scales.push(rng.random_range(lo..hi).exp());
        }
        s.opacities
            .push(rng.random_range(spec.opacity_range.0..spec.opacity_range.1));
        for _ in 0..spec.channels {
            s.features.push(rng.random_range(-0.5..1.5));
        }
    }
    s
}

/// A camera at the origin looking down `+z` (identity rotation) with the principal point on a
/// pixel centre, for analytic tests.
pub fn axis_camera(width: u32, height: u32, focal: f64) -> Camera {
    Camera::new(
        focal,
        focal,
        f64::from(width / 2) + 0.5,
        f64::from(height / 2) + 0.5,
        width,
        height,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
        0.01,
        1e4,
    )
    .expect("axis camera is valid")
}

/// One named stiff or extreme case.
#[derive(Clone, Debug)]
pub struct StiffCase {
    /// Short name for reports.
    pub name: &'static str,
    /// The scene.
    pub scene: HostScene,
}

fn single(camera: &Camera, mean: [f64; 3], quat: [f64; 4], scale: [f64; 3], o: f64) -> HostScene {
    HostScene {
        means: mean.to_vec(),
        quats: quat.to_vec(),
        scales: scale.to_vec(),
        opacities: vec![o],
        features: vec![0.9, 0.4, 0.1],
        xy_offsets: vec![0.0, 0.0],
        channels: 3,
        camera: camera.clone(),
        background: vec![0.1, 0.2, 0.3],
    }
}

/// The stiff and extreme cases every backend must survive with finite outputs and gradients:
/// edge-on flat Gaussians, scales from 1e-6 to 1e3, Gaussians crossing the near plane and
/// behind the camera, opacity 1 - 1e-7, 10,000 splats on one pixel, a near-zero quaternion,
/// and NaN / Inf parameters (which are culled, status 2).
pub fn stiff_cases() -> Vec<StiffCase> {
    let cam = axis_camera(64, 48, 60.0);
    let base = random_scene(
        7,
        &RandomSceneSpec {
            count: 20,
            channels: 3,
            size: (64, 48),
            radius: 0.6,
            scale_range: (0.02, 0.2),
            opacity_range: (0.2, 0.8),
            distance: 4.0,
            fov_x: 0.9,
        },
    );
    let with_base = |extra: HostScene| {
        let mut s = base.clone();
        let mut e = extra;
        e.camera = s.camera.clone();
        s.extend(&e);
        s
    };
    // One Gaussian before the axis camera.
    let case = |name, mean, quat, scale, o| StiffCase {
        name,
        scene: single(&cam, mean, quat, scale, o),
    };
    // A quaternion turning the local z axis (the flat one) to camera x: the splat is edge-on.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let edge_on_quat = [h, 0.0, h, 0.0];
    let id = [1.0, 0.0, 0.0, 0.0];
    // One case a row (name, mean, quaternion, scales, opacity), kept as a table.
    #[rustfmt::skip]
    let mut cases = vec![
        case("edge-on flat (scale 1e-6)", [0.0, 0.0, 3.0], edge_on_quat, [0.5, 0.5, 1e-6], 0.8),
        case("tiny scales (1e-6)", [0.05, -0.02, 3.0], [1.0, 0.2, 0.1, 0.0], [1e-6; 3], 0.8),
        case("huge scales (1e3)", [0.1, 0.0, 3.0], [0.9, 0.1, 0.3, 0.2], [1e3; 3], 0.5),
        case("mixed 1e-6 .. 1e3", [0.0, 0.1, 2.0], [0.7, 0.1, 0.7, 0.0], [1e3, 1e-6, 1.0], 0.6),
        case("crossing the near plane", [0.0, 0.0, 0.0105], id, [0.05; 3], 0.7),
        case("behind the camera", [0.0, 0.0, -1.0], id, [0.5; 3], 0.7),
        case("far outside the frustum", [40.0, -30.0, 2.0], id, [5.0; 3], 0.7),
        case("opacity 1 - 1e-7", [0.0, 0.0, 3.0], id, [0.2; 3], 1.0 - 1e-7),
        StiffCase {
            name: "near-zero quaternion (1e-5)",
            scene: with_base(single(&cam, [0.0; 3], [1e-5, 0.0, 0.0, 0.0], [0.1; 3], 0.5)),
        },
        case("small quaternion (1e-3)", [0.0, 0.0, 3.0], [1e-3, 2e-4, 0.0, 1e-4], [0.1; 3], 0.5),
    ];
    // 10,000 splats on one pixel.
    let mut pile = single(&cam, [0.0, 0.0, 3.0], id, [0.002; 3], 0.3);
    let one = pile.clone();
    for k in 1..10_000 {
        let mut g = one.clone();
        g.means[2] = 3.0 + 1e-4 * k as f64;
        g.opacities[0] = 0.05 + 0.9 * ((k * 7919) % 1000) as f64 / 1000.0;
        pile.extend(&g);
    }
    cases.push(StiffCase {
        name: "10,000 splats on one pixel",
        scene: pile,
    });
    // Non-finite parameters next to ordinary Gaussians.
    let bad = [
        ("NaN mean", 0usize, f64::NAN),
        ("Inf scale", 1, f64::INFINITY),
        ("NaN opacity", 2, f64::NAN),
        ("-Inf quaternion", 3, f64::NEG_INFINITY),
        ("NaN feature", 4, f64::NAN),
    ];
    let mut s = base.clone();
    for &(_, which, v) in &bad {
        let mut g = single(&cam, [0.0; 3], id, [0.1; 3], 0.5);
        g.camera = s.camera.clone();
        match which {
            0 => g.means[1] = v,
            1 => g.scales[2] = v,
            2 => g.opacities[0] = v,
            3 => g.quats[0] = v,
            _ => g.features[1] = v,
        }
        s.extend(&g);
    }
    cases.push(StiffCase {
        name: "NaN / Inf parameters",
        scene: s,
    });
    cases
}

/// Outputs and input gradients of one scene for a weighted-sum loss, computed on the NdArray
/// autodiff backend.
#[derive(Clone, Debug)]
pub struct SceneGradients {
    /// `[H, W, C + 1]` row-major: image channels, then alpha.
    pub output: Vec<f64>,
    /// Gradients of means, quats, scales, opacities, features and xy offsets, in that order
    /// (see [`INPUT_NAMES`]).
    pub grads: [Vec<f64>; 6],
}

/// Names of the six differentiable inputs, in the order of [`SceneGradients::grads`].
pub const INPUT_NAMES: [&str; 6] = [
    "means",
    "quats",
    "scales",
    "opacities",
    "features",
    "xy_offsets",
];

/// Renders `scene` in `dtype` on the NdArray autodiff backend and back-propagates
/// `loss = sum(weights * [image, alpha])` (`weights` is `[H, W, C + 1]` row-major).
pub fn weighted_loss_gradients(
    scene: &HostScene,
    dtype: DType,
    cutoff: AlphaCutoff,
    weights: &[f64],
) -> Result<SceneGradients, crate::RenderError> {
    weighted_loss_gradients_on(&Device::ndarray(), scene, dtype, cutoff, weights)
}

/// [`weighted_loss_gradients`] on any device with splatting kernels (its autodiff version is
/// used).
pub fn weighted_loss_gradients_on(
    device: &Device,
    scene: &HostScene,
    dtype: DType,
    cutoff: AlphaCutoff,
    weights: &[f64],
) -> Result<SceneGradients, crate::RenderError> {
    weighted_loss_gradients_with(device, scene, dtype, &scene.config(cutoff), weights)
}

/// [`weighted_loss_gradients_on`] rendered with `config` instead of the scene's own settings
/// (another blur, its compensation).
pub fn weighted_loss_gradients_with(
    device: &Device,
    scene: &HostScene,
    dtype: DType,
    config: &SplatConfig,
    weights: &[f64],
) -> Result<SceneGradients, crate::RenderError> {
    weighted_loss_gradients_through(device, scene, dtype, config, weights, |i| i)
}

/// [`weighted_loss_gradients_with`] where `through` turns the scene's leaf tensors into the
/// rendered inputs (a Burn expression, differentiated with the render): the gradients are
/// those of the leaves.
pub fn weighted_loss_gradients_through(
    device: &Device,
    scene: &HostScene,
    dtype: DType,
    config: &SplatConfig,
    weights: &[f64],
    through: impl FnOnce(SplatInputs) -> SplatInputs,
) -> Result<SceneGradients, crate::RenderError> {
    let device = device.clone().autodiff();
    let inp = scene.inputs(&device, dtype);
    let leaves = SplatInputs {
        means: inp.means.require_grad(),
        quats: inp.quats.require_grad(),
        scales: inp.scales.require_grad(),
        opacities: inp.opacities.require_grad(),
        features: inp.features.require_grad(),
        xy_offsets: inp.xy_offsets.map(|t| t.require_grad()),
    };
    let out = crate::render(through(leaves.clone()), config)?;
    let (h, w) = (scene.camera.height as usize, scene.camera.width as usize);
    let c = scene.channels;
    let wt = Tensor::<3>::from_data(
        TensorData::new(weights.to_vec(), [h, w, c + 1]),
        (&device, dtype),
    );
    let joined = Tensor::cat(vec![out.image, out.alpha.reshape([h, w, 1])], 2);
    let grads = (joined.clone() * wt).sum().backward();
    let host = |d: TensorData| d.iter::<f64>().collect::<Vec<f64>>();
    let g2 = |t: &Tensor<2>| {
        t.grad(&grads)
            .map(|g| host(g.into_data()))
            .unwrap_or_else(|| vec![0.0; t.dims().iter().product()])
    };
    let g_op = leaves
        .opacities
        .grad(&grads)
        .map(|g| host(g.into_data()))
        .unwrap_or_else(|| vec![0.0; scene.len()]);
    let xy = leaves
        .xy_offsets
        .as_ref()
        .expect("scene inputs carry offsets");
    Ok(SceneGradients {
        output: host(joined.inner().into_data()),
        grads: [
            g2(&leaves.means),
            g2(&leaves.quats),
            g2(&leaves.scales),
            g_op,
            g2(&leaves.features),
            g2(xy),
        ],
    })
}

/// Seeded weights in `[-1, 1)` for [`weighted_loss_gradients`].
pub fn random_weights(seed: u64, len: usize) -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..len).map(|_| rng.random_range(-1.0..1.0)).collect()
}
