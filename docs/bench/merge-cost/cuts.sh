#!/usr/bin/env bash
# Primitives of each mature record's cut under either merge cost rule, one
# JSON line per (tree, rule, ε, distance): docs/bench/merge-cost/cuts.jsonl.
# `error` rows read the shipped records (assets/trees/mature/, baked with
# the default `--merge-cost error`); `weighted` rows read records baked by
# `conifer bake --preset P --merge-cost weighted` into $WEIGHTED (default
# /tmp/mc/weighted), which the script bakes when they are missing.
set -euo pipefail
cd "$(dirname "$0")/../../.."
CONIFER=${CONIFER:-${CARGO_TARGET_DIR:-$HOME/.cache/bevy_conifer_lod/target}/release/conifer}
WEIGHTED=${WEIGHTED:-/tmp/mc/weighted}
mkdir -p "$WEIGHTED"
out=docs/bench/merge-cost/cuts.jsonl
: > "$out"
for tree in scots-pine norway-spruce eastern-white-pine lawson-cypress douglas-fir silver-fir; do
  [ -f "$WEIGHTED/$tree.conifer" ] || "$CONIFER" bake --preset "$tree" --merge-cost weighted -o "$WEIGHTED/$tree.conifer" > /dev/null
  for rule in error weighted; do
    if [ "$rule" = error ]; then record=assets/trees/mature/$tree.conifer; else record=$WEIGHTED/$tree.conifer; fi
    for eps in 3 1; do
      for d in 2 10 25 50 100 200 400; do
        "$CONIFER" cut "$record" --distance "$d" --pixel-error "$eps" --json |
          python3 -c "import json,sys; j=json.load(sys.stdin); j.update(tree='$tree', rule='$rule', record_baked_by='conifer bake --preset $tree --merge-cost $rule', pixel_error=$eps, height_px=1080, fov_deg=45, command='conifer cut RECORD --distance $d --pixel-error $eps --json'); print(json.dumps(j))" >> "$out"
      done
    done
  done
done
python3 - "$out" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
for eps in (3, 1):
    print(f"ε = {eps}")
    for tree in dict.fromkeys(r["tree"] for r in rows):
        cells = []
        for d in (25, 50, 100, 200, 400):
            get = lambda rule: next(r["primitives"] for r in rows if r["tree"] == tree and r["rule"] == rule and r["pixel_error"] == eps and r["distance"] == d)
            e, w = get("error"), get("weighted")
            cells.append(f"{e:,} / {w:,} ({w / max(e, 1):.2f}×)")
        print(f"| {tree} | " + " | ".join(cells) + " |")
PY
