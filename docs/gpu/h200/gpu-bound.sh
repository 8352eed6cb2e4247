#!/usr/bin/env bash
# The forest at 1920x1080 on the device machine, with the mature records
# as committed (ours: the thinnest pair merged first, the needles' merge
# error) and again as the paper's model (its weighted merge cost and nested
# error, rebaked there by the release `conifer`), and one
# run at a quarter of the pixels with the same cut (half the size, half ε),
# which tells vertex work from fragment work.
# Usage (device, repository root): bash docs/gpu/h200/gpu-bound.sh [WxH]
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
if [ -d .gl ]; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
[ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] && export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export XDG_RUNTIME_DIR=$(mktemp -d) BEVY_ASSET_ROOT=$PWD
mkdir -p /work && [ -e /work/main ] || ln -s "$PWD" /work/main
[ -x /tmp/forest ] || { xz -dc .devbin/forest.xz > /tmp/forest && chmod +x /tmp/forest; }
[ -x /tmp/conifer ] || { xz -dc .devbin/conifer.xz > /tmp/conifer && chmod +x /tmp/conifer; }
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.mem --format=csv > "$OUT/gpu.txt" 2>&1
S=--size=${1:-1920x1080}
H=--size=${2:-960x540}
run() { local name=$1; shift; local dir=/tmp; case $name in overview3) dir=$OUT;; esac
  echo "== $name: $*" | tee -a "$OUT/log.txt"
  timeout 120 /tmp/forest --headless --gpu-timings --screenshot "$dir/$name.png" "$@" 2>>"$OUT/stderr.txt" | tee -a "$OUT/runs.jsonl"; }
run overview3 $S --spacing 6 --pixel-error 3 --frames 20
run overview3-noshadow $S --spacing 6 --pixel-error 3 --frames 20 --no-shadows
run overview1.5-half-noshadow $H --spacing 6 --pixel-error 1.5 --frames 20 --no-shadows
run tree3-noshadow $S --view tree --spacing 6 --pixel-error 3 --frames 20 --no-shadows
echo "== rebake as the paper's model" | tee -a "$OUT/log.txt"
for p in scots-pine norway-spruce eastern-white-pine lawson-cypress douglas-fir silver-fir; do
  /tmp/conifer bake --preset $p --merge-cost weighted --merge-error nested -o assets/trees/mature/$p.conifer --json > "/tmp/paper-$p.json" 2>/dev/null
done
cat /tmp/paper-*.json > "$OUT/paper-bakes.json"; grep -h bake_seconds /tmp/paper-*.json | tee -a "$OUT/log.txt"
run paper-overview3 $S --spacing 6 --pixel-error 3 --frames 20
run paper-overview3-noshadow $S --spacing 6 --pixel-error 3 --frames 20 --no-shadows
run paper-tree3-noshadow $S --view tree --spacing 6 --pixel-error 3 --frames 20 --no-shadows
tail -c 2000 "$OUT/stderr.txt"
