//! Pixel-level helpers every step shares: bilinear sampling of a per-pixel map, and the
//! footprint of a camera's pixel at a point.

use glam::Vec3;
use gtsr_data::Camera;

/// Bilinear sample of a `w x h` single-channel image at continuous pixel coordinates
/// (pixel centres at `i + 0.5`), clamped at the border.
pub fn bilinear(img: &[f32], w: usize, h: usize, u: f32, v: f32) -> f32 {
    let x = (u - 0.5).clamp(0.0, (w - 1) as f32);
    let y = (v - 0.5).clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let at = |i: usize, j: usize| img[j * w + i];
    let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
    let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// The median over `cameras` of a pixel's footprint at `point` (its camera-space depth over
/// the larger focal length, in world units per pixel); 0 without cameras. The footprint of
/// the training images, not of the fusion's, sets how far off rendered depth can be.
pub fn median_pixel_footprint<'a>(
    cameras: impl IntoIterator<Item = &'a Camera>,
    point: Vec3,
) -> f32 {
    let mut f: Vec<f32> = cameras
        .into_iter()
        .map(|c| {
            let z = c.world_to_camera.transform_point3(point).z;
            z.abs() / c.fx.max(c.fy).max(1e-6)
        })
        .filter(|f| f.is_finite())
        .collect();
    f.sort_by(f32::total_cmp);
    f.get(f.len() / 2).copied().unwrap_or(0.0)
}
