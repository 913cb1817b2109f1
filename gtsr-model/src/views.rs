//! Training views on the device: the camera in the kernels' form, the ground-truth image and
//! mask as tensors, the pixel rays, and the per-view weights the losses need (PGSR's edge
//! weight, the edge-aware smoothness weights). Also what `auto` reads from a scene.

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_data::light::LightSettings;
use gtsr_data::{Scene, View};
use gtsr_render_kernels::Camera;

use crate::config::{MASK_EDGE_CAP, SceneEvidence};
use crate::error::ModelError;
use crate::geometry::pixel_rays;

/// Near and far clip distances used for every view (scene units; scenes are normalised to a
/// radius of about 1).
pub const NEAR: f64 = 0.05;
/// Far clip distance.
pub const FAR: f64 = 1000.0;

/// Converts a data camera (glam, OpenCV) to the kernels' camera ([`data_camera`] converts back).
pub fn kernel_camera(c: &gtsr_data::Camera, name: &str) -> Result<Camera, ModelError> {
    let m = c.world_to_camera.matrix3;
    let cols = [m.x_axis, m.y_axis, m.z_axis];
    let rotation: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| f64::from(cols[j][i])));
    let t = c.world_to_camera.translation;
    Camera::new(
        f64::from(c.fx),
        f64::from(c.fy),
        f64::from(c.cx),
        f64::from(c.cy),
        c.width,
        c.height,
        rotation,
        [f64::from(t.x), f64::from(t.y), f64::from(t.z)],
        NEAR,
        FAR,
    )
    .map_err(|e| ModelError::Camera {
        view: name.to_string(),
        reason: e.to_string(),
    })
}

/// The data camera of a kernel camera: the inverse of [`kernel_camera`], to the bit (every
/// value went from `f32` to `f64` and comes back).
pub fn data_camera(k: &Camera) -> gtsr_data::Camera {
    let r = &k.rotation;
    let column = |j: usize| glam::Vec3::new(r[0][j] as f32, r[1][j] as f32, r[2][j] as f32);
    let t = glam::Vec3::new(
        k.translation[0] as f32,
        k.translation[1] as f32,
        k.translation[2] as f32,
    );
    gtsr_data::Camera {
        world_to_camera: glam::Affine3A::from_mat3_translation(
            glam::Mat3::from_cols(column(0), column(1), column(2)),
            t,
        ),
        fx: k.fx as f32,
        fy: k.fy as f32,
        cx: k.cx as f32,
        cy: k.cy as f32,
        width: k.width,
        height: k.height,
    }
}

/// A training or test view on the device.
#[derive(Clone, Debug)]
pub struct ViewTensors {
    /// Index in its split.
    pub index: usize,
    /// Name (file path in the dataset).
    pub name: String,
    /// Camera.
    pub camera: Camera,
    /// `[H, W, 3]` ground truth in `[0, 1]`.
    pub rgb: Tensor<3>,
    /// `[H, W]` mask in `[0, 1]`, when the data has one.
    pub mask: Option<Tensor<2>>,
    /// `[H, W]` with the mask: per pixel the distance in pixels (the larger of the two axes)
    /// to the nearest pixel on the other side of the mask's 0.5 level, capped at
    /// [`MASK_EDGE_CAP`] ([`mask_edge_distance`]).
    pub mask_edge_px: Option<Tensor<2>>,
    /// `[H, W]` the masks' bound's own depth from this view (z, `0` where its ray misses
    /// it), for [`crate::losses::hull_depth`]; `None` until the front end sets it.
    pub hull_depth: Option<Tensor<2>>,
    /// `[H, W]` with [`ViewTensors::hull_depth`]: the bound's depth at the neighbour in front
    /// of an occluding edge of the bound, on the pixels just behind one (`0` elsewhere), for
    /// [`crate::losses::hull_depth`]; `None` unless the front end sets it.
    pub hull_occluders: Option<Tensor<2>>,
    /// `[H, W, 3]` camera-space pixel rays (z = 1).
    pub rays: Tensor<3>,
    /// `[H, W]` PGSR edge weight `(1 - g)^2`, `g` the min-max normalised image gradient.
    pub edge_weight: Tensor<2>,
    /// `[H, W-1]` smoothness weight `exp(-|dI/dx|)` times the mask of both pixels.
    pub smooth_wx: Tensor<2>,
    /// `[H-1, W]` smoothness weight along y.
    pub smooth_wy: Tensor<2>,
}

impl ViewTensors {
    /// Uploads `view`, checking sizes and values.
    pub fn new(view: &View, index: usize, device: &Device) -> Result<ViewTensors, ModelError> {
        let camera = kernel_camera(&view.camera, &view.name)?;
        let (w, h) = (view.width() as usize, view.height() as usize);
        if w < 3 || h < 3 {
            return Err(ModelError::Data(format!(
                "{}: image {w}x{h} is too small (3x3 at least)",
                view.name
            )));
        }
        if view.rgb.len() != w * h * 3 {
            return Err(ModelError::Data(format!(
                "{}: {} colour values for a {w}x{h} image",
                view.name,
                view.rgb.len()
            )));
        }
        if let Some(bad) = view.rgb.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Data(format!(
                "{}: non-finite colour at value {bad}",
                view.name
            )));
        }
        let mask = match &view.mask {
            Some(m) if m.len() != w * h => {
                return Err(ModelError::Data(format!(
                    "{}: mask has {} values for {w}x{h}",
                    view.name,
                    m.len()
                )));
            }
            Some(m) => Some(m.clone()),
            None => None,
        };
        let edge_px = mask.as_ref().map(|m| mask_edge_distance(m, w, h));
        let rgb = view.rgb.clone();
        let lum = |i: usize| (rgb[3 * i] + rgb[3 * i + 1] + rgb[3 * i + 2]) / 3.0;
        let mk = |i: usize| {
            mask.as_ref()
                .map_or(1.0, |m| if m[i] >= 0.5 { 1.0 } else { 0.0 })
        };
        // PGSR edge weight.
        let mut g = vec![0.0f32; w * h];
        for j in 1..h - 1 {
            for i in 1..w - 1 {
                let p = j * w + i;
                let gx = (0..3)
                    .map(|c| (rgb[3 * (p + 1) + c] - rgb[3 * (p - 1) + c]).abs())
                    .sum::<f32>()
                    / 3.0;
                let gy = (0..3)
                    .map(|c| (rgb[3 * (p + w) + c] - rgb[3 * (p - w) + c]).abs())
                    .sum::<f32>()
                    / 3.0;
                g[p] = gx.max(gy);
            }
        }
        let (gmin, gmax) = g
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
        let span = (gmax - gmin).max(1e-8);
        let edge: Vec<f32> = g
            .iter()
            .map(|v| (1.0 - (v - gmin) / span).clamp(0.0, 1.0).powi(2))
            .collect();
        let mut wx = Vec::with_capacity(h * (w - 1));
        for j in 0..h {
            for i in 0..w - 1 {
                let (a, b) = (j * w + i, j * w + i + 1);
                wx.push((-(lum(b) - lum(a)).abs()).exp() * mk(a) * mk(b));
            }
        }
        let mut wy = Vec::with_capacity((h - 1) * w);
        for j in 0..h - 1 {
            for i in 0..w {
                let (a, b) = (j * w + i, (j + 1) * w + i);
                wy.push((-(lum(b) - lum(a)).abs()).exp() * mk(a) * mk(b));
            }
        }
        Ok(ViewTensors {
            index,
            name: view.name.clone(),
            camera: camera.clone(),
            rgb: Tensor::from_data(TensorData::new(rgb.clone(), [h, w, 3]), device),
            mask: mask.map(|m| Tensor::from_data(TensorData::new(m, [h, w]), device)),
            mask_edge_px: edge_px.map(|d| Tensor::from_data(TensorData::new(d, [h, w]), device)),
            hull_depth: None,
            hull_occluders: None,
            rays: pixel_rays(&camera, device),
            edge_weight: Tensor::from_data(TensorData::new(edge, [h, w]), device),
            smooth_wx: Tensor::from_data(TensorData::new(wx, [h, w - 1]), device),
            smooth_wy: Tensor::from_data(TensorData::new(wy, [h - 1, w]), device),
        })
    }

    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        (self.camera.width as usize, self.camera.height as usize)
    }
}

/// Per pixel of a row-major `w x h` mask, the Chebyshev distance in pixels to the nearest pixel
/// on the other side of the 0.5 level (1 for the pixels on either side of the silhouette),
/// capped at [`MASK_EDGE_CAP`]; pixels off the image do not count.
pub fn mask_edge_distance(mask: &[f32], w: usize, h: usize) -> Vec<f32> {
    let inside: Vec<bool> = mask.iter().map(|&m| m >= 0.5).collect();
    let r = MASK_EDGE_CAP as isize;
    (0..w * h)
        .map(|p| {
            let (x, y) = ((p % w) as isize, (p / w) as isize);
            let me = inside[p];
            let mut best = MASK_EDGE_CAP;
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= h as isize {
                    continue;
                }
                for dx in -r..=r {
                    let xx = x + dx;
                    let d = dx.unsigned_abs().max(dy.unsigned_abs());
                    if xx < 0 || xx >= w as isize || d >= best {
                        continue;
                    }
                    if inside[yy as usize * w + xx as usize] != me {
                        best = d;
                    }
                }
            }
            best as f32
        })
        .collect()
}

/// Uploads every view of a split ([`ViewTensors::new`] with its index).
pub fn upload_views(views: &[View], device: &Device) -> Result<Vec<ViewTensors>, ModelError> {
    views
        .iter()
        .enumerate()
        .map(|(i, v)| ViewTensors::new(v, i, device))
        .collect()
}

/// For each view, the other views whose viewing directions (towards the scene centre) lie
/// within `max_angle_deg`, nearest first, at most 8 (PGSR).
pub fn neighbours(cameras: &[Camera], max_angle_deg: f64) -> Vec<Vec<usize>> {
    let dirs: Vec<[f64; 3]> = cameras.iter().map(|c| c.rotation[2]).collect();
    let cos_max = max_angle_deg.to_radians().cos();
    (0..cameras.len())
        .map(|i| {
            let mut near: Vec<(f64, usize)> = (0..cameras.len())
                .filter(|&j| j != i)
                .map(|j| ((0..3).map(|k| dirs[i][k] * dirs[j][k]).sum::<f64>(), j))
                .filter(|(c, _)| *c >= cos_max)
                .collect();
            near.sort_by(|a, b| b.0.total_cmp(&a.0));
            near.into_iter().take(8).map(|(_, j)| j).collect()
        })
        .collect()
}

/// Gathers what [`crate::config::auto_components`] decides from: `meta.json` beside the
/// transforms when present (the light and the material), whether the images' shading follows
/// the camera ([`gtsr_data::light`]), and the neighbour structure of the training cameras.
pub fn scene_evidence(scene: &Scene, max_angle_deg: f64) -> Result<SceneEvidence, ModelError> {
    let mut e = SceneEvidence {
        train_views: scene.train.len(),
        ..SceneEvidence::default()
    };
    let meta_path = scene.root.join("meta.json");
    if meta_path.is_file() {
        let text =
            std::fs::read_to_string(&meta_path).map_err(|err| ModelError::io(&meta_path, err))?;
        let meta: serde_json::Value = serde_json::from_str(&text).map_err(|err| {
            ModelError::Data(format!("{}: not valid JSON: {err}", meta_path.display()))
        })?;
        if let Some(pos) = meta.pointer("/light/position").and_then(|v| v.as_str()) {
            e.colocated_light = Some(pos == "camera centre");
        }
        if let Some(s) = meta.pointer("/material/sigma_s").and_then(|v| v.as_array()) {
            let total: f64 = s.iter().filter_map(|v| v.as_f64()).sum();
            e.opaque = Some(total <= 0.0);
        }
    }
    e.light = gtsr_data::light::light_evidence(&scene.train, &LightSettings::default());
    let cams: Vec<Camera> = scene
        .train
        .iter()
        .map(|v| kernel_camera(&v.camera, &v.name))
        .collect::<Result<_, _>>()?;
    e.views_with_neighbours = neighbours(&cams, max_angle_deg)
        .iter()
        .filter(|n| !n.is_empty())
        .count();
    Ok(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_data_camera_comes_back_from_the_kernels_to_the_bit() {
        let eye = glam::Vec3::new(0.3, -1.7, 2.9);
        let c2w =
            glam::Mat4::look_at_rh(eye, glam::Vec3::new(0.1, 0.2, -0.3), glam::Vec3::Y).inverse();
        let c = gtsr_data::Camera::from_opengl_camera_to_world(c2w, 91.3, 88.7, 31.9, 24.1, 64, 48);
        let back = data_camera(&kernel_camera(&c, "view").unwrap());
        assert_eq!(back.world_to_camera, c.world_to_camera);
        assert_eq!(
            (back.fx, back.fy, back.cx, back.cy),
            (c.fx, c.fy, c.cx, c.cy)
        );
        assert_eq!((back.width, back.height), (c.width, c.height));
    }
}
