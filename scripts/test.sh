#!/usr/bin/env bash
# Sets up what the tests need on a fresh Debian machine with a Rust toolchain, then runs them.
# Usage: scripts/test.sh   (from anywhere; extra arguments go to `cargo test`)
set -euo pipefail
cd "$(dirname "$0")/.."

# The ../shared/data scenes are read by gtsr-data's tests; nothing else is needed from outside.
# System packages: none are needed yet (pure-Rust dependencies only). The wgpu tests (issue #4)
# will add Mesa 25 lavapipe from bookworm-backports here.

if ! command -v cargo >/dev/null; then
    echo "error: cargo not found; install Rust 1.95 (https://rustup.rs) first" >&2
    exit 1
fi

# Everything runs in release: Burn and the kernels are too slow unoptimised, and the same
# artefacts then serve `cargo bench` and `cargo run --release`.
cargo test --workspace --release --locked "$@"
