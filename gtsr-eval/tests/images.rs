use gtsr_eval::{EvalError, ImageRef, psnr, ssim};
use gtsr_mesh::MeshError;
use gtsr_mesh::mesh::SplitMix64;

fn random_image(w: usize, h: usize, c: usize, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    (0..w * h * c).map(|_| rng.next_f64() as f32).collect()
}

/// Direct 2-D SSIM (11x11 window, zero padding) as 3DGS computes it, for comparison.
fn reference_ssim(a: &[f32], b: &[f32], w: usize, h: usize, c: usize) -> f64 {
    let g: Vec<f64> = (0..11)
        .map(|k| (-((k as f64 - 5.0).powi(2)) / 4.5).exp())
        .collect();
    let s: f64 = g.iter().sum();
    let mut total = 0.0;
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                let (mut ma, mut mb, mut aa, mut bb, mut ab) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for dy in 0..11 {
                    for dx in 0..11 {
                        let (xx, yy) = (x as isize + dx as isize - 5, y as isize + dy as isize - 5);
                        if xx < 0 || yy < 0 || xx >= w as isize || yy >= h as isize {
                            continue;
                        }
                        let wgt = g[dx] * g[dy] / (s * s);
                        let i = (yy as usize * w + xx as usize) * c + ch;
                        let (va, vb) = (a[i] as f64, b[i] as f64);
                        ma += wgt * va;
                        mb += wgt * vb;
                        aa += wgt * va * va;
                        bb += wgt * vb * vb;
                        ab += wgt * va * vb;
                    }
                }
                let (c1, c2) = (1e-4, 9e-4);
                total += ((2.0 * ma * mb + c1) * (2.0 * (ab - ma * mb) + c2))
                    / ((ma * ma + mb * mb + c1) * (aa - ma * ma + bb - mb * mb + c2));
            }
        }
    }
    total / (w * h * c) as f64
}

#[test]
fn constant_offset_of_a_tenth_is_20_db() {
    let (w, h) = (37, 23);
    let gt: Vec<f32> = random_image(w, h, 3, 1).iter().map(|v| v * 0.8).collect();
    let pred: Vec<f32> = gt.iter().map(|v| v + 0.1).collect();
    let p = psnr(
        ImageRef::new(w, h, 3, &pred),
        ImageRef::new(w, h, 3, &gt),
        None,
    )
    .unwrap();
    assert!((p - 20.0).abs() < 1e-4, "{p}");
    // Masked: the error only where the mask is off does not count.
    let mut pred2 = gt.clone();
    let mask: Vec<f32> = (0..w * h)
        .map(|i| if i % 2 == 0 { 1.0 } else { 0.0 })
        .collect();
    for i in 0..w * h {
        let off = if i % 2 == 0 { 0.01 } else { 0.5 };
        for ch in 0..3 {
            pred2[3 * i + ch] += off;
        }
    }
    let pm = psnr(
        ImageRef::new(w, h, 3, &pred2),
        ImageRef::new(w, h, 3, &gt),
        Some(&mask),
    )
    .unwrap();
    assert!((pm - 40.0).abs() < 1e-3, "{pm}");
    let same = psnr(
        ImageRef::new(w, h, 3, &gt),
        ImageRef::new(w, h, 3, &gt),
        None,
    )
    .unwrap();
    assert_eq!(same, f64::INFINITY);
}

#[test]
fn ssim_of_identical_images_is_one_and_matches_a_direct_implementation() {
    let (w, h, c) = (40, 31, 3);
    let a = random_image(w, h, c, 2);
    let s = ssim(ImageRef::new(w, h, c, &a), ImageRef::new(w, h, c, &a), None).unwrap();
    assert_eq!(s, 1.0);
    let b: Vec<f32> = a
        .iter()
        .zip(random_image(w, h, c, 3))
        .map(|(x, n)| (0.7 * x + 0.3 * n).clamp(0.0, 1.0))
        .collect();
    let s = ssim(ImageRef::new(w, h, c, &b), ImageRef::new(w, h, c, &a), None).unwrap();
    let r = reference_ssim(&b, &a, w, h, c);
    assert!((s - r).abs() < 1e-9, "{s} vs reference {r}");
    assert!(s > 0.3 && s < 0.99, "{s}");
    // Symmetric.
    let t = ssim(ImageRef::new(w, h, c, &a), ImageRef::new(w, h, c, &b), None).unwrap();
    assert!((s - t).abs() < 1e-12);
    // Constant images 0.5 vs 0.5: 1 everywhere, even at the zero-padded border.
    let half = vec![0.5f32; w * h];
    assert!(
        (ssim(
            ImageRef::new(w, h, 1, &half),
            ImageRef::new(w, h, 1, &half),
            None
        )
        .unwrap()
            - 1.0)
            .abs()
            < 1e-12
    );
}

#[test]
fn masked_ssim_averages_over_the_mask() {
    let (w, h) = (48, 48);
    let a = random_image(w, h, 1, 4);
    // Right half differs, left half is identical.
    let b: Vec<f32> = a
        .iter()
        .enumerate()
        .map(|(i, &v)| if i % w >= w / 2 { 1.0 - v } else { v })
        .collect();
    let left: Vec<f32> = (0..w * h)
        .map(|i| if i % w < 10 { 1.0 } else { 0.0 })
        .collect();
    let right: Vec<f32> = (0..w * h)
        .map(|i| if i % w >= w - 10 { 1.0 } else { 0.0 })
        .collect();
    let (ia, ib) = (ImageRef::new(w, h, 1, &a), ImageRef::new(w, h, 1, &b));
    let sl = ssim(ib, ia, Some(&left)).unwrap();
    let sr = ssim(ib, ia, Some(&right)).unwrap();
    let all = ssim(ib, ia, None).unwrap();
    assert!((sl - 1.0).abs() < 1e-9, "{sl}");
    assert!(sr < 0.0, "{sr}");
    assert!(all < sl && all > sr);
}

#[test]
fn image_errors() {
    let a = vec![0.5f32; 12];
    let b = vec![0.5f32; 9];
    let e = psnr(ImageRef::new(2, 2, 3, &a), ImageRef::new(3, 1, 3, &b), None);
    assert!(matches!(
        e,
        Err(EvalError::Input(MeshError::SizeMismatch { .. }))
    ));
    let e = ssim(ImageRef::new(2, 2, 3, &a), ImageRef::new(2, 2, 3, &b), None);
    assert!(matches!(
        e,
        Err(EvalError::Input(MeshError::SizeMismatch { .. }))
    ));
    let e = psnr(
        ImageRef::new(2, 2, 3, &a),
        ImageRef::new(2, 2, 3, &a),
        Some(&[0.0; 4]),
    );
    assert!(matches!(e, Err(EvalError::Input(MeshError::EmptyMask))));
    let e = ssim(
        ImageRef::new(2, 2, 3, &a),
        ImageRef::new(2, 2, 3, &a),
        Some(&[1.0; 3]),
    );
    assert!(matches!(
        e,
        Err(EvalError::Input(MeshError::SizeMismatch { .. }))
    ));
    let mut n = a.clone();
    n[5] = f32::NAN;
    let e = psnr(ImageRef::new(2, 2, 3, &n), ImageRef::new(2, 2, 3, &a), None);
    assert!(matches!(
        e,
        Err(EvalError::Input(MeshError::NonFinite { .. }))
    ));
    let e = ssim(
        ImageRef::new(0, 0, 3, &[]),
        ImageRef::new(0, 0, 3, &[]),
        None,
    );
    assert!(matches!(
        e,
        Err(EvalError::Input(MeshError::SizeMismatch { .. }))
    ));
}
