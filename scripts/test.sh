#!/usr/bin/env bash
# Sets up what the tests need on a fresh Debian machine with a Rust toolchain, then runs them.
# Usage: scripts/test.sh   (from anywhere; extra arguments go to `cargo test`)
set -euo pipefail
cd "$(dirname "$0")/.."

# The ../shared/data scenes are read by gtsr-data's tests; nothing else is needed from outside.
#
# System packages: the wgpu kernel tests (gtsr-render-kernels/tests/wgpu.rs) need a Vulkan
# driver; without a GPU that is Mesa's lavapipe (CPU Vulkan). Mesa 22 from plain bookworm
# silently caps shader loops at 65,535 iterations (wrong results), so Mesa >= 25 comes from
# bookworm-backports. Nothing is installed when a recent enough driver is already there.
mesa_major() {
    local v
    v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
    echo "${v%%.*}"
}
if [[ "$(mesa_major)" =~ ^[0-9]+$ ]] && (( $(mesa_major) >= 25 )); then
    :
else
    sudo=""
    if [[ $(id -u) -ne 0 ]]; then sudo=sudo; fi
    codename=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
    release=()
    if [[ "$codename" == bookworm ]]; then
        if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
            echo "deb http://deb.debian.org/debian bookworm-backports main" |
                $sudo tee /etc/apt/sources.list.d/bookworm-backports.list >/dev/null
        fi
        release=(-t bookworm-backports)
    fi
    echo "== installing Mesa lavapipe (mesa-vulkan-drivers) ${release[*]:-}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${release[@]}" \
        mesa-vulkan-drivers >/dev/null
    if ! [[ "$(mesa_major)" =~ ^[0-9]+$ ]] || (( $(mesa_major) < 25 )); then
        echo "error: mesa-vulkan-drivers >= 25 is needed for the wgpu tests, got '$(mesa_major)'" >&2
        exit 1
    fi
fi

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
