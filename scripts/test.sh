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
log=$(mktemp)
trap 'rm -f "$log"' EXIT
set +e
cargo test --workspace --release --locked "$@" 2>&1 | tee "$log"
status=${PIPESTATUS[0]}
set -e
# One closing line over every test binary and doc-test run (cargo prints one per binary).
awk '/^test result:/ { p += $4; f += $6; i += $8 }
     END { printf "%d passed, %d failed, %d skipped\n", p, f, i }' "$log"
exit "$status"
