//! Scene generation: cameras on Fibonacci spheres, rendering, and the Blender/NeRF layout on
//! disk (`train/r_K.png`, `test/r_K.png`, `transforms_{train,test}.json`, `mesh.ply`,
//! `meta.json`). Every file is written atomically (temporary file + rename).

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::error::{DataError, Result};
use crate::image_io::{linear_to_srgb, write_atomic, write_png_rgba8};
use crate::ply::write_ply;
use crate::synthetic::shapes::ShapeKind;
use crate::transport::material::{Material, MaterialPreset};
use crate::transport::tracer::{Lighting, Rendered, Tracer};

/// Horizontal field of view of the generated views (as the development data).
pub const DEFAULT_FOV_X: f32 = 0.691_111_2;
/// Camera distance from the origin (as the development data).
pub const DEFAULT_DISTANCE: f32 = 4.0;
/// Default point-light intensity (W/sr); exposes the presets to mid-grey-ish values.
pub const DEFAULT_INTENSITY: f32 = 20.0;

/// What to generate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneConfig {
    /// Shape.
    pub shape: ShapeKind,
    /// Preset the material came from, if any (recorded in `meta.json`).
    pub preset: Option<MaterialPreset>,
    /// Material.
    pub material: Material,
    /// Image width and height in pixels.
    pub resolution: u32,
    /// Number of training views.
    pub n_train: usize,
    /// Number of test views.
    pub n_test: usize,
    /// Samples per pixel.
    pub spp: u32,
    /// Seed of every random stream.
    pub seed: u64,
    /// Point-light radiant intensity (W/sr).
    pub light_intensity: f32,
    /// Camera distance from the origin.
    pub distance: f32,
    /// Horizontal field of view (radians).
    pub fov_x: f32,
}

impl SceneConfig {
    /// A configuration with the development-data camera layout.
    pub fn new(shape: ShapeKind, preset: MaterialPreset) -> SceneConfig {
        SceneConfig {
            shape,
            preset: Some(preset),
            material: preset.material(),
            resolution: 128,
            n_train: 100,
            n_test: 20,
            spp: 64,
            seed: 0,
            light_intensity: DEFAULT_INTENSITY,
            distance: DEFAULT_DISTANCE,
            fov_x: DEFAULT_FOV_X,
        }
    }

    fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(DataError::InvalidArgument(m));
        self.material.validate().or_else(bad)?;
        if self.resolution == 0 || self.resolution > 8192 {
            return bad(format!("resolution {} not in 1..=8192", self.resolution));
        }
        if self.n_train == 0 {
            return bad("at least one training view is needed".into());
        }
        if self.spp == 0 {
            return bad("spp must be > 0".into());
        }
        if !(self.distance > 1.0 && self.distance.is_finite()) {
            return bad(format!(
                "camera distance {} must exceed the object radius 1",
                self.distance
            ));
        }
        if !(self.fov_x > 0.0 && self.fov_x < 3.0) {
            return bad(format!("fov_x {} not in (0, 3) radians", self.fov_x));
        }
        if !(self.light_intensity >= 0.0 && self.light_intensity.is_finite()) {
            return bad(format!(
                "light intensity {} must be >= 0",
                self.light_intensity
            ));
        }
        Ok(())
    }
}

/// Camera centres on a Fibonacci sphere of radius `distance` (pole along +z), azimuths
/// rotated by `offset` radians.
pub fn fibonacci_sphere(n: usize, distance: f32, offset: f32) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = i as f32 * golden + offset;
            Vec3::new(r * phi.cos(), r * phi.sin(), z) * distance
        })
        .collect()
}

/// The cameras of a configuration: `(train, test)`. Train views lie on a Fibonacci sphere,
/// test views on another one with a different azimuth offset; all look at the origin with
/// +z up.
pub fn scene_cameras(cfg: &SceneConfig) -> (Vec<Camera>, Vec<Camera>) {
    let mk = |p: Vec3| {
        Camera::look_at(
            p,
            Vec3::ZERO,
            Vec3::Z,
            cfg.fov_x,
            cfg.resolution,
            cfg.resolution,
        )
    };
    let train = fibonacci_sphere(cfg.n_train, cfg.distance, 0.0)
        .into_iter()
        .map(mk)
        .collect();
    let test = fibonacci_sphere(cfg.n_test, cfg.distance, 1.234_567)
        .into_iter()
        .map(mk)
        .collect();
    (train, test)
}

/// Encodes a rendering as 8-bit sRGB RGBA with straight alpha (colour = premultiplied
/// radiance / coverage), as Blender writes a transparent film.
pub fn to_rgba8(r: &Rendered) -> Vec<u8> {
    let mut out = Vec::with_capacity(r.alpha.len() * 4);
    for (k, &a) in r.alpha.iter().enumerate() {
        let inv = if a > 0.0 { 1.0 / a } else { 0.0 };
        for c in 0..3 {
            let v = linear_to_srgb(r.rgb[3 * k + c] * inv);
            out.push((v * 255.0 + 0.5) as u8);
        }
        out.push((a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
    }
    out
}

#[derive(Serialize)]
struct FrameJson {
    file_path: String,
    transform_matrix: [[f32; 4]; 4],
}

#[derive(Serialize)]
struct TransformsJson {
    camera_angle_x: f32,
    frames: Vec<FrameJson>,
}

/// Progress report passed to the callback of [`generate_scene`].
#[derive(Clone, Debug)]
pub struct Progress {
    /// `"train"` or `"test"`.
    pub split: &'static str,
    /// Views of this split done.
    pub done: usize,
    /// Views in this split.
    pub total: usize,
    /// The file just written.
    pub path: PathBuf,
}

/// What [`generate_scene`] wrote.
#[derive(Clone, Debug)]
pub struct GeneratedScene {
    /// Output folder.
    pub root: PathBuf,
    /// Every file written.
    pub files: Vec<PathBuf>,
    /// Triangles in the mesh.
    pub triangles: usize,
    /// Seconds spent building the mesh and acceleration structures.
    pub setup_seconds: f64,
    /// Seconds spent rendering and writing images.
    pub render_seconds: f64,
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let s = serde_json::to_string_pretty(value).map_err(|e| DataError::MalformedJson {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    write_atomic(path, s.as_bytes())
}

/// Generates a synthetic scene into `out_dir` (created if needed): renders every view,
/// writes the Blender/NeRF layout, `mesh.ply`, `meta.json` and, for a shape with a part no
/// silhouette sees, that part as `hidden.ply` ([`ShapeKind::hidden_part`]). Deterministic
/// for a configuration (including the seed), whatever the number of threads. `progress` is
/// called after each image.
pub fn generate_scene(
    out_dir: &Path,
    cfg: &SceneConfig,
    mut progress: impl FnMut(&Progress),
) -> Result<GeneratedScene> {
    cfg.validate()?;
    let t0 = Instant::now();
    std::fs::create_dir_all(out_dir).map_err(|e| DataError::io(out_dir, e))?;
    let mesh = cfg.shape.mesh();
    let tracer = Tracer::new(&mesh, cfg.material);
    let mut files = Vec::new();
    let mesh_path = out_dir.join("mesh.ply");
    write_ply(&mesh_path, &mesh)?;
    files.push(mesh_path);
    if let Some(hidden) = cfg.shape.hidden_part_of(&mesh) {
        let path = out_dir.join("hidden.ply");
        write_ply(&path, &hidden)?;
        files.push(path);
    }
    let setup_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let (train, test) = scene_cameras(cfg);
    let lighting = Lighting {
        point_intensity: cfg.light_intensity,
        environment: 0.0,
    };
    for (split, cams, key_base) in [("train", &train, 0u64), ("test", &test, 1u64 << 32)] {
        let mut frames = Vec::with_capacity(cams.len());
        for (k, cam) in cams.iter().enumerate() {
            let r = tracer.render(cam, lighting, cfg.spp, cfg.seed, key_base + k as u64);
            let rel = format!("./{split}/r_{k}");
            let path = out_dir.join(split).join(format!("r_{k}.png"));
            write_png_rgba8(&path, r.width, r.height, &to_rgba8(&r))?;
            let m = cam.opengl_camera_to_world().transpose().to_cols_array_2d();
            frames.push(FrameJson {
                file_path: rel,
                transform_matrix: m,
            });
            progress(&Progress {
                split,
                done: k + 1,
                total: cams.len(),
                path: path.clone(),
            });
            files.push(path);
        }
        let json = out_dir.join(format!("transforms_{split}.json"));
        write_json(
            &json,
            &TransformsJson {
                camera_angle_x: cfg.fov_x,
                frames,
            },
        )?;
        files.push(json);
    }
    let render_seconds = t1.elapsed().as_secs_f64();
    let meta = serde_json::json!({
        "generator": concat!("gtsr-data ", env!("CARGO_PKG_VERSION")),
        "shape": cfg.shape.name(),
        "preset": cfg.preset.map(|p| p.name()),
        "material": cfg.material,
        "light": {
            "type": "point",
            "position": "camera centre",
            "intensity_w_per_sr": cfg.light_intensity,
        },
        "world": "black",
        "seed": cfg.seed,
        "spp": cfg.spp,
        "resolution": [cfg.resolution, cfg.resolution],
        "n_train": cfg.n_train,
        "n_test": cfg.n_test,
        "camera_distance": cfg.distance,
        "camera_angle_x": cfg.fov_x,
        "image_encoding": "8-bit sRGB RGBA PNG, straight alpha = camera-ray coverage",
        "mesh_triangles": mesh.triangles.len(),
        "units": "object normalised to bounding radius 1 around the origin; coefficients per unit length",
    });
    let meta_path = out_dir.join("meta.json");
    write_json(&meta_path, &meta)?;
    files.push(meta_path);
    Ok(GeneratedScene {
        root: out_dir.to_path_buf(),
        files,
        triangles: mesh.triangles.len(),
        setup_seconds,
        render_seconds,
    })
}
