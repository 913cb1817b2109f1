//! Blender / NeRF-synthetic loader (`transforms_{train,val,test}.json`).
//!
//! Accepted fields (top level, and per frame where a frame overrides them):
//! `camera_angle_x`, `camera_angle_y`, `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`; each frame has
//! `file_path` (relative to the JSON's folder, with or without extension: `.png`, `.jpg`,
//! `.jpeg`, `.exr` and upper-case variants are tried) and `transform_matrix`
//! (4x4 camera-to-world, OpenGL convention, row-major as nested arrays).
//!
//! Intrinsics: `fx = fl_x` or `0.5 * W / tan(0.5 * camera_angle_x)`; `fy = fl_y`, or from
//! `camera_angle_y`, or `fx`; `cx = W/2`, `cy = H/2` unless given. `W, H` are `w, h` when
//! given (then the image must have that size) or the size of the split's first image
//! (then every image of the split must have it).
//!
//! Masks: the alpha channel of RGBA images; for RGB images, a mask file found at
//! `<root>/masks/<file_path>.png`, `<root>/masks/<file name>.png` or
//! `<image folder>/masks/<file name>.png` (first found), else no mask.

use std::path::{Path, PathBuf};

use glam::Mat4;
use rayon::prelude::*;
use serde::Deserialize;

use crate::camera::{Camera, check_rigid, orthonormalise};
use crate::error::{DataError, Result};
use crate::image_io::read_image;
use crate::scene::{LoadOptions, Normalisation, Scene, View, make_view, separate_mask};

#[derive(Deserialize, Default, Clone, Copy)]
struct Intrinsics {
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
}

impl Intrinsics {
    fn or(self, base: Intrinsics) -> Intrinsics {
        Intrinsics {
            camera_angle_x: self.camera_angle_x.or(base.camera_angle_x),
            camera_angle_y: self.camera_angle_y.or(base.camera_angle_y),
            fl_x: self.fl_x.or(base.fl_x),
            fl_y: self.fl_y.or(base.fl_y),
            cx: self.cx.or(base.cx),
            cy: self.cy.or(base.cy),
            w: self.w.or(base.w),
            h: self.h.or(base.h),
        }
    }
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
    #[serde(flatten)]
    intr: Intrinsics,
}

#[derive(Deserialize)]
struct Transforms {
    #[serde(flatten)]
    intr: Intrinsics,
    frames: Vec<Frame>,
}

const IMAGE_EXTS: [&str; 8] = ["png", "PNG", "jpg", "JPG", "jpeg", "JPEG", "exr", "EXR"];

fn find_image(root: &Path, file_path: &str) -> std::result::Result<PathBuf, Vec<PathBuf>> {
    let base = root.join(file_path);
    let mut tried = Vec::new();
    let has_ext = base
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTS.contains(&e));
    if has_ext {
        if base.is_file() {
            return Ok(base);
        }
        tried.push(base.clone());
    }
    for ext in IMAGE_EXTS {
        let mut s = base.clone().into_os_string();
        s.push(".");
        s.push(ext);
        let p = PathBuf::from(s);
        if p.is_file() {
            return Ok(p);
        }
        tried.push(p);
    }
    Err(tried)
}

fn find_mask(root: &Path, file_path: &str, image: &Path) -> Option<PathBuf> {
    let rel = file_path.trim_start_matches("./");
    let stem = image.file_stem()?.to_string_lossy().into_owned();
    let rel_noext = Path::new(rel).with_extension("");
    let mut c = vec![
        root.join("masks")
            .join(format!("{}.png", rel_noext.display())),
        root.join("masks").join(format!("{stem}.png")),
    ];
    if let Some(dir) = image.parent() {
        c.push(dir.join("masks").join(format!("{stem}.png")));
    }
    c.into_iter().find(|p| p.is_file())
}

/// Loads one split (`train`, `val` or `test`) of a Blender/NeRF scene.
///
/// Errors: [`DataError::MissingFile`] when the transforms file is absent,
/// [`DataError::MalformedJson`], [`DataError::EmptySplit`], [`DataError::NonRigid`],
/// [`DataError::MissingImage`], [`DataError::SizeMismatch`], [`DataError::Decode`].
pub fn load_split(root: &Path, split: &str, opts: &LoadOptions) -> Result<Vec<View>> {
    let json = root.join(format!("transforms_{split}.json"));
    if !json.is_file() {
        return Err(DataError::MissingFile {
            path: json,
            what: format!("transforms of split '{split}'"),
        });
    }
    let bytes = std::fs::read(&json).map_err(|e| DataError::io(&json, e))?;
    let t: Transforms = serde_json::from_slice(&bytes).map_err(|e| DataError::MalformedJson {
        path: json.clone(),
        message: e.to_string(),
    })?;
    if t.frames.is_empty() {
        return Err(DataError::EmptySplit {
            path: json,
            split: split.to_string(),
        });
    }
    // Validate every matrix and find every image before decoding anything.
    let mut frames = Vec::with_capacity(t.frames.len());
    for (k, f) in t.frames.iter().enumerate() {
        let m =
            Mat4::from_cols_array_2d(&f.transform_matrix.map(|r| r.map(|v| v as f32))).transpose();
        check_rigid(&m).map_err(|message| DataError::NonRigid {
            path: json.clone(),
            frame: k,
            message,
        })?;
        let img = find_image(root, &f.file_path).map_err(|tried| DataError::MissingImage {
            json: json.clone(),
            frame: k,
            tried: tried
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        })?;
        let intr = f.intr.or(t.intr);
        if intr.camera_angle_x.is_none() && intr.fl_x.is_none() {
            return Err(DataError::MalformedJson {
                path: json.clone(),
                message: format!("frame {k}: neither camera_angle_x nor fl_x is given"),
            });
        }
        frames.push((k, f, orthonormalise(&m), img, intr));
    }
    // The reference size: from the JSON, or from the first image.
    let first_size = {
        let (_, _, _, img, intr) = &frames[0];
        match (intr.w, intr.h) {
            (Some(w), Some(h)) => (w.round() as u32, h.round() as u32),
            _ => {
                let (w, h) = image::image_dimensions(img).map_err(|e| DataError::Decode {
                    path: img.clone(),
                    message: e.to_string(),
                })?;
                (w, h)
            }
        }
    };
    let seed_key = split_key(split);
    frames
        .par_iter()
        .map(|(k, f, c2w, img_path, intr)| {
            let image = read_image(img_path)?;
            let (want_w, want_h) = match (intr.w, intr.h) {
                (Some(w), Some(h)) => (w.round() as u32, h.round() as u32),
                _ => first_size,
            };
            if (image.width, image.height) != (want_w, want_h) {
                return Err(DataError::SizeMismatch {
                    path: img_path.clone(),
                    frame: *k,
                    got_w: image.width,
                    got_h: image.height,
                    want_w,
                    want_h,
                });
            }
            let (w, h) = (want_w as f64, want_h as f64);
            let fx = intr
                .fl_x
                .or_else(|| intr.camera_angle_x.map(|a| 0.5 * w / (0.5 * a).tan()))
                .unwrap_or(1.0);
            let fy = intr
                .fl_y
                .or_else(|| intr.camera_angle_y.map(|a| 0.5 * h / (0.5 * a).tan()))
                .unwrap_or(fx);
            let cx = intr.cx.unwrap_or(0.5 * w);
            let cy = intr.cy.unwrap_or(0.5 * h);
            if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
                return Err(DataError::MalformedJson {
                    path: json.clone(),
                    message: format!("frame {k}: focal length is not positive ({fx}, {fy})"),
                });
            }
            let camera = Camera::from_opengl_camera_to_world(
                *c2w, fx as f32, fy as f32, cx as f32, cy as f32, want_w, want_h,
            );
            let mask = separate_mask(&image, || find_mask(root, &f.file_path, img_path))?;
            make_view(
                f.file_path.clone(),
                img_path.clone(),
                camera,
                image,
                mask,
                opts,
                (seed_key, *k),
            )
        })
        .collect()
}

fn split_key(split: &str) -> u64 {
    split.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// Loads a Blender/NeRF scene: `transforms_train.json` (required), `transforms_test.json`
/// (optional: empty test split when absent), `transforms_val.json` when
/// [`LoadOptions::load_val`] (optional), and `mesh.ply` when present.
pub fn load_blender(root: impl AsRef<Path>, opts: &LoadOptions) -> Result<Scene> {
    let root = root.as_ref().to_path_buf();
    let train = load_split(&root, "train", opts)?;
    let optional = |split: &str| -> Result<Vec<View>> {
        if root.join(format!("transforms_{split}.json")).is_file() {
            load_split(&root, split, opts)
        } else {
            Ok(Vec::new())
        }
    };
    let test = optional("test")?;
    let val = if opts.load_val {
        optional("val")?
    } else {
        Vec::new()
    };
    let mesh = root.join("mesh.ply");
    Scene {
        mesh_path: mesh.is_file().then_some(mesh),
        root,
        train,
        val,
        test,
        normalisation: Normalisation::IDENTITY,
        normalisation_applied: false,
        points: Vec::new(),
        point_colors: Vec::new(),
    }
    .finish(opts)
}
