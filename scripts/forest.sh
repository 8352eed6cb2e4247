#!/usr/bin/env bash
# The main job: the forest demo. With a display it opens a window (fly
# camera, keys in examples/forest.rs); without one it renders headless on
# Mesa's software Vulkan (installed if missing) to target/forest.png.
# Extra arguments go to the example, e.g. `--spacing 10` or `--overlay`.
set -euo pipefail
cd "$(dirname "$0")/.."

# The same build directory and features as `.ci/test`, so one build serves both.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

have_vulkan() { ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1; }
if ! have_vulkan; then
    echo "== installing mesa-vulkan-drivers (software Vulkan)"
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers >/dev/null
fi

if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ]; then
    exec cargo run --all-features --example forest -- "$@"
fi
if [ "$#" -eq 0 ]; then
    # The README's forest (3,332 mature trees 6 m apart), at a pixel error
    # of 3: a software renderer draws it in a few minutes.
    set -- --size 640x360 --spacing 6 --pixel-error 3 --screenshot target/forest.png
fi
echo "== no display: rendering headless ($*)"
exec cargo run --all-features --example forest -- --headless "$@"
