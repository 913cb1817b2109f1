//! COLMAP sparse models (`cameras`, `images`, `points3D`, `.txt` or `.bin`) and a loader
//! for captures laid out as COLMAP leaves them:
//!
//! ```text
//! <root>/images/<image name>          the (undistorted) photographs
//! <root>/masks/<image name>[.png]     optional object masks (also <stem>.png)
//! <root>/sparse/0/{cameras,images,points3D}.{bin,txt}   (or <root>/sparse/, or <root>/)
//! ```
//!
//! Binary layout (little-endian): `cameras.bin` = u64 count, then per camera u32 id,
//! i32 model id, u64 width, u64 height, f64 params; `images.bin` = u64 count, then per image
//! u32 id, f64 qw qx qy qz (world-to-camera rotation), f64 tx ty tz, u32 camera id,
//! NUL-terminated name, u64 number of 2D points, then (f64 x, f64 y, i64 point id) each;
//! `points3D.bin` = u64 count, then per point u64 id, f64 xyz, u8 rgb, f64 error,
//! u64 track length, then (i32 image id, i32 point2D index) each.
//!
//! Camera models: `SIMPLE_PINHOLE` and `PINHOLE` load directly; the radial/OpenCV models
//! (`SIMPLE_RADIAL`, `RADIAL`, `OPENCV`, `FULL_OPENCV`) load when all their distortion
//! coefficients are zero and otherwise give [`DataError::UnsupportedCamera`] asking for
//! `colmap image_undistorter`; fisheye and FOV models always give that error.
//! COLMAP's pixel convention (centre of the top-left pixel at (0.5, 0.5)) is the crate's.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3, Mat4, Vec3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{DataError, Result};
use crate::image_io::read_image;
use crate::scene::{LoadOptions, Normalisation, Scene, View, make_view, separate_mask};

/// A COLMAP camera (intrinsics).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Camera id.
    pub id: u32,
    /// Model name, e.g. `PINHOLE`.
    pub model: String,
    /// Width in pixels.
    pub width: u64,
    /// Height in pixels.
    pub height: u64,
    /// Model parameters in COLMAP order.
    pub params: Vec<f64>,
}

/// A registered COLMAP image (extrinsics).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Image id.
    pub id: u32,
    /// World-to-camera rotation as a quaternion `(w, x, y, z)`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// Camera id.
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
}

/// A COLMAP 3D point.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// Point id.
    pub id: u64,
    /// Position.
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Reprojection error.
    pub error: f64,
}

/// `(model id, name, number of parameters)` for every COLMAP camera model.
pub const CAMERA_MODELS: [(i32, &str, usize); 12] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
    (11, "RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

impl ColmapCamera {
    /// Pinhole intrinsics `(fx, fy, cx, cy)`, or an error when the model needs undistortion.
    pub fn pinhole(&self, path: &Path) -> Result<(f64, f64, f64, f64)> {
        let p = &self.params;
        let err = |message: String| DataError::UnsupportedCamera {
            path: path.to_path_buf(),
            camera_id: self.id,
            message,
        };
        let (intr, distortion): ((f64, f64, f64, f64), &[f64]) = match self.model.as_str() {
            "SIMPLE_PINHOLE" => ((p[0], p[0], p[1], p[2]), &[]),
            "PINHOLE" => ((p[0], p[1], p[2], p[3]), &[]),
            "SIMPLE_RADIAL" | "RADIAL" => ((p[0], p[0], p[1], p[2]), &p[3..]),
            "OPENCV" | "FULL_OPENCV" => ((p[0], p[1], p[2], p[3]), &p[4..]),
            m => {
                return Err(err(format!(
                    "model {m} is not a pinhole projection; undistort the images first \
                     (colmap image_undistorter) and load the undistorted model"
                )));
            }
        };
        if distortion.iter().any(|&d| d != 0.0) {
            return Err(err(format!(
                "model {} has non-zero distortion {:?}: the images need undistortion; run \
                 `colmap image_undistorter` and load its output (PINHOLE cameras)",
                self.model, distortion
            )));
        }
        if !(intr.0 > 0.0 && intr.1 > 0.0) {
            return Err(err(format!(
                "non-positive focal length ({}, {})",
                intr.0, intr.1
            )));
        }
        Ok(intr)
    }
}

/// The fields of one record of a sparse model, read alike from a binary file ([`Reader`]) or
/// from a line of a text file ([`Line`]); `what` names the field in errors.
trait Fields {
    fn u32(&mut self, what: &str) -> Result<u32>;
    fn u64(&mut self, what: &str) -> Result<u64>;
    fn f64(&mut self, what: &str) -> Result<f64>;
}

struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    fn new(data: &'a [u8], path: &'a Path) -> Self {
        Reader { data, pos: 0, path }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if self.pos + n > self.data.len() {
            return Err(DataError::malformed(
                self.path,
                format!(
                    "truncated: needed {n} bytes for {what} at byte {} of {}",
                    self.pos,
                    self.data.len()
                ),
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn cstr(&mut self, what: &str) -> Result<String> {
        let rest = &self.data[self.pos..];
        let end = rest.iter().position(|&b| b == 0).ok_or_else(|| {
            DataError::malformed(
                self.path,
                format!("unterminated {what} at byte {}", self.pos),
            )
        })?;
        let s = String::from_utf8_lossy(&rest[..end]).into_owned();
        self.pos += end + 1;
        Ok(s)
    }
    /// A count that must fit in the remaining bytes at `min_size` bytes per element.
    fn count(&mut self, what: &str, min_size: usize) -> Result<usize> {
        let n = self.u64(what)?;
        let left = (self.data.len() - self.pos) as u64;
        if n.saturating_mul(min_size as u64) > left {
            return Err(DataError::malformed(
                self.path,
                format!(
                    "{what} = {n} at byte {} does not fit in the remaining {left} bytes",
                    self.pos - 8
                ),
            ));
        }
        Ok(n as usize)
    }
}

impl Fields for Reader<'_> {
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
}

/// One data line of a text model: its number (from 1) and its whitespace-separated fields.
struct Line<'a> {
    path: &'a Path,
    ln: usize,
    tokens: std::str::SplitWhitespace<'a>,
}

impl Line<'_> {
    /// The next field, parsed.
    fn next<T: std::str::FromStr>(&mut self, what: &str) -> Result<T> {
        let (path, line) = (self.path, self.ln);
        let tok = self
            .tokens
            .next()
            .ok_or_else(|| DataError::malformed(path, format!("line {line}: missing {what}")))?;
        tok.parse().map_err(|_| {
            DataError::malformed(
                path,
                format!("line {line}: cannot parse {what} from '{tok}'"),
            )
        })
    }
}

impl Fields for Line<'_> {
    fn u32(&mut self, what: &str) -> Result<u32> {
        self.next(what)
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        self.next(what)
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        self.next(what)
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

fn read_text(path: &Path) -> Result<String> {
    let b = read_bytes(path)?;
    String::from_utf8(b).map_err(|e| DataError::malformed(path, format!("not UTF-8: {e}")))
}

fn is_bin(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "bin")
}

/// The records of a binary model file: a u64 count (`count_what` in errors) that must fit in
/// the file at `min_size` bytes a record, then the records, each read by `record`.
fn bin_records<T>(
    path: &Path,
    count_what: &str,
    min_size: usize,
    mut record: impl FnMut(&mut Reader<'_>) -> Result<T>,
) -> Result<Vec<T>> {
    let data = read_bytes(path)?;
    let mut r = Reader::new(&data, path);
    let n = r.count(count_what, min_size)?;
    (0..n).map(|_| record(&mut r)).collect()
}

/// The records of a text model file, one a line that is neither blank nor a `#` comment, each
/// read by `record`; with `skip_next`, the line after each record (an image's 2D points,
/// possibly blank) is passed over too.
fn text_records<T>(
    path: &Path,
    skip_next: bool,
    mut record: impl FnMut(&mut Line<'_>) -> Result<T>,
) -> Result<Vec<T>> {
    let text = read_text(path)?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim_start().starts_with('#'));
    let mut out = Vec::new();
    while let Some((ln, line)) = lines.next() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        out.push(record(&mut Line {
            path,
            ln: ln + 1,
            tokens: line.split_whitespace(),
        })?);
        if skip_next {
            lines.next();
        }
    }
    Ok(out)
}

fn model_params(path: &Path, model: &str, line: usize) -> Result<usize> {
    CAMERA_MODELS
        .iter()
        .find(|m| m.1 == model)
        .map(|m| m.2)
        .ok_or_else(|| {
            DataError::malformed(path, format!("line {line}: unknown camera model '{model}'"))
        })
}

/// A camera record: id, model, width, height, parameters. The formats differ in how they
/// store the model (`model` reads its name and number of parameters, given the camera id)
/// and the parameters (`params` reads them, given the model), and in the names their errors
/// give the width and the height (`size_names`).
fn camera_record<F: Fields>(
    f: &mut F,
    size_names: [&str; 2],
    model: impl FnOnce(&mut F, u32) -> Result<(String, usize)>,
    params: impl FnOnce(&mut F, &str, usize) -> Result<Vec<f64>>,
) -> Result<ColmapCamera> {
    let id = f.u32("camera id")?;
    let (model, np) = model(f, id)?;
    let width = f.u64(size_names[0])?;
    let height = f.u64(size_names[1])?;
    let params = params(f, &model, np)?;
    Ok(ColmapCamera {
        id,
        model,
        width,
        height,
        params,
    })
}

/// Reads `cameras.txt` or `cameras.bin` (by extension).
pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>> {
    if is_bin(path) {
        bin_records(path, "number of cameras", 24, |r| {
            camera_record(
                r,
                ["camera width", "camera height"],
                |r, id| {
                    let model_id = r.i32("camera model id")?;
                    let (_, name, np) = *CAMERA_MODELS
                        .iter()
                        .find(|m| m.0 == model_id)
                        .ok_or_else(|| {
                            DataError::malformed(
                                path,
                                format!("camera {id}: unknown camera model id {model_id}"),
                            )
                        })?;
                    Ok((name.to_string(), np))
                },
                |r, _, np| (0..np).map(|_| r.f64("camera parameter")).collect(),
            )
        })
    } else {
        text_records(path, false, |l| {
            camera_record(
                l,
                ["width", "height"],
                |l, _| {
                    let model: String = l.next("camera model")?;
                    let np = model_params(path, &model, l.ln)?;
                    Ok((model, np))
                },
                |l, model, np| {
                    let ln = l.ln;
                    let params: Vec<f64> = (&mut l.tokens)
                        .map(|s| {
                            s.parse::<f64>().map_err(|_| {
                                DataError::malformed(
                                    path,
                                    format!("line {ln}: cannot parse parameter '{s}'"),
                                )
                            })
                        })
                        .collect::<Result<_>>()?;
                    if params.len() != np {
                        return Err(DataError::malformed(
                            path,
                            format!(
                                "line {ln}: model {model} needs {np} parameters, found {}",
                                params.len()
                            ),
                        ));
                    }
                    Ok(params)
                },
            )
        })
    }
}

/// An image record: id, rotation, translation, camera id, then the name as `name` reads it.
fn image_record<F: Fields>(
    f: &mut F,
    name: impl FnOnce(&mut F) -> Result<String>,
) -> Result<ColmapImage> {
    let id = f.u32("image id")?;
    let mut qvec = [0.0; 4];
    for q in qvec.iter_mut() {
        *q = f.f64("quaternion")?;
    }
    let mut tvec = [0.0; 3];
    for t in tvec.iter_mut() {
        *t = f.f64("translation")?;
    }
    let camera_id = f.u32("camera id")?;
    let name = name(f)?;
    Ok(ColmapImage {
        id,
        qvec,
        tvec,
        camera_id,
        name,
    })
}

/// Reads `images.txt` or `images.bin` (by extension); 2D points are skipped.
pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    if is_bin(path) {
        bin_records(path, "number of images", 64, |r| {
            image_record(r, |r| {
                let name = r.cstr("image name")?;
                let np = r.count("number of 2D points", 24)?;
                r.take(np * 24, "2D points")?;
                Ok(name)
            })
        })
    } else {
        // Two lines an image: the second lists its 2D points (possibly none).
        text_records(path, true, |l| {
            image_record(l, |l| {
                let name = (&mut l.tokens).collect::<Vec<_>>().join(" ");
                if name.is_empty() {
                    return Err(DataError::malformed(
                        path,
                        format!("line {}: missing image name", l.ln),
                    ));
                }
                Ok(name)
            })
        })
    }
}

/// A point record: id, position, colour (as `rgb` reads it), reprojection error.
fn point_record<F: Fields>(
    f: &mut F,
    rgb: impl FnOnce(&mut F) -> Result<[u8; 3]>,
) -> Result<ColmapPoint> {
    let id = f.u64("point id")?;
    let xyz = [f.f64("x")?, f.f64("y")?, f.f64("z")?];
    let rgb = rgb(f)?;
    let error = f.f64("error")?;
    Ok(ColmapPoint {
        id,
        xyz,
        rgb,
        error,
    })
}

/// Reads `points3D.txt` or `points3D.bin` (by extension); tracks are skipped.
pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint>> {
    if is_bin(path) {
        bin_records(path, "number of points", 51, |r| {
            let point = point_record(r, |r| {
                let c = r.take(3, "colour")?;
                Ok([c[0], c[1], c[2]])
            })?;
            let tl = r.count("track length", 8)?;
            r.take(tl * 8, "track")?;
            Ok(point)
        })
    } else {
        text_records(path, false, |l| {
            point_record(l, |l| Ok([l.next("r")?, l.next("g")?, l.next("b")?]))
        })
    }
}

/// The folder holding the sparse model: `<root>/sparse/0`, `<root>/sparse` or `<root>`,
/// the first that has a `cameras.bin` or `cameras.txt`.
pub fn find_model_dir(root: &Path) -> Result<PathBuf> {
    for d in [
        root.join("sparse").join("0"),
        root.join("sparse"),
        root.to_path_buf(),
    ] {
        if d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file() {
            return Ok(d);
        }
    }
    Err(DataError::MissingFile {
        path: root.join("sparse/0/cameras.bin"),
        what: "COLMAP model (cameras.{bin,txt} in sparse/0, sparse or the root)".into(),
    })
}

fn model_file(dir: &Path, stem: &str) -> Result<PathBuf> {
    let bin = dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        return Ok(bin);
    }
    let txt = dir.join(format!("{stem}.txt"));
    if txt.is_file() {
        return Ok(txt);
    }
    Err(DataError::MissingFile {
        path: bin,
        what: format!("COLMAP {stem} (.bin or .txt)"),
    })
}

/// World-to-camera matrix from a COLMAP quaternion and translation; errors on a
/// non-unit or non-finite quaternion.
fn extrinsics(img: &ColmapImage, path: &Path) -> Result<Mat4> {
    let [w, x, y, z] = img.qvec;
    let q = DQuat::from_xyzw(x, y, z, w);
    let norm = q.length();
    let t = DVec3::from_array(img.tvec);
    if !(norm.is_finite() && t.is_finite()) || (norm - 1.0).abs() > 1e-2 {
        return Err(DataError::NonRigid {
            path: path.to_path_buf(),
            frame: img.id as usize,
            message: format!(
                "quaternion {:?} has norm {norm} (expected 1) or the pose is not finite",
                img.qvec
            ),
        });
    }
    let m = glam::DMat4::from_rotation_translation(q / norm, t);
    Ok(m.as_mat4())
}

fn find_colmap_mask(root: &Path, name: &str) -> Option<PathBuf> {
    let dir = root.join("masks");
    let p = Path::new(name);
    let stem = p.with_extension("");
    [
        dir.join(name),
        dir.join(format!("{name}.png")),
        dir.join(format!("{}.png", stem.display())),
    ]
    .into_iter()
    .find(|c| c.is_file())
}

/// Loads a COLMAP capture (see the module documentation for the layout). Images are sorted by
/// name; every [`LoadOptions::colmap_test_every`]-th goes to the test split.
pub fn load_colmap(root: impl AsRef<Path>, opts: &LoadOptions) -> Result<Scene> {
    let root = root.as_ref().to_path_buf();
    let dir = find_model_dir(&root)?;
    let cam_path = model_file(&dir, "cameras")?;
    let img_path = model_file(&dir, "images")?;
    let cams: HashMap<u32, ColmapCamera> = read_cameras(&cam_path)?
        .into_iter()
        .map(|c| (c.id, c))
        .collect();
    let mut images = read_images(&img_path)?;
    if images.is_empty() {
        return Err(DataError::EmptySplit {
            path: img_path,
            split: "all".into(),
        });
    }
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let points = match model_file(&dir, "points3D") {
        Ok(p) => read_points3d(&p)?,
        Err(_) => Vec::new(),
    };
    // Validate everything cheap before decoding images.
    let mut jobs = Vec::with_capacity(images.len());
    for img in &images {
        let cam = cams.get(&img.camera_id).ok_or_else(|| {
            DataError::malformed(
                &img_path,
                format!(
                    "image {} ({}) refers to camera {} which {} does not define",
                    img.id,
                    img.name,
                    img.camera_id,
                    cam_path.display()
                ),
            )
        })?;
        let (fx, fy, cx, cy) = cam.pinhole(&cam_path)?;
        let w2c = extrinsics(img, &img_path)?;
        let file = root.join("images").join(&img.name);
        if !file.is_file() {
            return Err(DataError::MissingImage {
                json: img_path.clone(),
                frame: img.id as usize,
                tried: file.display().to_string(),
            });
        }
        let camera = Camera {
            world_to_camera: glam::Affine3A::from_mat4(w2c),
            fx: fx as f32,
            fy: fy as f32,
            cx: cx as f32,
            cy: cy as f32,
            width: cam.width as u32,
            height: cam.height as u32,
        };
        jobs.push((img, file, camera));
    }
    let views: Vec<View> = jobs
        .par_iter()
        .map(|(img, file, camera)| {
            let image = read_image(file)?;
            if (image.width, image.height) != (camera.width, camera.height) {
                return Err(DataError::SizeMismatch {
                    path: file.clone(),
                    frame: img.id as usize,
                    got_w: image.width,
                    got_h: image.height,
                    want_w: camera.width,
                    want_h: camera.height,
                });
            }
            let mask = separate_mask(&image, || find_colmap_mask(&root, &img.name))?;
            make_view(
                img.name.clone(),
                file.clone(),
                *camera,
                image,
                mask,
                opts,
                (0x636f6c6d6170, img.id as usize),
            )
        })
        .collect::<Result<_>>()?;
    let (mut train, mut test) = (Vec::new(), Vec::new());
    for (k, v) in views.into_iter().enumerate() {
        match opts.colmap_test_every {
            Some(n) if n > 0 && k % n == 0 => test.push(v),
            _ => train.push(v),
        }
    }
    if train.is_empty() {
        return Err(DataError::EmptySplit {
            path: img_path,
            split: "train".into(),
        });
    }
    Scene {
        root,
        train,
        val: Vec::new(),
        test,
        normalisation: Normalisation::IDENTITY,
        normalisation_applied: false,
        mesh_path: None,
        points: points
            .iter()
            .map(|p| Vec3::new(p.xyz[0] as f32, p.xyz[1] as f32, p.xyz[2] as f32))
            .collect(),
        point_colors: points.iter().map(|p| p.rgb).collect(),
    }
    .finish(opts)
}

/// Writes a COLMAP model as text (`cameras.txt`, `images.txt`, `points3D.txt`) into `dir`:
/// PINHOLE cameras, one per view. Useful for tests and for exporting synthetic scenes.
pub fn write_text_model(
    dir: &Path,
    views: &[(String, Camera)],
    points: &[(Vec3, [u8; 3])],
) -> Result<()> {
    let mut cams = String::from("# Camera list with one line of data per camera:\n");
    let mut imgs = String::from("# Image list with two lines of data per image:\n");
    for (k, (name, c)) in views.iter().enumerate() {
        let id = k + 1;
        cams += &format!(
            "{id} PINHOLE {} {} {} {} {} {}\n",
            c.width, c.height, c.fx, c.fy, c.cx, c.cy
        );
        let q = glam::Quat::from_mat3a(&c.world_to_camera.matrix3);
        let t = c.world_to_camera.translation;
        imgs += &format!(
            "{id} {} {} {} {} {} {} {} {id} {name}\n\n",
            q.w, q.x, q.y, q.z, t.x, t.y, t.z
        );
    }
    let mut pts = String::from("# 3D point list\n");
    for (k, (p, c)) in points.iter().enumerate() {
        pts += &format!(
            "{} {} {} {} {} {} {} 0.5\n",
            k + 1,
            p.x,
            p.y,
            p.z,
            c[0],
            c[1],
            c[2]
        );
    }
    crate::image_io::write_atomic(&dir.join("cameras.txt"), cams.as_bytes())?;
    crate::image_io::write_atomic(&dir.join("images.txt"), imgs.as_bytes())?;
    crate::image_io::write_atomic(&dir.join("points3D.txt"), pts.as_bytes())
}
