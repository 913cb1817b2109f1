//! `cargo xtask exposure`: a copy of a Blender/NeRF-layout scene whose views differ in
//! exposure, as a phone's auto exposure makes them: each image's linear radiance scaled by
//! `2^s`, `s` drawn per view from `[-stops, stops]`, re-encoded as 8-bit sRGB with the mask
//! kept. The stops drawn are written to `exposures.json` beside the images (for diagnosis only:
//! the product reads the exposure from the images).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use gtsr_data::image_io::{Encoding, linear_to_srgb, read_image, srgb_to_linear, write_png_rgba8};

/// Arguments of `cargo xtask exposure`.
#[derive(clap::Args, Debug, Clone)]
pub struct ExposureArgs {
    /// The scene to copy (Blender/NeRF layout with 8-bit PNG images).
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder (created; files with the same names are replaced).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Each view's exposure is drawn uniformly from this many stops either way.
    #[arg(long, default_value_t = 1.0)]
    pub stops: f32,
    /// Seed of the draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// A uniform draw in `[0, 1)` from a seed and an index (SplitMix64).
fn uniform(seed: u64, index: u64) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(index.wrapping_add(1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

fn copy(from: &Path, to: &Path) -> anyhow::Result<()> {
    std::fs::copy(from, to)
        .with_context(|| format!("copying {} to {}", from.display(), to.display()))?;
    Ok(())
}

/// Writes the copy and prints the stops drawn.
pub fn run(args: &ExposureArgs) -> anyhow::Result<()> {
    if !(args.stops >= 0.0 && args.stops.is_finite()) {
        bail!("--stops {} must be a finite number >= 0", args.stops);
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mesh = args.data.join("mesh.ply");
    if mesh.is_file() {
        copy(&mesh, &args.out.join("mesh.ply"))?;
    }
    let mut drawn = serde_json::Map::new();
    let mut index = 0u64;
    for split in ["train", "test"] {
        let name = format!("transforms_{split}.json");
        let path = args.data.join(&name);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let json: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{}: not valid JSON", path.display()))?;
        let frames = json["frames"]
            .as_array()
            .with_context(|| format!("{}: no frames", path.display()))?;
        for frame in frames {
            let rel = frame["file_path"]
                .as_str()
                .with_context(|| format!("{}: a frame without file_path", path.display()))?;
            let file = format!("{rel}.png");
            let from = args.data.join(&file);
            let img = read_image(&from)?;
            if img.encoding != Encoding::Srgb {
                bail!("{}: only 8-bit sRGB images are re-exposed", from.display());
            }
            let s = args.stops * (2.0 * uniform(args.seed, index) as f32 - 1.0);
            index += 1;
            let gain = s.exp2();
            let alpha = img
                .alpha
                .clone()
                .unwrap_or_else(|| vec![1.0; img.rgb.len() / 3]);
            let mut rgba = Vec::with_capacity(alpha.len() * 4);
            for (k, a) in alpha.iter().enumerate() {
                for c in 0..3 {
                    let v = linear_to_srgb(srgb_to_linear(img.rgb[3 * k + c]) * gain);
                    rgba.push((v * 255.0 + 0.5) as u8);
                }
                rgba.push((a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
            }
            let to = args.out.join(&file);
            if let Some(dir) = to.parent() {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
            }
            write_png_rgba8(&to, img.width, img.height, &rgba)?;
            drawn.insert(rel.trim_start_matches("./").to_string(), s.into());
        }
        copy(&path, &args.out.join(&name))?;
    }
    let listing = args.out.join("exposures.json");
    std::fs::write(&listing, serde_json::to_string_pretty(&drawn)?)
        .with_context(|| format!("writing {}", listing.display()))?;
    println!(
        "exposure: {} views of {} re-exposed within +-{} stops -> {} (stops drawn in {})",
        drawn.len(),
        args.data.display(),
        args.stops,
        args.out.display(),
        listing.display()
    );
    Ok(())
}
