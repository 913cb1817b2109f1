//! The binary end to end on a tiny generated scene, and its answers to bad input.

use std::path::Path;
use std::process::{Command, Output};

use gtsr_data::synthetic::{MaterialPreset, SceneConfig, ShapeKind, generate_scene};

/// The tiny run's schedule: every call on one run passes it (so `--resume` finds it finished).
const TINY_RUN: [&str; 4] = ["--iterations", "40", "--resolution", "24"];

/// Runs gtsr-train on `data` with outputs in `out`, plus `args`.
fn gtsr_train(data: &Path, out: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gtsr-train"))
        .arg("--data")
        .arg(data)
        .arg("--out")
        .arg(out)
        .args(args)
        .output()
        .expect("running gtsr-train")
}

fn tiny_scene(dir: &Path) {
    let mut c = SceneConfig::new(ShapeKind::Sphere, MaterialPreset::Wax);
    c.resolution = 24;
    c.n_train = 12;
    c.n_test = 2;
    c.spp = 4;
    c.seed = 3;
    generate_scene(dir, &c, |_| {}).expect("generating the tiny scene");
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn trains_a_tiny_scene_and_writes_every_output() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene");
    tiny_scene(&scene);
    let out = tmp.path().join("out");
    let o = gtsr_train(
        &scene,
        &out,
        &[
            &TINY_RUN[..],
            &["--eval-points", "2", "--checkpoint-every", "0"],
        ]
        .concat(),
    );
    assert!(o.status.success(), "{}", text(&o));
    for f in [
        "mesh.ply",
        "gaussians.ply",
        "metrics.json",
        "config.json",
        "error_vs_time.csv",
        "error_vs_time.png",
        "checkpoint.safetensors",
        "renders/test_000.png",
        "renders/test_001.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing\n{}", text(&o));
    }
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["iterations"], 40);
    let psnr = m["test_psnr"].as_f64().unwrap();
    assert!(psnr.is_finite() && psnr > 5.0, "{m}");
    let chamfer = m["mesh"]["chamfer"].as_f64().unwrap();
    assert!(chamfer.is_finite() && chamfer > 0.0, "{m}");
    // The masks alone are scored beside the mesh, and both split by what the masks miss.
    let masks = m["masks_alone"]["chamfer"].as_f64().unwrap();
    assert!(masks.is_finite() && masks > 0.0, "{m}");
    let blind = &m["mesh"]["hull_blind"];
    assert!(blind["fraction"].as_f64().unwrap() >= 0.0, "{m}");
    assert!(blind["rest"].as_f64().unwrap() > 0.0, "{m}");
    // Every view has a mask, so the surface set starts inside them and the mask term is on.
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(c["train"]["init"], "mask-carved", "{c}");
    assert_eq!(c["train"]["weights"]["mask"], 1.0, "{c}");
    // The mesh is not empty.
    let mesh = gtsr_data::ply::read_ply(&out.join("mesh.ply")).unwrap();
    assert!(!mesh.triangles.is_empty());

    // The run's config.json alone (no --resolution, no --iterations) reproduces the run.
    let again = tmp.path().join("again");
    let o = gtsr_train(
        &scene,
        &again,
        &[
            "--config",
            out.join("config.json").to_str().unwrap(),
            "--eval-points",
            "2",
            "--checkpoint-every",
            "0",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let c2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(again.join("config.json")).unwrap()).unwrap();
    assert_eq!(c2["resolution"], 24, "{c2}");
    assert_eq!(c2["train"], c["train"]);
    let m2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(again.join("metrics.json")).unwrap())
            .unwrap();
    for key in ["test_psnr", "test_ssim", "surface_gaussians", "mesh"] {
        assert_eq!(
            m2[key], m[key],
            "{key} differs when the run is repeated from its config"
        );
    }

    // --resume on a finished run re-extracts and re-evaluates without training further.
    let o = gtsr_train(&scene, &out, &[&TINY_RUN[..], &["--resume"]].concat());
    assert!(o.status.success(), "{}", text(&o));
    // Another step count cannot resume the run: its schedule was laid out for 40.
    let o = gtsr_train(
        &scene,
        &out,
        &["--iterations", "41", "--resolution", "24", "--resume"],
    );
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("--iterations 41 with --resume") && text(&o).contains("40 steps"),
        "{}",
        text(&o)
    );
    // And with the other depth and fusion options.
    let o = gtsr_train(
        &scene,
        &out,
        &[
            &TINY_RUN[..],
            &[
                "--resume",
                "--fusion",
                "tsdf",
                "--depth-crossing",
                "0.9",
                "--depth-consistency",
                "2",
                "--snap-to-hull",
                "2",
                "--truncation",
                "0.2",
            ],
        ]
        .concat(),
    );
    assert!(o.status.success(), "{}", text(&o));
    let log = text(&o);
    assert!(log.contains("depth consistency (2 of 8"), "{log}");
    assert!(
        log.contains("snapped to the hull (within 2 footprints)"),
        "{log}"
    );
    let mesh = gtsr_data::ply::read_ply(&out.join("mesh.ply")).unwrap();
    assert!(!mesh.triangles.is_empty());
}

#[test]
fn bad_input_is_an_error_naming_the_problem() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let missing = tmp.path().join("no-such-scene");
    let o = gtsr_train(&missing, &out, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no-such-scene"), "{err}");

    // A transforms file that is not JSON.
    let bad = tmp.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("transforms_train.json"), "{ not json").unwrap();
    std::fs::write(bad.join("transforms_test.json"), "{ not json").unwrap();
    let o = gtsr_train(&bad, &out, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("transforms_"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    // An unknown preset and zero iterations, on a good scene.
    let scene = tmp.path().join("scene");
    tiny_scene(&scene);
    // And mesh settings out of range.
    for (flag, value, word) in [
        ("--preset", "nope", "nope"),
        ("--iterations", "0", "iterations"),
        ("--depth-crossing", "1.5", "--depth-crossing"),
        ("--depth-consistency", "0", "--depth-consistency"),
        ("--depth-consistency", "9", "--depth-consistency"),
        ("--snap-to-hull", "-1", "--snap-to-hull"),
        ("--snap-to-hull", "NaN", "--snap-to-hull"),
        ("--snap-to-hull", "2", "--fusion tsdf"),
        ("--carve-margin", "-1", "--carve-margin"),
        ("--carve-views", "0", "--carve-views"),
    ] {
        let o = gtsr_train(&scene, &out, &[flag, value]);
        assert_eq!(o.status.code(), Some(1), "{}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(word), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}
