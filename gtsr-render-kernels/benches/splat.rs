//! `cargo bench -p gtsr-render-kernels`: forward and forward+backward of the splat op on the
//! NdArray backend (f32), on the bench scene of the crate README, at 256x256 and 512x512 with
//! 10k, 100k and 300k Gaussians.
//!
//! `cargo bench -p gtsr-render-kernels --features wgpu`: the same on the wgpu backend (the
//! default adapter: a GPU where there is one, else a CPU Vulkan driver such as lavapipe), plus
//! 800x800 with 300k and 1M Gaussians. `GTSR_BENCH_BACKEND=ndarray` forces the CPU rows.
//!
//! Each configuration runs in its own process so that its peak resident memory (VmHWM) is its
//! own. Prints a markdown table. `GTSR_BENCH_FILTER=256x256` (a substring of the config name)
//! runs a subset. `GTSR_BLEND=per-pixel|scalar|avx2|avx512` runs the f32 blend on another
//! implementation (`cpu::BlendPath`).

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

use std::process::Command;
use std::time::{Duration, Instant};

use burn::tensor::{DType, Device};
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};
use gtsr_render_kernels::{AlphaCutoff, cpu, render};

const CONFIGS: [(u32, usize); 8] = [
    (256, 10_000),
    (256, 100_000),
    (256, 300_000),
    (512, 10_000),
    (512, 100_000),
    (512, 300_000),
    (800, 300_000),
    (800, 1_000_000),
];

/// The backend the rows run on: wgpu when the feature is on (unless `GTSR_BENCH_BACKEND` says
/// `ndarray`), else NdArray.
fn backend() -> &'static str {
    let want = std::env::var("GTSR_BENCH_BACKEND").unwrap_or_default();
    if cfg!(feature = "wgpu") && want != "ndarray" {
        "wgpu"
    } else {
        "ndarray"
    }
}

fn bench_device() -> Device {
    #[cfg(feature = "wgpu")]
    if backend() == "wgpu" {
        return Device::wgpu(burn::tensor::DeviceKind::DefaultDevice);
    }
    Device::ndarray()
}

fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<f64>().ok())
        .map(|kb| kb / 1024.0)
        .unwrap_or(f64::NAN)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time_it(mut f: impl FnMut()) -> (f64, usize) {
    f(); // warm-up
    let mut times = Vec::new();
    let start = Instant::now();
    while times.len() < 3 || (times.len() < 15 && start.elapsed() < Duration::from_secs(6)) {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let n = times.len();
    (median(times), n)
}

fn single(size: u32, count: usize) {
    // As gtsr-train runs the kernels: freed buffers stay in the process between calls
    // (`GTSR_MALLOC=default` opts out).
    cpu::keep_freed_memory();
    let scene = random_scene(2024, &RandomSceneSpec::bench(count, size, size));
    let cfg = scene.config(AlphaCutoff::Hard);
    // Work counts from the host kernels (same code the backend runs).
    let scene32 = scene.to_f32();
    let host = scene32.host();
    let counts = cpu::forward(&host, &cfg);
    let evals = counts.evaluations as f64;
    let isects = counts.intersections;
    drop(counts);

    let device = bench_device();
    let (fwd_ms, fwd_n) = time_it(|| {
        let out = render(scene.inputs(&device, DType::F32), &cfg).unwrap();
        let _ = out.image.sum().into_scalar::<f32>();
    });
    let ad = bench_device().autodiff();
    let step = || {
        let inp = scene.inputs(&ad, DType::F32);
        let inp = gtsr_render_kernels::SplatInputs {
            means: inp.means.require_grad(),
            quats: inp.quats.require_grad(),
            scales: inp.scales.require_grad(),
            opacities: inp.opacities.require_grad(),
            features: inp.features.require_grad(),
            xy_offsets: None,
        };
        let keep = inp.means.clone();
        let out = render(inp, &cfg).unwrap();
        let loss = out.image.sum() + out.alpha.sum();
        let grads = loss.backward();
        let _ = keep.grad(&grads).unwrap().sum().into_scalar::<f32>();
    };
    // Where the time of a forward+backward call goes (CPU kernels; mean over the timed calls
    // and the warm-up).
    let k0 = cpu::kernel_times();
    let (step_ms, step_n) = time_it(step);
    let k = cpu::kernel_times().since(&k0);
    let calls = (step_n + 1) as f64;
    let ms = |d: Duration| d.as_secs_f64() * 1e3 / calls;
    println!(
        "PHASES {size} {count} {:.1} {:.1} {:.1} {:.1} {:.1} {:.1} {:.1}",
        ms(k.project),
        ms(k.sort_bin),
        ms(k.blend_forward),
        ms(k.blend_backward),
        ms(k.gather),
        ms(k.host_copies),
        (step_ms - ms(k.total())).max(0.0)
    );
    println!(
        "RESULT {size} {count} {fwd_ms:.2} {fwd_n} {step_ms:.2} {step_n} {evals} {isects} {:.1}",
        peak_rss_mb()
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--single") {
        let size: u32 = args[i + 1].parse().unwrap();
        let count: usize = args[i + 2].parse().unwrap();
        single(size, count);
        return;
    }
    let filter = std::env::var("GTSR_BENCH_FILTER").unwrap_or_default();
    let exe = std::env::current_exe().expect("bench executable path");
    if backend() == "wgpu" {
        println!(
            "wgpu backend, f32{}. Median wall time per call.\n",
            adapter_note()
        );
    } else {
        println!(
            "NdArray backend, f32, {} rayon threads, blend {:?} (`GTSR_BLEND` picks another). \
             Median wall time per call.\n",
            rayon::current_num_threads(),
            cpu::BlendPath::default_path()
        );
    }
    println!(
        "| image | Gaussians | forward ms | fwd+bwd ms | splat-pixel evals (fwd) | fwd Meval/s | tile intersections | peak RSS MB |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut phases = Vec::new();
    for (size, count) in CONFIGS {
        // The 800x800 rows are the GPU targets of the wgpu issue; on NdArray they only repeat
        // what the 512x512 rows show, at several seconds per call.
        if backend() == "ndarray" && size == 800 {
            continue;
        }
        let name = format!("{size}x{size}/{count}");
        if !name.contains(&filter) {
            continue;
        }
        let out = Command::new(&exe)
            .args(["--single", &size.to_string(), &count.to_string()])
            .output()
            .expect("run bench child");
        let text = String::from_utf8_lossy(&out.stdout);
        let Some(line) = text.lines().find(|l| l.starts_with("RESULT")) else {
            eprintln!("{name}: failed\n{}", String::from_utf8_lossy(&out.stderr));
            continue;
        };
        if let Some(p) = text.lines().find(|l| l.starts_with("PHASES")) {
            phases.push(format!(
                "| {size}x{size} | {count} | {} |",
                p.split_whitespace().skip(3).collect::<Vec<_>>().join(" | ")
            ));
        }
        let v: Vec<&str> = line.split_whitespace().collect();
        let fwd: f64 = v[3].parse().unwrap();
        let evals: f64 = v[7].parse().unwrap();
        println!(
            "| {size}x{size} | {count} | {} (n={}) | {} (n={}) | {:.3e} | {:.0} | {} | {} |",
            v[3],
            v[4],
            v[5],
            v[6],
            evals,
            evals / fwd / 1e3,
            v[8],
            v[9]
        );
    }
    if !phases.is_empty() {
        println!(
            "\nOne forward+backward call by phase, mean ms (CPU kernels; `rest` is the median call \
             minus the kernels: Burn's autodiff and tensor work around them):\n"
        );
        println!(
            "| image | Gaussians | projection | sort + binning | blend fwd | blend bwd | gather + projection bwd | host copies | rest |"
        );
        println!("|---|---|---|---|---|---|---|---|---|");
        for p in phases {
            println!("{p}");
        }
    }
}

/// The adapter the wgpu rows ran on (name and driver), from `vulkaninfo` when it is installed.
fn adapter_note() -> String {
    let out = Command::new("vulkaninfo").arg("--summary").output();
    let Ok(out) = out else {
        return String::new();
    };
    let text = String::from_utf8_lossy(&out.stdout);
    let field = |key: &str| {
        text.lines()
            .find(|l| l.trim_start().starts_with(key))
            .and_then(|l| l.split('=').nth(1))
            .map(|v| v.trim().to_string())
    };
    match (field("deviceName"), field("driverInfo")) {
        (Some(name), Some(driver)) => format!(", adapter {name} ({driver})"),
        (Some(name), None) => format!(", adapter {name}"),
        _ => String::new(),
    }
}
