//! Loads a scene (Blender/NeRF or COLMAP layout) and prints a summary, with what its images
//! say about the light ([`gtsr_data::light`]).
//!
//! `cargo run --release -p gtsr-data --example scene_summary -- <scene folder>`
//! (defaults to the development scene `../shared/data/wax_knot`).

use gtsr_data::{LoadOptions, NormaliseFrom, load_scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = std::env::args().nth(1).unwrap_or_else(|| {
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/wax_knot").to_string()
    });
    let t = std::time::Instant::now();
    let opts = LoadOptions {
        normalise_from: NormaliseFrom::Cameras,
        ..LoadOptions::default()
    };
    let scene = load_scene(&root, &opts)?;
    println!(
        "{} loaded in {:.2} s",
        scene.root.display(),
        t.elapsed().as_secs_f64()
    );
    for (split, views) in [
        ("train", &scene.train),
        ("val", &scene.val),
        ("test", &scene.test),
    ] {
        let Some(v) = views.first() else { continue };
        let masked = views.iter().filter(|v| v.mask.is_some()).count();
        let c = &v.camera;
        println!(
            "  {split}: {} views, {}x{}, fx {:.1} fy {:.1} cx {:.1} cy {:.1}, {:?}, {masked} with masks",
            views.len(),
            c.width,
            c.height,
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            v.encoding
        );
        let d: Vec<f32> = views.iter().map(|v| v.camera.centre().length()).collect();
        let (lo, hi) = d
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        println!("    camera distance from the world origin: {lo:.3} .. {hi:.3}");
    }
    let n = scene.normalisation;
    println!(
        "  normalisation from cameras: centre {:.4} radius {:.4}",
        n.centre, n.radius
    );
    if !scene.train.iter().any(|v| v.mask.is_none()) {
        let m = gtsr_data::scene::normalisation_from_masks(&scene.train, &scene.root)?;
        println!(
            "  normalisation from masks (visual hull): centre {:.4} radius {:.4}",
            m.centre, m.radius
        );
    }
    if let Some(p) = &scene.mesh_path {
        let mesh = gtsr_data::ply::read_ply(p)?;
        let (lo, hi) = mesh.bounds();
        println!(
            "  mesh {}: {} vertices, {} triangles, bounds {lo:.3} .. {hi:.3}",
            p.display(),
            mesh.positions.len(),
            mesh.triangles.len()
        );
    }
    if !scene.points.is_empty() {
        println!("  {} sparse points", scene.points.len());
    }
    let t = std::time::Instant::now();
    let settings = gtsr_data::light::LightSettings::default();
    match gtsr_data::light::read_views(&scene.train.iter().collect::<Vec<_>>(), &settings) {
        Some(gtsr_data::light::Reading {
            light: e,
            exposure_stops,
        }) => println!(
            "  light {} ({:.2} s): {}\n  exposure per view (stops): {}",
            if e.follows_camera() {
                "at the camera"
            } else {
                "not at the camera"
            },
            t.elapsed().as_secs_f64(),
            e.describe(),
            exposure_stops
                .iter()
                .map(|s| format!("{s:+.2}"))
                .collect::<Vec<_>>()
                .join(" ")
        ),
        None => println!("  light: cannot be read (no masks, or too few points seen)"),
    }
    Ok(())
}
