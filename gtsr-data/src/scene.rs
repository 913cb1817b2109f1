//! [`Scene`]: the loaded views of a dataset, its normalisation and optional ground truth.

use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{DataError, Result};
use crate::image_io::{Encoding, Image, downscale_image, read_mask};
use crate::transport::rng::Rng;

/// Background to composite RGBA images onto (`out = rgb * mask + bg * (1 - mask)`, in the
/// file's encoding, as NeRF-style pipelines do with straight alpha).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Background {
    /// Keep the stored colour (straight alpha): no compositing.
    Keep,
    /// Composite onto black.
    Black,
    /// Composite onto white.
    White,
    /// Composite onto per-pixel uniform random colours, deterministic for
    /// `(seed, split, view index)`.
    Random {
        /// Seed of the background noise.
        seed: u64,
    },
}

/// Resolution reduction applied at load time (box filter in linear light, see
/// [`crate::image_io::downscale_image`]; intrinsics follow [`Camera::downscaled`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Downscale {
    /// Full resolution.
    None,
    /// Divide both sides by this integer factor (remainders cropped).
    Factor(u32),
    /// The smallest integer factor that makes the longer side at most this many pixels.
    MaxSide(u32),
}

impl Downscale {
    /// The integer factor for an image of `width x height`.
    pub fn factor(&self, width: u32, height: u32) -> u32 {
        match *self {
            Downscale::None => 1,
            Downscale::Factor(f) => f.max(1),
            Downscale::MaxSide(m) => {
                let side = width.max(height);
                side.div_ceil(m.max(1)).max(1)
            }
        }
    }
}

/// Where the scene normalisation (centre, radius) comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NormaliseFrom {
    /// Centre: least-squares intersection of the training cameras' optical axes. Radius: the
    /// largest sphere around it that every training camera sees whole
    /// (`min_k dist_k * sin(half the smaller field of view)`).
    Cameras,
    /// Visual hull of the training masks (mask > 0.5) carved on a 64^3 grid inside the
    /// camera sphere; centre and radius of the hull's bounding sphere. Needs masks.
    Masks,
    /// Identity: centre 0, radius 1.
    Identity,
}

/// The similarity `p_normalised = (p_world - centre) / radius`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalisation {
    /// Centre in the file's world units.
    pub centre: Vec3,
    /// Radius in the file's world units (> 0).
    pub radius: f32,
}

impl Normalisation {
    /// The identity.
    pub const IDENTITY: Normalisation = Normalisation {
        centre: Vec3::ZERO,
        radius: 1.0,
    };

    /// World (file units) to normalised coordinates.
    pub fn to_normalised(&self, p: Vec3) -> Vec3 {
        (p - self.centre) / self.radius
    }

    /// Normalised coordinates to world (file units).
    pub fn to_world(&self, p: Vec3) -> Vec3 {
        p * self.radius + self.centre
    }
}

/// Options shared by the loaders.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Compositing of images that have a mask (default [`Background::Black`]).
    pub background: Background,
    /// Resolution reduction (default none).
    pub downscale: Downscale,
    /// Where the normalisation comes from (default [`NormaliseFrom::Cameras`]).
    pub normalise_from: NormaliseFrom,
    /// Apply the normalisation to the cameras (and points) at load time (default `false`:
    /// cameras stay in file units and [`Scene::normalisation`] says how to normalise).
    pub apply_normalisation: bool,
    /// Load the `val` split of Blender scenes too (default `false`).
    pub load_val: bool,
    /// COLMAP only: every `n`-th image (sorted by name, starting with the first) goes to the
    /// test split; `None` puts all images in train (default `Some(8)`, the LLFF convention).
    pub colmap_test_every: Option<usize>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            background: Background::Black,
            downscale: Downscale::None,
            normalise_from: NormaliseFrom::Cameras,
            apply_normalisation: false,
            load_val: false,
            colmap_test_every: Some(8),
        }
    }
}

/// One posed image.
#[derive(Clone, Debug)]
pub struct View {
    /// Name (Blender: `file_path` as written; COLMAP: image name).
    pub name: String,
    /// The image file that was read.
    pub path: PathBuf,
    /// Camera, with intrinsics matching the (possibly downscaled) image.
    pub camera: Camera,
    /// `width * height * 3` values, row-major, composited per [`LoadOptions::background`];
    /// encoding in [`View::encoding`].
    pub rgb: Vec<f32>,
    /// Encoding of `rgb` (sRGB for PNG/JPEG, linear for EXR).
    pub encoding: Encoding,
    /// Object mask in `[0, 1]` (alpha channel or mask file), `width * height` values.
    pub mask: Option<Vec<f32>>,
}

impl View {
    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.camera.width
    }
    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.camera.height
    }
}

/// A loaded dataset.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The dataset folder.
    pub root: PathBuf,
    /// Training views.
    pub train: Vec<View>,
    /// Validation views (Blender `transforms_val.json` when [`LoadOptions::load_val`]).
    pub val: Vec<View>,
    /// Held-out test views.
    pub test: Vec<View>,
    /// Normalisation computed at load time (see [`NormaliseFrom`]).
    pub normalisation: Normalisation,
    /// Whether the cameras and points are already normalised (then `normalisation` is the
    /// transform that was applied, so `to_world` maps back to file units).
    pub normalisation_applied: bool,
    /// Ground-truth mesh (`mesh.ply` beside the transforms), when present.
    pub mesh_path: Option<PathBuf>,
    /// Sparse points (COLMAP `points3D`), empty for Blender scenes.
    pub points: Vec<Vec3>,
    /// Colours of `points`.
    pub point_colors: Vec<[u8; 3]>,
}

impl Scene {
    /// Applies [`Scene::normalisation`] to every camera and point (no-op when already
    /// applied).
    pub fn normalise(&mut self) {
        if self.normalisation_applied {
            return;
        }
        let n = self.normalisation;
        for v in self
            .train
            .iter_mut()
            .chain(self.val.iter_mut())
            .chain(self.test.iter_mut())
        {
            v.camera = v.camera.normalised(n.centre, n.radius);
        }
        for p in self.points.iter_mut() {
            *p = n.to_normalised(*p);
        }
        self.normalisation_applied = true;
    }

    /// All views (train, val, test).
    pub fn all_views(&self) -> impl Iterator<Item = &View> {
        self.train
            .iter()
            .chain(self.val.iter())
            .chain(self.test.iter())
    }

    /// Computes the normalisation and applies it if asked (called by the loaders).
    pub(crate) fn finish(mut self, opts: &LoadOptions) -> Result<Scene> {
        self.normalisation = match opts.normalise_from {
            NormaliseFrom::Identity => Normalisation::IDENTITY,
            NormaliseFrom::Cameras => normalisation_from_cameras(&self.train),
            NormaliseFrom::Masks => normalisation_from_masks(&self.train, &self.root)?,
        };
        if opts.apply_normalisation {
            self.normalise();
        }
        Ok(self)
    }
}

/// A mask read from its own file: path, width, height, values in `[0, 1]`.
pub(crate) type MaskFile = (PathBuf, u32, u32, Vec<f32>);

/// A mask file for an image without alpha: `find` locates it (`None`: no mask), and it is read
/// here. Images with alpha use that instead and get `None`.
pub(crate) fn separate_mask(
    image: &Image,
    find: impl FnOnce() -> Option<PathBuf>,
) -> Result<Option<MaskFile>> {
    if image.alpha.is_some() {
        return Ok(None);
    }
    match find() {
        Some(path) => {
            let (w, h, m) = read_mask(&path)?;
            Ok(Some((path, w, h, m)))
        }
        None => Ok(None),
    }
}

/// Turns a decoded image (+ optional separate mask) into a [`View`]: checks sizes,
/// downscales, composites.
#[allow(clippy::too_many_arguments)]
pub(crate) fn make_view(
    name: String,
    path: PathBuf,
    camera: Camera,
    mut image: Image,
    mask: Option<MaskFile>,
    opts: &LoadOptions,
    bg_key: (u64, usize),
) -> Result<View> {
    if let Some((mpath, mw, mh, m)) = mask {
        if (mw, mh) != (image.width, image.height) {
            return Err(DataError::MaskSizeMismatch {
                path: mpath,
                got_w: mw,
                got_h: mh,
                want_w: image.width,
                want_h: image.height,
            });
        }
        image.alpha = Some(m);
    }
    let factor = opts.downscale.factor(image.width, image.height);
    let image = if factor > 1 {
        downscale_image(&image, factor)
    } else {
        image
    };
    let camera = if factor > 1 {
        camera.downscaled(factor)
    } else {
        camera
    };
    let Image {
        mut rgb,
        alpha,
        encoding,
        ..
    } = image;
    if let Some(a) = &alpha {
        composite(&mut rgb, a, opts.background, bg_key);
    }
    Ok(View {
        name,
        path,
        camera,
        rgb,
        encoding,
        mask: alpha,
    })
}

/// `rgb = rgb * a + bg * (1 - a)` in place.
pub fn composite(rgb: &mut [f32], alpha: &[f32], bg: Background, key: (u64, usize)) {
    match bg {
        Background::Keep => {}
        Background::Black | Background::White => {
            let b = if bg == Background::White { 1.0 } else { 0.0 };
            for (p, &a) in rgb.chunks_exact_mut(3).zip(alpha) {
                for v in p {
                    *v = *v * a + b * (1.0 - a);
                }
            }
        }
        Background::Random { seed } => {
            let mut rng = Rng::new(seed, key.0, key.1 as u64, 0x6267);
            for (p, &a) in rgb.chunks_exact_mut(3).zip(alpha) {
                for v in p {
                    let b = rng.next_f32();
                    *v = *v * a + b * (1.0 - a);
                }
            }
        }
    }
}

/// See [`NormaliseFrom::Cameras`].
pub fn normalisation_from_cameras(views: &[View]) -> Normalisation {
    normalisation_of_cameras(&views.iter().map(|v| &v.camera).collect::<Vec<_>>())
}

/// [`normalisation_from_cameras`] of the cameras alone.
pub fn normalisation_of_cameras(cameras: &[&Camera]) -> Normalisation {
    if cameras.is_empty() {
        return Normalisation::IDENTITY;
    }
    let mut a = Mat3::ZERO;
    let mut b = Vec3::ZERO;
    let mut mean = Vec3::ZERO;
    for c in cameras {
        let o = c.centre();
        let d = c.forward();
        let p = Mat3::IDENTITY - Mat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * o;
        mean += o;
    }
    mean /= cameras.len() as f32;
    let centre = if a.determinant().abs() > 1e-6 * (cameras.len() as f32).powi(3) {
        a.inverse() * b
    } else {
        mean
    };
    let radius = cameras
        .iter()
        .map(|c| {
            let half = 0.5
                * (2.0 * (0.5 * c.width as f32 / c.fx).atan())
                    .min(2.0 * (0.5 * c.height as f32 / c.fy).atan());
            (c.centre() - centre).length() * half.sin()
        })
        .fold(f32::INFINITY, f32::min);
    let radius = if radius.is_finite() && radius > 0.0 {
        radius
    } else {
        1.0
    };
    Normalisation { centre, radius }
}

/// See [`NormaliseFrom::Masks`].
pub fn normalisation_from_masks(views: &[View], root: &Path) -> Result<Normalisation> {
    if let Some(v) = views.iter().find(|v| v.mask.is_none()) {
        return Err(DataError::InvalidArgument(format!(
            "{}: normalisation from masks needs a mask for every training view; {} has none",
            root.display(),
            v.path.display()
        )));
    }
    let cam = normalisation_from_cameras(views);
    const N: usize = 64;
    let half = 1.5 * cam.radius;
    let h = 2.0 * half / N as f32;
    let lo = cam.centre - Vec3::splat(half);
    let kept: Vec<Vec3> = (0..N * N * N)
        .into_par_iter()
        .filter_map(|idx| {
            let (i, j, k) = (idx % N, (idx / N) % N, idx / (N * N));
            let p = lo + Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * h;
            for v in views {
                let c = &v.camera;
                let (uv, _) = c.project(p)?;
                if uv.x < 0.0 || uv.y < 0.0 || uv.x >= c.width as f32 || uv.y >= c.height as f32 {
                    return None;
                }
                let m = v.mask.as_ref()?;
                if m[uv.y as usize * c.width as usize + uv.x as usize] <= 0.5 {
                    return None;
                }
            }
            Some(p)
        })
        .collect();
    if kept.is_empty() {
        return Err(DataError::InvalidArgument(format!(
            "{}: the masks carve away the whole visual hull (empty masks, or cameras that do not see a common object)",
            root.display()
        )));
    }
    let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in &kept {
        bmin = bmin.min(*p);
        bmax = bmax.max(*p);
    }
    let centre = 0.5 * (bmin + bmax);
    let radius = kept
        .iter()
        .map(|p| (*p - centre).length())
        .fold(0.0f32, f32::max)
        + 0.5 * 3f32.sqrt() * h;
    Ok(Normalisation { centre, radius })
}
