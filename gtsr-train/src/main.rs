//! `gtsr-train`: images in, mesh and numbers out.
//!
//! With no arguments it generates (or reuses) a small built-in translucent scene (a wax bear,
//! path-traced by `gtsr-data`) and reconstructs it on the CPU. See `--help` for the options and
//! the README for what lands in `--out`.

use gtsr_train::{Args, ConfigError, Outcome, run};

fn main() {
    // Each training step renders many views; keep their freed buffers in the process instead
    // of faulting fresh pages in at every render (`GTSR_MALLOC=default` opts out).
    gtsr_render_kernels::cpu::keep_freed_memory();
    let args = Args::parse_with_sources();
    match run(&args) {
        Ok(Outcome::Finished) => {}
        Ok(Outcome::Interrupted) => std::process::exit(130),
        Err(e) => {
            eprintln!("gtsr-train: error: {e:#}");
            // Settings that cannot be used exit as a bad flag does.
            let usage = e.chain().any(|c| c.is::<ConfigError>());
            std::process::exit(if usage { 2 } else { 1 });
        }
    }
}
