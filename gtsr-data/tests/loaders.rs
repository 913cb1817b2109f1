//! Loader tests: the development scenes, layout variants, the camera convention, and every
//! bad-input case with its error.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};
use gtsr_data::camera::{Camera, check_rigid};
use gtsr_data::colmap::{read_cameras, read_images, read_points3d, write_text_model};
use gtsr_data::image_io::write_png_rgba8;
use gtsr_data::{
    Background, DataError, Downscale, Encoding, LoadOptions, NormaliseFrom, load_blender,
    load_colmap,
};

fn shared_data() -> PathBuf {
    // Read at run time: a test binary reused from a shared target directory may have been
    // compiled in another checkout, so the compile-time path can be stale.
    let manifest = std::env::var("CARGO_MANIFEST_DIR")
        .unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").to_string());
    let p = PathBuf::from(manifest).join("../../shared/data");
    assert!(
        p.join("wax_knot").is_dir() && p.join("amber_ingot").is_dir(),
        "development data not found at {} (the shared/ folder beside the checkout; present in CI)",
        p.display()
    );
    p
}

// ---------------------------------------------------------------- development data

#[test]
fn development_scenes_load() {
    let root = shared_data();
    for name in ["wax_knot", "amber_ingot"] {
        let t = std::time::Instant::now();
        let scene = load_blender(root.join(name), &LoadOptions::default()).unwrap();
        let secs = t.elapsed().as_secs_f64();
        assert_eq!(scene.train.len(), 80, "{name}");
        assert_eq!(scene.test.len(), 16, "{name}");
        assert!(scene.mesh_path.as_ref().unwrap().is_file());
        for v in scene.all_views() {
            assert_eq!((v.width(), v.height()), (256, 256));
            assert_eq!(v.rgb.len(), 256 * 256 * 3);
            assert_eq!(v.encoding, Encoding::Srgb);
            let m = v.mask.as_ref().expect("RGBA images carry a mask");
            let cover = m.iter().filter(|&&a| a > 0.5).count();
            assert!(
                cover > 500 && cover < 256 * 256 / 2,
                "{name} {}: coverage {cover}",
                v.name
            );
            // Cameras at distance 4 looking at the origin, fov 0.6911.
            assert!((v.camera.centre().length() - 4.0).abs() < 1e-3);
            assert!(v.camera.forward().dot(-v.camera.centre().normalize()) > 0.999);
            assert!((v.camera.fov_x() - 0.6911).abs() < 1e-3);
            // The object (at the origin) projects near the image centre.
            let (uv, z) = v.camera.project(Vec3::ZERO).unwrap();
            assert!((uv - glam::Vec2::splat(128.0)).length() < 1e-2 && (z - 4.0).abs() < 1e-3);
            // Composited onto black: outside the mask the colour is 0.
            let k = m.iter().position(|&a| a == 0.0).unwrap();
            assert_eq!(&v.rgb[3 * k..3 * k + 3], &[0.0, 0.0, 0.0]);
        }
        // Loading is fast (target: a 100-view 256x256 scene in 2 s; generous bound here).
        assert!(secs < 20.0, "{name} took {secs} s");
        // Camera normalisation: the axes meet at the origin.
        assert!(scene.normalisation.centre.length() < 1e-3);
        let n = gtsr_data::scene::normalisation_from_masks(&scene.train, &scene.root).unwrap();
        assert!(n.centre.length() < 0.15, "{name}: hull centre {}", n.centre);
        assert!(
            (n.radius - 1.0).abs() < 0.2,
            "{name}: hull radius {}",
            n.radius
        );
        let mesh = gtsr_data::ply::read_ply(scene.mesh_path.as_ref().unwrap()).unwrap();
        let r = mesh
            .positions
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max);
        assert!((r - 1.0).abs() < 0.02, "{name}: mesh radius {r}");
        assert!(mesh.volume() > 0.0);
    }
}

#[test]
fn mask_normalisation_and_apply() {
    let root = shared_data().join("wax_knot");
    let opts = LoadOptions {
        normalise_from: NormaliseFrom::Masks,
        apply_normalisation: true,
        downscale: Downscale::Factor(4),
        ..LoadOptions::default()
    };
    let scene = load_blender(&root, &opts).unwrap();
    assert!(scene.normalisation_applied);
    assert!((scene.normalisation.radius - 1.0).abs() < 0.2);
    let v = &scene.train[0];
    assert_eq!((v.width(), v.height()), (64, 64));
    // After normalisation the camera distance is 4 / radius.
    let d = v.camera.centre().length() * scene.normalisation.radius;
    assert!((d - 4.0).abs() < 0.2 * 4.0, "{d}");
    check_rigid(&Mat4::from(v.camera.world_to_camera)).unwrap();
}

// ---------------------------------------------------------------- camera convention

#[test]
fn camera_convention() {
    // Blender camera at +z looking down -z (identity rotation, OpenGL).
    let c2w = Mat4::from_translation(Vec3::new(0.0, 0.0, 4.0));
    let cam = Camera::from_opengl_camera_to_world(c2w, 100.0, 100.0, 50.0, 40.0, 100, 80);
    assert!((cam.centre() - Vec3::new(0.0, 0.0, 4.0)).length() < 1e-6);
    assert!((cam.forward() - Vec3::NEG_Z).length() < 1e-6);
    // World +x is image right, world +y (OpenGL up) is image up = smaller row index.
    let (uv, z) = cam.project(Vec3::new(0.4, 0.0, 0.0)).unwrap();
    assert!((z - 4.0).abs() < 1e-6 && (uv.x - 60.0).abs() < 1e-4 && (uv.y - 40.0).abs() < 1e-4);
    let (uv, _) = cam.project(Vec3::new(0.0, 0.4, 0.0)).unwrap();
    assert!((uv.y - 30.0).abs() < 1e-4);
    // Ray through a pixel centre re-projects onto it.
    let (o, d) = cam.pixel_ray(7, 9);
    let (uv, _) = cam.project(o + d * 3.0).unwrap();
    assert!((uv - glam::Vec2::new(7.5, 9.5)).length() < 1e-3);
    // Round trip of the OpenGL matrix.
    assert!(cam.opengl_camera_to_world().abs_diff_eq(c2w, 1e-6));
    // Downscaling keeps projections consistent.
    let half = cam.downscaled(2);
    let (a, _) = cam.project(Vec3::new(0.3, -0.2, 0.1)).unwrap();
    let (b, _) = half.project(Vec3::new(0.3, -0.2, 0.1)).unwrap();
    assert!((a / 2.0 - b).length() < 1e-4);
    assert_eq!((half.width, half.height), (50, 40));
    // look_at: +z up appears up in the image.
    let la = Camera::look_at(Vec3::new(4.0, 0.0, 0.0), Vec3::ZERO, Vec3::Z, 0.7, 64, 64);
    let (up, _) = la.project(Vec3::new(0.0, 0.0, 0.5)).unwrap();
    assert!(up.y < 32.0);
    check_rigid(&Mat4::from(la.world_to_camera)).unwrap();
}

// ---------------------------------------------------------------- helpers for fixtures

fn write_rgba(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) {
    let mut buf = Vec::new();
    for j in 0..h {
        for i in 0..w {
            buf.extend(f(i, j));
        }
    }
    write_png_rgba8(path, w, h, &buf).unwrap();
}

fn write_rgb(path: &Path, w: u32, h: u32, v: u8) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_pixel(w, h, image::Rgb([v, v / 2, 10]))
        .save(path)
        .unwrap();
}

fn gl_matrix(eye: Vec3) -> [[f32; 4]; 4] {
    let cam = Camera::look_at(eye, Vec3::ZERO, Vec3::Z, 0.7, 8, 8);
    cam.opengl_camera_to_world().transpose().to_cols_array_2d()
}

/// A valid two-frame Blender scene with 8x8 RGBA images.
fn blender_fixture(dir: &Path) {
    for k in 0..2 {
        write_rgba(&dir.join(format!("train/r_{k}.png")), 8, 8, |i, _| {
            [200, 100, 50, if i < 4 { 255 } else { 0 }]
        });
    }
    write_json(dir, "train", &frames_json(2, None));
}

fn frames_json(n: usize, ext: Option<&str>) -> serde_json::Value {
    let frames: Vec<_> = (0..n)
        .map(|k| {
            serde_json::json!({
                "file_path": format!("./train/r_{k}{}", ext.unwrap_or("")),
                "transform_matrix": gl_matrix(Vec3::new(4.0, k as f32, 1.0)),
            })
        })
        .collect();
    serde_json::json!({ "camera_angle_x": 0.7, "frames": frames })
}

fn write_json(dir: &Path, split: &str, v: &serde_json::Value) {
    std::fs::write(
        dir.join(format!("transforms_{split}.json")),
        serde_json::to_string_pretty(v).unwrap(),
    )
    .unwrap();
}

fn err_text(e: &DataError) -> String {
    e.to_string()
}

// ---------------------------------------------------------------- Blender variants

#[test]
fn blender_variants_and_backgrounds() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blender_fixture(dir);
    let black = load_blender(dir, &LoadOptions::default()).unwrap();
    assert_eq!(black.train.len(), 2);
    assert!(black.test.is_empty());
    let v = &black.train[0];
    assert!((v.camera.fx - 4.0 / (0.35f32).tan()).abs() < 1e-3);
    assert_eq!(v.mask.as_ref().unwrap()[0], 1.0);
    assert_eq!(v.mask.as_ref().unwrap()[7], 0.0);
    assert!((v.rgb[0] - 200.0 / 255.0).abs() < 1e-6);
    assert_eq!(&v.rgb[21..24], &[0.0, 0.0, 0.0]);
    let white = load_blender(
        dir,
        &LoadOptions {
            background: Background::White,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(&white.train[0].rgb[21..24], &[1.0, 1.0, 1.0]);
    let keep = load_blender(
        dir,
        &LoadOptions {
            background: Background::Keep,
            ..Default::default()
        },
    )
    .unwrap();
    assert!((keep.train[0].rgb[21] - 200.0 / 255.0).abs() < 1e-6);
    let rnd = |seed| {
        load_blender(
            dir,
            &LoadOptions {
                background: Background::Random { seed },
                ..Default::default()
            },
        )
        .unwrap()
        .train[0]
            .rgb
            .clone()
    };
    let (a, b, c) = (rnd(1), rnd(1), rnd(2));
    assert_eq!(a, b, "random background is deterministic for a seed");
    assert_ne!(a, c);
    assert_eq!(
        &a[..12],
        &black.train[0].rgb[..12],
        "opaque pixels unchanged"
    );

    // Explicit intrinsics, file_path with extension, downscale to a maximum side.
    let mut j = frames_json(2, Some(".png"));
    let o = j.as_object_mut().unwrap();
    o.remove("camera_angle_x");
    for (k, v) in [
        ("fl_x", 10.0),
        ("fl_y", 11.0),
        ("cx", 3.0),
        ("cy", 5.0),
        ("w", 8.0),
        ("h", 8.0),
    ] {
        o.insert(k.into(), serde_json::json!(v));
    }
    write_json(dir, "train", &j);
    let s = load_blender(
        dir,
        &LoadOptions {
            downscale: Downscale::MaxSide(4),
            ..Default::default()
        },
    )
    .unwrap();
    let c = s.train[0].camera;
    assert_eq!(
        (c.width, c.height, c.fx, c.fy, c.cx, c.cy),
        (4, 4, 5.0, 5.5, 1.5, 2.5)
    );
    assert_eq!(s.train[0].rgb.len(), 4 * 4 * 3);
    assert_eq!(s.train[0].mask.as_ref().unwrap()[..4], [1.0, 1.0, 0.0, 0.0]);
}

#[test]
fn blender_rgb_with_mask_folder_and_exr() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_rgb(&dir.join("train/r_0.jpg"), 8, 8, 240);
    std::fs::create_dir_all(dir.join("masks/train")).unwrap();
    image::GrayImage::from_fn(8, 8, |i, _| image::Luma([if i < 2 { 255 } else { 0 }]))
        .save(dir.join("masks/train/r_0.png"))
        .unwrap();
    // An EXR frame (linear float RGB).
    let exr = image::Rgb32FImage::from_pixel(8, 8, image::Rgb([2.5f32, 0.5, 0.25]));
    image::DynamicImage::ImageRgb32F(exr)
        .save(dir.join("train/r_1.exr"))
        .unwrap();
    write_json(dir, "train", &frames_json(2, None));
    let s = load_blender(dir, &LoadOptions::default()).unwrap();
    let v = &s.train[0];
    assert_eq!(v.encoding, Encoding::Srgb);
    let m = v.mask.as_ref().unwrap();
    assert_eq!((m[0], m[1], m[2]), (1.0, 1.0, 0.0));
    assert_eq!(&v.rgb[6..9], &[0.0, 0.0, 0.0], "masked out -> black");
    let e = &s.train[1];
    assert_eq!(e.encoding, Encoding::Linear);
    assert!(e.mask.is_none());
    assert!((e.rgb[0] - 2.5).abs() < 1e-3 && (e.rgb[2] - 0.25).abs() < 1e-3);
}

// ---------------------------------------------------------------- Blender bad input

#[test]
fn missing_image_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    blender_fixture(tmp.path());
    std::fs::remove_file(tmp.path().join("train/r_1.png")).unwrap();
    let e = load_blender(tmp.path(), &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DataError::MissingImage { frame: 1, .. }),
        "{e:?}"
    );
    let t = err_text(&e);
    assert!(
        t.contains("transforms_train.json") && t.contains("frame 1") && t.contains("r_1.png"),
        "{t}"
    );
}

#[test]
fn size_mismatch_between_frames_and_intrinsics() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blender_fixture(dir);
    // Second frame has another size than the first.
    write_rgba(&dir.join("train/r_1.png"), 6, 8, |_, _| [0, 0, 0, 255]);
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            DataError::SizeMismatch {
                frame: 1,
                got_w: 6,
                want_w: 8,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(err_text(&e).contains("r_1.png") && err_text(&e).contains("6x8"));
    // Intrinsics say 16x16.
    blender_fixture(dir);
    let mut j = frames_json(2, None);
    j["w"] = serde_json::json!(16);
    j["h"] = serde_json::json!(16);
    write_json(dir, "train", &j);
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            DataError::SizeMismatch {
                want_w: 16,
                want_h: 16,
                ..
            }
        ),
        "{e:?}"
    );
}

#[test]
fn malformed_json_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blender_fixture(dir);
    std::fs::write(
        dir.join("transforms_train.json"),
        "{ \"camera_angle_x\": 0.7, \"frames\": [ {",
    )
    .unwrap();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::MalformedJson { .. }), "{e:?}");
    assert!(err_text(&e).contains("transforms_train.json") && err_text(&e).contains("line"));
    // Missing field.
    std::fs::write(
        dir.join("transforms_train.json"),
        "{ \"camera_angle_x\": 0.7 }",
    )
    .unwrap();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(err_text(&e).contains("frames"), "{e}");
    // No focal length.
    std::fs::write(
        dir.join("transforms_train.json"),
        serde_json::to_string(&serde_json::json!({"frames": frames_json(1, None)["frames"]}))
            .unwrap(),
    )
    .unwrap();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(err_text(&e).contains("camera_angle_x"), "{e}");
}

#[test]
fn non_rigid_matrix_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blender_fixture(dir);
    for (what, bad) in [
        ("scaled", Mat4::from_scale(Vec3::splat(1.1))),
        ("reflected", Mat4::from_scale(Vec3::new(1.0, 1.0, -1.0))),
        (
            "sheared",
            Mat4::from_cols_array(&[
                1.0, 0.0, 0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ]),
        ),
    ] {
        let mut j = frames_json(2, None);
        j["frames"][1]["transform_matrix"] = serde_json::json!(bad.transpose().to_cols_array_2d());
        write_json(dir, "train", &j);
        let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
        assert!(
            matches!(e, DataError::NonRigid { frame: 1, .. }),
            "{what}: {e:?}"
        );
        assert!(err_text(&e).contains("transforms_train.json") && err_text(&e).contains("frame 1"));
    }
    let mut j = frames_json(1, None);
    j["frames"][0]["transform_matrix"][0][0] = serde_json::json!(null);
    write_json(dir, "train", &j);
    assert!(matches!(
        load_blender(dir, &LoadOptions::default()).unwrap_err(),
        DataError::MalformedJson { .. }
    ));
}

#[test]
fn empty_split_and_missing_transforms() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DataError::MissingFile { .. })
            && err_text(&e).contains("transforms_train.json")
    );
    blender_fixture(dir);
    write_json(
        dir,
        "test",
        &serde_json::json!({"camera_angle_x": 0.7, "frames": []}),
    );
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::EmptySplit { .. }), "{e:?}");
    assert!(err_text(&e).contains("transforms_test.json") && err_text(&e).contains("'test'"));
}

#[test]
fn corrupt_image_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blender_fixture(dir);
    let p = dir.join("train/r_0.png");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::Decode { .. }), "{e:?}");
    assert!(err_text(&e).contains("r_0.png"));
    std::fs::write(&p, b"this is not an image").unwrap();
    let e = load_blender(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::Decode { .. }), "{e:?}");
}

// ---------------------------------------------------------------- COLMAP

fn colmap_views() -> Vec<(String, Camera)> {
    (0..5)
        .map(|k| {
            let a = k as f32 * 0.7;
            let mut c = Camera::look_at(
                Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.5),
                Vec3::new(0.1, 0.0, 0.0),
                Vec3::Z,
                0.8,
                12,
                10,
            );
            c.fy = c.fx * 1.01;
            c.cx = 6.2;
            (format!("img_{k}.png"), c)
        })
        .collect()
}

fn colmap_fixture(dir: &Path) -> Vec<(String, Camera)> {
    let views = colmap_views();
    let model = dir.join("sparse/0");
    std::fs::create_dir_all(&model).unwrap();
    let pts = vec![
        (Vec3::new(0.1, 0.2, 0.3), [1, 2, 3]),
        (Vec3::new(-0.5, 0.0, 0.25), [200, 100, 0]),
    ];
    write_text_model(&model, &views, &pts).unwrap();
    for (name, c) in &views {
        write_rgb(&dir.join("images").join(name), c.width, c.height, 100);
    }
    views
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend(v.to_le_bytes());
}
fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend(v.to_le_bytes());
}
fn put_f64(b: &mut Vec<u8>, v: f64) {
    b.extend(v.to_le_bytes());
}

/// Writes the binary model equivalent of the text one (from the text readers' output).
fn write_bin_model(model: &Path) {
    let cams = read_cameras(&model.join("cameras.txt")).unwrap();
    let imgs = read_images(&model.join("images.txt")).unwrap();
    let pts = read_points3d(&model.join("points3D.txt")).unwrap();
    let mut b = Vec::new();
    put_u64(&mut b, cams.len() as u64);
    for c in &cams {
        put_u32(&mut b, c.id);
        let id = gtsr_data::colmap::CAMERA_MODELS
            .iter()
            .find(|m| m.1 == c.model)
            .unwrap()
            .0;
        b.extend(id.to_le_bytes());
        put_u64(&mut b, c.width);
        put_u64(&mut b, c.height);
        c.params.iter().for_each(|&p| put_f64(&mut b, p));
    }
    std::fs::write(model.join("cameras.bin"), &b).unwrap();
    let mut b = Vec::new();
    put_u64(&mut b, imgs.len() as u64);
    for i in &imgs {
        put_u32(&mut b, i.id);
        i.qvec
            .iter()
            .chain(i.tvec.iter())
            .for_each(|&v| put_f64(&mut b, v));
        put_u32(&mut b, i.camera_id);
        b.extend(i.name.as_bytes());
        b.push(0);
        put_u64(&mut b, 1); // one 2D point
        put_f64(&mut b, 1.0);
        put_f64(&mut b, 2.0);
        b.extend((-1i64).to_le_bytes());
    }
    std::fs::write(model.join("images.bin"), &b).unwrap();
    let mut b = Vec::new();
    put_u64(&mut b, pts.len() as u64);
    for p in &pts {
        put_u64(&mut b, p.id);
        p.xyz.iter().for_each(|&v| put_f64(&mut b, v));
        b.extend(p.rgb);
        put_f64(&mut b, p.error);
        put_u64(&mut b, 2);
        for _ in 0..2 {
            b.extend(1i32.to_le_bytes());
            b.extend(0i32.to_le_bytes());
        }
    }
    std::fs::write(model.join("points3D.bin"), &b).unwrap();
}

#[test]
fn colmap_text_and_binary_round_trip() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let views = colmap_fixture(dir);
    let opts = LoadOptions {
        colmap_test_every: Some(4),
        ..Default::default()
    };
    let txt = load_colmap(dir, &opts).unwrap();
    assert_eq!((txt.train.len(), txt.test.len()), (3, 2));
    assert_eq!(txt.points.len(), 2);
    assert_eq!(txt.point_colors[1], [200, 100, 0]);
    // Names sorted; img_0 and img_4 are test views.
    assert_eq!(txt.test[0].name, "img_0.png");
    for v in txt.all_views() {
        let (_, c) = views.iter().find(|(n, _)| *n == v.name).unwrap();
        assert!((v.camera.centre() - c.centre()).length() < 1e-4);
        assert!((v.camera.fy - c.fy).abs() < 1e-3 && (v.camera.cx - 6.2).abs() < 1e-5);
        let p = Vec3::new(0.2, -0.1, 0.3);
        let (a, _) = v.camera.project(p).unwrap();
        let (b, _) = c.project(p).unwrap();
        assert!((a - b).length() < 1e-3);
        assert!(v.mask.is_none());
    }
    // Binary model takes precedence and gives the same cameras.
    write_bin_model(&dir.join("sparse/0"));
    let bin = load_colmap(dir, &opts).unwrap();
    for (a, b) in txt.all_views().zip(bin.all_views()) {
        assert_eq!(a.name, b.name);
        assert!(
            a.camera
                .world_to_camera
                .abs_diff_eq(b.camera.world_to_camera, 1e-6)
        );
        assert_eq!((a.camera.fx, a.camera.cy), (b.camera.fx, b.camera.cy));
    }
    assert_eq!(bin.points, txt.points);
    // Masks folder.
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    for (name, c) in &views {
        image::GrayImage::from_pixel(c.width, c.height, image::Luma([255]))
            .save(dir.join("masks").join(format!("{name}.png")))
            .unwrap();
    }
    let masked = load_colmap(dir, &opts).unwrap();
    assert!(
        masked
            .all_views()
            .all(|v| v.mask.as_ref().is_some_and(|m| m.iter().all(|&a| a == 1.0)))
    );
}

#[test]
fn colmap_radial_model_needs_undistortion() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    colmap_fixture(dir);
    let cams = dir.join("sparse/0/cameras.txt");
    // Zero distortion loads as a pinhole.
    std::fs::write(&cams, "1 SIMPLE_RADIAL 12 10 9.0 6.0 5.0 0.0\n2 PINHOLE 12 10 9 9 6 5\n3 SIMPLE_PINHOLE 12 10 9 6 5\n4 OPENCV 12 10 9 9 6 5 0 0 0 0\n5 RADIAL 12 10 9 6 5 0 0\n").unwrap();
    let s = load_colmap(dir, &LoadOptions::default()).unwrap();
    assert_eq!(s.train.len() + s.test.len(), 5);
    std::fs::write(&cams, "1 SIMPLE_RADIAL 12 10 9.0 6.0 5.0 0.01\n2 PINHOLE 12 10 9 9 6 5\n3 SIMPLE_PINHOLE 12 10 9 6 5\n4 PINHOLE 12 10 9 9 6 5\n5 PINHOLE 12 10 9 9 6 5\n").unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DataError::UnsupportedCamera { camera_id: 1, .. }),
        "{e:?}"
    );
    let t = err_text(&e);
    assert!(
        t.contains("cameras.txt") && t.contains("SIMPLE_RADIAL") && t.contains("undistort"),
        "{t}"
    );
    std::fs::write(&cams, "1 OPENCV_FISHEYE 12 10 9 9 6 5 0 0 0 0\n2 PINHOLE 12 10 9 9 6 5\n3 SIMPLE_PINHOLE 12 10 9 6 5\n4 PINHOLE 12 10 9 9 6 5\n5 PINHOLE 12 10 9 9 6 5\n").unwrap();
    assert!(matches!(
        load_colmap(dir, &LoadOptions::default()).unwrap_err(),
        DataError::UnsupportedCamera { .. }
    ));
}

#[test]
fn colmap_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    colmap_fixture(dir);
    // Missing image.
    std::fs::remove_file(dir.join("images/img_2.png")).unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DataError::MissingImage { frame: 3, .. }),
        "{e:?}"
    );
    assert!(err_text(&e).contains("img_2.png") && err_text(&e).contains("images.txt"));
    // Size mismatch between image and intrinsics.
    write_rgb(&dir.join("images/img_2.png"), 13, 10, 1);
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            DataError::SizeMismatch {
                got_w: 13,
                want_w: 12,
                ..
            }
        ),
        "{e:?}"
    );
    write_rgb(&dir.join("images/img_2.png"), 12, 10, 1);
    // Truncated binary model.
    write_bin_model(&dir.join("sparse/0"));
    let p = dir.join("sparse/0/images.bin");
    let b = std::fs::read(&p).unwrap();
    std::fs::write(&p, &b[..b.len() - 30]).unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        matches!(e, DataError::Malformed { .. }) && err_text(&e).contains("images.bin"),
        "{e:?}"
    );
    std::fs::remove_file(&p).unwrap();
    std::fs::remove_file(dir.join("sparse/0/cameras.bin")).unwrap();
    std::fs::remove_file(dir.join("sparse/0/points3D.bin")).unwrap();
    // Malformed text line.
    let t = dir.join("sparse/0/images.txt");
    let good = std::fs::read_to_string(&t).unwrap();
    std::fs::write(&t, good.replacen("1 ", "1 x", 1)).unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(
        err_text(&e).contains("images.txt") && err_text(&e).contains("line"),
        "{e}"
    );
    // Non-unit quaternion.
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    let k = lines.iter().position(|l| l.starts_with("2 ")).unwrap();
    let mut f: Vec<String> = lines[k].split(' ').map(String::from).collect();
    f[1] = "3.0".into();
    lines[k] = f.join(" ");
    std::fs::write(&t, lines.join("\n")).unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::NonRigid { frame: 2, .. }), "{e:?}");
    // Empty model.
    std::fs::write(&t, "# no images\n").unwrap();
    let e = load_colmap(dir, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::EmptySplit { .. }), "{e:?}");
    // No model at all.
    let e = load_colmap(tmp.path().join("sparse/0/nothing"), &LoadOptions::default()).unwrap_err();
    assert!(matches!(e, DataError::MissingFile { .. }));
}
