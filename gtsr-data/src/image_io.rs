//! Image reading (PNG, JPEG, EXR), downscaling, background compositing and PNG writing.
//!
//! # Pixel values
//!
//! [`Image::rgb`] holds `width * height * 3` `f32` values, row-major (row `j`, column `i`
//! at `3 * (j * width + i)`), **in the encoding of the file** ([`Image::encoding`]):
//! 8- and 16-bit PNG/JPEG are sRGB-encoded and scaled to `[0, 1]`
//! ([`Encoding::Srgb`]); EXR is linear radiance, not clamped ([`Encoding::Linear`]).
//! Use [`srgb_to_linear`] to linearise. Alpha (when the file has it) is straight
//! (not premultiplied), in `[0, 1]`.

use std::path::Path;

use crate::error::{DataError, Result};

/// How the values in [`Image::rgb`] are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Encoding {
    /// sRGB transfer function, values in `[0, 1]` (8/16-bit PNG, JPEG).
    Srgb,
    /// Linear values (EXR); may exceed 1.
    Linear,
}

/// A decoded image (see the module documentation for the layout and encoding).
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` values, row-major RGB.
    pub rgb: Vec<f32>,
    /// Straight alpha, `width * height` values in `[0, 1]`, when the file has an alpha channel.
    pub alpha: Option<Vec<f32>>,
    /// Encoding of `rgb`.
    pub encoding: Encoding,
}

fn decode(path: &Path) -> Result<image::DynamicImage> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DataError::io(path, e))?;
    reader.decode().map_err(|e| DataError::Decode {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn is_float(img: &image::DynamicImage) -> bool {
    matches!(
        img,
        image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
    )
}

/// Reads a PNG, JPEG or EXR file (format from the content, not the extension).
pub fn read_image(path: &Path) -> Result<Image> {
    let img = decode(path)?;
    let (width, height) = (img.width(), img.height());
    let encoding = if is_float(&img) {
        Encoding::Linear
    } else {
        Encoding::Srgb
    };
    let has_alpha = img.color().has_alpha();
    let n = (width as usize) * (height as usize);
    let mut rgb = Vec::with_capacity(3 * n);
    let mut alpha = if has_alpha {
        Some(Vec::with_capacity(n))
    } else {
        None
    };
    match img {
        image::DynamicImage::ImageRgba8(buf) => {
            for p in buf.pixels() {
                rgb.extend(p.0[..3].iter().map(|&v| v as f32 * (1.0 / 255.0)));
                if let Some(a) = alpha.as_mut() {
                    a.push(p.0[3] as f32 * (1.0 / 255.0));
                }
            }
        }
        image::DynamicImage::ImageRgb8(buf) => {
            rgb.extend(buf.as_raw().iter().map(|&v| v as f32 * (1.0 / 255.0)));
        }
        other => {
            let f = other.to_rgba32f();
            for p in f.pixels() {
                rgb.extend_from_slice(&p.0[..3]);
                if let Some(a) = alpha.as_mut() {
                    a.push(p.0[3].clamp(0.0, 1.0));
                }
            }
        }
    }
    Ok(Image {
        width,
        height,
        rgb,
        alpha,
        encoding,
    })
}

/// Reads a mask file: the alpha channel if the file has a non-constant one, else the first
/// (red or grey) channel; values in `[0, 1]`. Returns `(width, height, values)`.
pub fn read_mask(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let img = read_image(path)?;
    if let Some(a) = &img.alpha {
        let first = a.first().copied().unwrap_or(1.0);
        if a.iter().any(|&v| v != first) {
            return Ok((img.width, img.height, a.clone()));
        }
    }
    let v = img
        .rgb
        .chunks_exact(3)
        .map(|p| p[0].clamp(0.0, 1.0))
        .collect();
    Ok((img.width, img.height, v))
}

/// sRGB-encoded value to linear (IEC 61966-2-1).
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// [`srgb_to_linear`] in f64, for host reference evaluations.
#[inline]
pub fn srgb_to_linear_f64(v: f64) -> f64 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear value to sRGB encoding (IEC 61966-2-1); input clamped to `[0, 1]`.
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Box-filter downscale of an interleaved `channels`-channel buffer by an integer factor
/// (remainder columns/rows cropped). Returns `(new_w, new_h, data)`.
pub fn downscale_box(
    data: &[f32],
    width: u32,
    height: u32,
    channels: usize,
    factor: u32,
) -> (u32, u32, Vec<f32>) {
    if factor <= 1 {
        return (width, height, data.to_vec());
    }
    let f = factor as usize;
    let (w, h) = (width as usize, height as usize);
    let (nw, nh) = (w / f, h / f);
    let mut out = vec![0.0f32; nw * nh * channels];
    let norm = 1.0 / (f * f) as f32;
    for j in 0..nh {
        for i in 0..nw {
            let o = (j * nw + i) * channels;
            for dy in 0..f {
                let row = (j * f + dy) * w;
                for dx in 0..f {
                    let s = (row + i * f + dx) * channels;
                    for c in 0..channels {
                        out[o + c] += data[s + c];
                    }
                }
            }
            for c in 0..channels {
                out[o + c] *= norm;
            }
        }
    }
    (nw as u32, nh as u32, out)
}

/// Downscales an [`Image`] by an integer factor. Averaging happens in linear light
/// (sRGB data is linearised, averaged and re-encoded) and, when there is alpha, on
/// premultiplied colour (then un-premultiplied), so edges do not darken.
pub fn downscale_image(img: &Image, factor: u32) -> Image {
    if factor <= 1 {
        return img.clone();
    }
    let n = (img.width as usize) * (img.height as usize);
    let mut lin: Vec<f32> = match img.encoding {
        Encoding::Srgb => img.rgb.iter().map(|&v| srgb_to_linear(v)).collect(),
        Encoding::Linear => img.rgb.clone(),
    };
    if let Some(a) = &img.alpha {
        for k in 0..n {
            for c in 0..3 {
                lin[3 * k + c] *= a[k];
            }
        }
    }
    let (nw, nh, mut rgb) = downscale_box(&lin, img.width, img.height, 3, factor);
    let alpha = img
        .alpha
        .as_ref()
        .map(|a| downscale_box(a, img.width, img.height, 1, factor).2);
    if let Some(a) = &alpha {
        for (k, &ak) in a.iter().enumerate() {
            let inv = if ak > 1e-6 { 1.0 / ak } else { 0.0 };
            for c in 0..3 {
                rgb[3 * k + c] *= inv;
            }
        }
    }
    if img.encoding == Encoding::Srgb {
        for v in rgb.iter_mut() {
            *v = linear_to_srgb(*v);
        }
    }
    Image {
        width: nw,
        height: nh,
        rgb,
        alpha,
        encoding: img.encoding,
    }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, then a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path.parent().unwrap_or_else(|| Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes).map_err(|e| DataError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        DataError::io(path, e)
    })
}

/// Encodes 8-bit RGBA pixels (`width * height * 4` bytes, row-major) as PNG and writes it
/// atomically.
pub fn write_png_rgba8(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<()> {
    let mut buf = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut buf);
    image::ImageEncoder::write_image(enc, rgba, width, height, image::ExtendedColorType::Rgba8)
        .map_err(|e| DataError::Encode {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    write_atomic(path, &buf)
}
