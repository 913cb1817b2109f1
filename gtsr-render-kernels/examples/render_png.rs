//! Renders 20,000 random Gaussians and writes a PNG (image | alpha).
//!
//! `cargo run --release -p gtsr-render-kernels --example render_png -- [out.png]` (NdArray);
//! add `--features wgpu` and `wgpu` after the file name for the wgpu backend.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

use burn::tensor::{DType, Device};
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};
use gtsr_render_kernels::{AlphaCutoff, render};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "splat.png".to_string());
    let device = match std::env::args().nth(2).as_deref() {
        #[cfg(feature = "wgpu")]
        Some("wgpu") => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice),
        None | Some("ndarray") => Device::ndarray(),
        Some(other) => {
            return Err(format!(
                "unknown backend {other:?}: ndarray or wgpu (with --features wgpu)"
            )
            .into());
        }
    };
    let mut spec = RandomSceneSpec::bench(20_000, 320, 240);
    spec.scale_range = (0.01, 0.06);
    let mut scene = random_scene(3, &spec);
    // Colour each Gaussian by its position so the picture shows the ball's structure.
    for i in 0..scene.len() {
        for k in 0..3 {
            scene.features[3 * i + k] = 0.5 + 0.5 * scene.means[3 * i + k];
        }
    }
    scene.background = vec![0.05, 0.05, 0.08];
    let t = std::time::Instant::now();
    let out = render(
        scene.inputs(&device, DType::F32),
        &scene.config(AlphaCutoff::Hard),
    )?;
    let [h, w, _] = out.image.dims();
    let image: Vec<f32> = out.image.into_data().try_to_vec()?;
    let alpha: Vec<f32> = out.alpha.into_data().try_to_vec()?;
    println!(
        "rendered {} Gaussians at {w}x{h} on {device:?} in {:.1} ms (first call: includes kernel compilation)",
        scene.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let mut png = image::RgbImage::new(2 * w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let rgb = [
                to8(image[3 * p]),
                to8(image[3 * p + 1]),
                to8(image[3 * p + 2]),
            ];
            png.put_pixel(x as u32, y as u32, image::Rgb(rgb));
            let a = to8(alpha[p]);
            png.put_pixel((w + x) as u32, y as u32, image::Rgb([a, a, a]));
        }
    }
    png.save(&path)?;
    println!("wrote {path} (left: image, right: alpha)");
    Ok(())
}
