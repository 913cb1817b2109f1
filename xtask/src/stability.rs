//! `cargo xtask stability`: renders every stiff case of `gtsr_render_kernels::scenes` in f32 and
//! f64 (NdArray autodiff backend, hard 3DGS cut-off), back-propagates a seeded weighted-sum loss,
//! and prints the largest |f32 - f64| difference of the outputs and of each gradient, plus the
//! number of non-finite values.

use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::scenes::{
    INPUT_NAMES, random_weights, stiff_cases, weighted_loss_gradients,
};

fn max_diff(a: &[f64], b: &[f64]) -> (f64, f64) {
    // (max abs difference, max abs of the f64 values) over entries finite in both.
    let mut d: f64 = 0.0;
    let mut m: f64 = 0.0;
    for (x, y) in a.iter().zip(b) {
        if x.is_finite() && y.is_finite() {
            d = d.max((x - y).abs());
            m = m.max(y.abs());
        }
    }
    (d, m)
}

pub fn run() -> anyhow::Result<()> {
    println!(
        "Stiff cases, NdArray backend, hard cut-off, loss = sum(W * [image, alpha]), W seeded."
    );
    println!(
        "Each cell: max |f32 - f64| (in brackets: relative to max |f64|, where that exceeds 1e-12)."
    );
    println!("Non-finite: count of NaN / Inf in the f32 and f64 results together.\n");
    print!("| case | N | output |");
    for n in INPUT_NAMES {
        print!(" d/d {n} |");
    }
    println!(" non-finite |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut total_bad = 0usize;
    for case in stiff_cases() {
        let s = &case.scene;
        let (h, w) = (s.camera.height as usize, s.camera.width as usize);
        let weights = random_weights(5, h * w * (s.channels + 1));
        let r32 = weighted_loss_gradients(s, DType::F32, AlphaCutoff::Hard, &weights)?;
        let r64 = weighted_loss_gradients(s, DType::F64, AlphaCutoff::Hard, &weights)?;
        let mut bad = 0;
        let mut cells = Vec::new();
        let mut cell = |a: &[f64], b: &[f64]| {
            bad += a.iter().chain(b).filter(|v| !v.is_finite()).count();
            let (d, m) = max_diff(a, b);
            // A relative figure only where the f64 gradient is not zero up to rounding (an
            // isotropic Gaussian's rotation gradient is exactly zero, say).
            cells.push(if m > 1e-12 {
                format!("{d:.1e} ({:.0e})", d / m)
            } else {
                format!("{d:.1e}")
            });
        };
        cell(&r32.output, &r64.output);
        for k in 0..6 {
            cell(&r32.grads[k], &r64.grads[k]);
        }
        total_bad += bad;
        println!(
            "| {} | {} | {} | {bad} |",
            case.name,
            s.len(),
            cells.join(" | ")
        );
    }
    println!("\nnon-finite values in total: {total_bad}");
    if total_bad > 0 {
        anyhow::bail!("{total_bad} non-finite outputs or gradients");
    }
    Ok(())
}
