#!/usr/bin/env bash
# The README forest (640x360, 6 m apart, pixel error 3): the shadow maps
# at scale 1 with hardware lines, at 2 and 4 with their lines drawn as
# quads of their bundle's width (`--shadow-line-quads`). Two frames each,
# each render pass's GPU time (Bevy times no shadow pass: they are in
# `median_frame_ms` only). One JSON line per run, as in runs.jsonl; the
# pictures compared with ../shadow-error-scale/diff.py (picture-diffs.txt).
# The fourth line of runs.jsonl (every quad one texel wide) came from
# this script's scale-2 run with `with_line_quad`'s shadow half width set
# to 0.5 in src/plugin/render/conifer_compact.wgsl, an experiment not
# kept.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
out=${1:-/tmp/shadow-line-quads}
mkdir -p "$out"
cargo build --all-features --example forest
forest="$CARGO_TARGET_DIR/debug/examples/forest"
common=(--headless --size 640x360 --spacing 6 --pixel-error 3 --frames 2 --gpu-timings)
"$forest" "${common[@]}" --shadow-error-scale 1 --screenshot "$out/scale1.png" | grep '^{'
for scale in 2 4; do
    "$forest" "${common[@]}" --shadow-error-scale "$scale" --shadow-line-quads --screenshot "$out/scale$scale.png" | grep '^{'
done
for picture in scale2 scale4; do
    python3 docs/forest/shadow-error-scale/diff.py "$out/scale1.png" "$out/$picture.png"
done
