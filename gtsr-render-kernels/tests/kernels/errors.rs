use burn::tensor::{DType, Device, Tensor};
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};
use gtsr_render_kernels::{AlphaCutoff, Camera, CameraError, RenderError, render};

#[test]
fn bad_shapes_and_backgrounds_are_rejected_with_clear_errors() {
    let scene = random_scene(1, &RandomSceneSpec::bench(10, 32, 32));
    let device = Device::ndarray();
    let cfg = scene.config(AlphaCutoff::Hard);

    let mut inp = scene.inputs(&device, DType::F32);
    inp.quats = Tensor::zeros([10, 3], &device);
    let err = render(inp, &cfg).unwrap_err();
    assert!(
        matches!(err, RenderError::Shape { name: "quats", .. }),
        "{err}"
    );
    assert!(err.to_string().contains("[N, 4]"), "{err}");

    let mut bad_bg = cfg.clone();
    bad_bg.background = vec![0.0; 2];
    let err = render(scene.inputs(&device, DType::F32), &bad_bg).unwrap_err();
    assert_eq!(
        err,
        RenderError::Background {
            background: 2,
            features: 3
        }
    );

    let mut nan_bg = cfg.clone();
    nan_bg.background[1] = f64::NAN;
    let err = render(scene.inputs(&device, DType::F32), &nan_bg).unwrap_err();
    assert!(matches!(err, RenderError::NonFiniteBackground(_)), "{err}");

    for blur in [-0.1, f64::NAN, f64::INFINITY] {
        let mut bad_blur = cfg.clone();
        bad_blur.blur_px2 = blur;
        let err = render(scene.inputs(&device, DType::F32), &bad_blur).unwrap_err();
        assert!(matches!(err, RenderError::Blur(_)), "{err}");
        assert!(err.to_string().contains("blur_px2"), "{err}");
    }

    let mut inp = scene.inputs(&device, DType::F32);
    inp.features = Tensor::zeros([10, 3], (&device, DType::F64));
    let err = render(inp, &cfg).unwrap_err();
    assert!(matches!(err, RenderError::Mixed(_)), "{err}");
}

#[test]
fn degenerate_cameras_are_rejected() {
    let r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let ok = Camera::new(50.0, 50.0, 16.0, 16.0, 32, 32, r, [0.0; 3], 0.01, 100.0);
    assert!(ok.is_ok());
    let e = Camera::new(0.0, 50.0, 16.0, 16.0, 32, 32, r, [0.0; 3], 0.01, 100.0).unwrap_err();
    assert!(matches!(e, CameraError::BadFocal { .. }));
    let e = Camera::new(50.0, 50.0, f64::NAN, 16.0, 32, 32, r, [0.0; 3], 0.01, 100.0).unwrap_err();
    assert_eq!(e, CameraError::NonFinite("cx"));
    let e = Camera::new(50.0, 50.0, 16.0, 16.0, 0, 32, r, [0.0; 3], 0.01, 100.0).unwrap_err();
    assert!(matches!(e, CameraError::EmptyImage { .. }));
    let sheared = [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let e = Camera::new(
        50.0, 50.0, 16.0, 16.0, 32, 32, sheared, [0.0; 3], 0.01, 100.0,
    )
    .unwrap_err();
    assert!(matches!(e, CameraError::NotRigid { .. }), "{e}");
    let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let e = Camera::new(
        50.0, 50.0, 16.0, 16.0, 32, 32, mirror, [0.0; 3], 0.01, 100.0,
    )
    .unwrap_err();
    assert!(matches!(e, CameraError::NotRigid { .. }), "{e}");
    let e = Camera::new(50.0, 50.0, 16.0, 16.0, 32, 32, r, [0.0; 3], 1.0, 0.5).unwrap_err();
    assert!(matches!(e, CameraError::BadClip { .. }));
}
