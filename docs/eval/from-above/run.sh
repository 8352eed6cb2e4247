#!/usr/bin/env bash
# Mature crowns seen from above (`conifer eval --elevation`): the Norway
# spruce and the Scots pine 80 m from the crown centre in a 256 x 256, 45°
# view at pixel error 1 (the crown impostor in full: 2.6 texels a pixel
# error), level and from above (the impostor is drawn in full up to
# 30°), `ours` as the impostor and, with --ours-no-impostor, as its lines.
# Each run is stopped once its two pictures are written (the dolly and the
# timings that follow are not needed); the figures come from the pictures
# (docs/eval/crossfade/crown_colour.py, as `conifer eval` computes the
# crown colour error), in figures.txt. Usage: run.sh [OUT [ELEVATION...]];
# TREES="scots-pine" runs one tree.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}"
out=${1:-/tmp/from-above}
shift || true
elevations=("$@")
[[ ${#elevations[@]} -gt 0 ]] || elevations=(0 15 27)
mkdir -p "$out"
cargo build --bin conifer
conifer="$CARGO_TARGET_DIR/debug/conifer"
common=(--methods ours --distances 80 --size 256x256 --fov-deg 45 --supersampling 4 --dolly-steps 2 --frames 1 --json --hdr)
run() {
    local tree=$1 elevation=$2 what=$3
    shift 3
    local dir="$out/$tree-$elevation-$what"
    mkdir -p "$dir"
    "$conifer" eval "assets/trees/mature/$tree.conifer" "${common[@]}" --elevation "$elevation" "$@" \
        --out "$dir" > /dev/null 2>&1 &
    local pid=$!
    until [[ -s "$dir/ours_80m.png" && -s "$dir/ref_80m.png" ]]; do sleep 2; done
    sleep 2
    kill "$pid"
    wait "$pid" || true
    echo "$tree, $elevation° above, $what: $(python3 docs/eval/crossfade/crown_colour.py "$dir/ref_80m.png" "$dir/ours_80m.png")"
}
read -ra trees <<< "${TREES:-norway-spruce scots-pine}"
for tree in "${trees[@]}"; do
    for elevation in "${elevations[@]}"; do
        run "$tree" "$elevation" impostor
        run "$tree" "$elevation" lines --ours-no-impostor
    done
done
