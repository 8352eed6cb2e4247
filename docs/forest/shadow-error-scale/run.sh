#!/usr/bin/env bash
# The README forest (640x360, 6 m apart, pixel error 3) with the shadow
# maps' error at 1, 2 and 4 times their texel's, without shadow maps, and
# from the ground (`--view ground`) at 1 and 2:
# two frames each, each render pass's GPU time (Bevy times no shadow pass:
# they are in `median_frame_ms` only). One JSON line per run, as in
# runs.jsonl; the pictures compared with diff.py (picture-diffs.txt).
set -euo pipefail
cd "$(dirname "$0")/../../.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
out=${1:-/tmp/shadow-error-scale}
mkdir -p "$out"
cargo build --all-features --example forest
forest="$CARGO_TARGET_DIR/debug/examples/forest"
common=(--headless --size 640x360 --spacing 6 --pixel-error 3 --frames 2 --gpu-timings)
for scale in 1 2 4; do
    "$forest" "${common[@]}" --shadow-error-scale "$scale" --screenshot "$out/scale$scale.png" | grep '^{'
done
"$forest" "${common[@]}" --no-shadows --screenshot "$out/no-shadows.png" | grep '^{'
for scale in 1 2; do
    "$forest" "${common[@]}" --view ground --shadow-error-scale "$scale" --screenshot "$out/ground$scale.png" | grep '^{'
done
python3 docs/forest/shadow-error-scale/diff.py "$out/ground1.png" "$out/ground2.png"
for picture in scale2 scale4 no-shadows; do
    python3 docs/forest/shadow-error-scale/diff.py "$out/scale1.png" "$out/$picture.png"
done
