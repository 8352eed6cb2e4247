#!/usr/bin/env bash
# The README forest (640x360, 6 m apart, pixel error 3, the hillside
# `overview` camera) under the default steep band (the far impostors give
# way to the lines from 30° to 45° above a crown) and under a lower one,
# 15° to 30° (`--impostor-steep`). Two frames each, each render pass's GPU
# time; one JSON line per run, as in runs.jsonl; the pictures compared
# with ../shadow-error-scale/diff.py, whole and by halves (the lower half
# holds the near trees, seen from most steeply above), in
# picture-diffs.txt. Usage: run.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/../../.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
out=${1:-/tmp/steep}
mkdir -p "$out"
cargo build --all-features --example forest
forest="$CARGO_TARGET_DIR/debug/examples/forest"
common=(--headless --size 640x360 --spacing 6 --pixel-error 3 --frames 2 --gpu-timings)
for band in 30,45 15,30; do
    "$forest" "${common[@]}" --impostor-steep "$band" --screenshot "$out/band-${band/,/-}.png" | grep '^{'
done
python3 docs/forest/shadow-error-scale/diff.py "$out/band-30-45.png" "$out/band-15-30.png"
python3 - "$out/band-30-45.png" "$out/band-15-30.png" <<'PY'
import sys
from PIL import Image
import numpy as np
a, b = (np.asarray(Image.open(p).convert('RGB')).astype(int) for p in sys.argv[1:3])
h = a.shape[0] // 2
for name, rows in (("upper half", slice(0, h)), ("lower half", slice(h, None))):
    d = np.abs(a[rows] - b[rows])
    print(f"{name}: mean |dRGB| {d.mean():.3f}, p99 {np.percentile(d.max(axis=2), 99):.1f}")
PY
