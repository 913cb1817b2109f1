use std::process::Command;

use glam::Vec3;
use gtsr_mesh::mesh::icosphere;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_gtsr-eval"))
}

#[test]
fn mesh_subcommand_prints_and_writes_json() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, j) = (
        dir.path().join("a.ply"),
        dir.path().join("b.ply"),
        dir.path().join("m.json"),
    );
    gtsr_data::ply::write_ply(&a, &icosphere(Vec3::ZERO, 1.0, 4)).unwrap();
    gtsr_data::ply::write_ply(&b, &icosphere(Vec3::ZERO, 1.05, 4)).unwrap();
    let out = bin()
        .args(["mesh", "--pred"])
        .arg(&a)
        .arg("--gt")
        .arg(&b)
        .args(["--samples", "5000", "--threshold", "0.1", "--json"])
        .arg(&j)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("chamfer:"), "{text}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&j).unwrap()).unwrap();
    assert!((v["chamfer"].as_f64().unwrap() - 0.05).abs() < 2e-3, "{v}");
    assert_eq!(v["fscore"].as_f64().unwrap(), 1.0);
    // A missing file is named in the error.
    let out = bin()
        .args(["mesh", "--pred", "/nonexistent/x.ply", "--gt"])
        .arg(&b)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/x.ply"));
}

#[test]
fn images_subcommand_compares_folders() {
    let dir = tempfile::tempdir().unwrap();
    let (p, g) = (dir.path().join("pred"), dir.path().join("gt"));
    std::fs::create_dir_all(&p).unwrap();
    std::fs::create_dir_all(&g).unwrap();
    let (w, h) = (16u32, 12u32);
    let gt: Vec<u8> = (0..w * h)
        .flat_map(|i| [(i % 200) as u8, 100, 50, 255])
        .collect();
    // Offset of 51/255 = 0.2 in every channel: PSNR 20 log10(5) = 13.98 dB.
    let pred: Vec<u8> = gt
        .chunks(4)
        .flat_map(|c| [c[0] + 51, c[1] + 51, c[2] + 51, 255])
        .collect();
    gtsr_data::image_io::write_png_rgba8(&g.join("0.png"), w, h, &gt).unwrap();
    gtsr_data::image_io::write_png_rgba8(&p.join("0.png"), w, h, &pred).unwrap();
    let out = bin()
        .args(["images", "--pred"])
        .arg(&p)
        .arg("--gt")
        .arg(&g)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("PSNR 13.979"), "{text}");
    // A prediction missing from the folder is an error naming it.
    gtsr_data::image_io::write_png_rgba8(&g.join("1.png"), w, h, &gt).unwrap();
    let out = bin()
        .args(["images", "--pred"])
        .arg(&p)
        .arg("--gt")
        .arg(&g)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("1.png"));
}

#[test]
fn plot_subcommand_writes_a_png() {
    use gtsr_eval::{Timeline, TimelinePoint};
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("run.csv");
    let mut t = Timeline::new();
    for k in 0..4u64 {
        t.push(TimelinePoint {
            iteration: k * 100,
            train_seconds: k as f64,
            psnr: 20.0 + k as f64,
            ssim: 0.9,
            chamfer: Some(0.01 / (k + 1) as f64),
            depth_only_chamfer: None,
            masks_alone_chamfer: None,
            depth_error: None,
            blind_completeness: None,
            rest_completeness: None,
            masks_alone_blind_completeness: None,
            masks_alone_rest_completeness: None,
            mesh_change: None,
            gaussians: 1000,
            label: "run".into(),
        });
    }
    t.write_csv(&csv).unwrap();
    let png = dir.path().join("p.png");
    let out = bin()
        .args(["plot", "--out"])
        .arg(&png)
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(image::open(&png).unwrap().width(), 1400);
    let out = bin()
        .args(["plot", "--out"])
        .arg(&png)
        .arg(dir.path().join("missing.csv"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.csv"));
}
