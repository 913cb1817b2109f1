//! `gtsr-train`: images in, mesh and numbers out.
//!
//! The reconstruction pipeline (model, losses, training, mesh extraction) is not implemented
//! yet: it arrives with the gtsr-model and gtsr-train issues. Until then this binary says so
//! and exits with status 2 rather than pretend.

fn main() {
    eprintln!(
        "gtsr-train: the reconstruction pipeline is not implemented yet.\n\
         What exists today: the differentiable splatting kernels (crate gtsr-render-kernels):\n  \
         cargo run --release -p gtsr-render-kernels --example render_png\n  \
         cargo xtask stability\n  \
         cargo bench -p gtsr-render-kernels"
    );
    std::process::exit(2);
}
