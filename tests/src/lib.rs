//! Cross-crate integration tests live in `tests/`: the splatting kernels fitting a scene
//! through Burn's autodiff (`fit.rs`), and the extraction's steps (`gtsr-mesh`) scored by
//! `gtsr-eval` on analytic spheres (`carve.rs`, `consistency.rs`, `tsdf_hull.rs`).
