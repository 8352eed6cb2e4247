#!/usr/bin/env bash
# GPU frame times of the forest example (device machine). Run from the repo root.
set -u
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export XDG_RUNTIME_DIR=$(mktemp -d)
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.mem --format=csv | tee $OUT/gpu.txt
# The example reads its assets from the path it was built in.
mkdir -p /work && [ -e /work/main ] || ln -s "$PWD" /work/main
xz -dc .devbin/forest.xz > /tmp/forest && chmod +x /tmp/forest
run() { # name, args...
  local name=$1; shift
  local dir=/tmp; case $name in overview|tree|tree-taa) dir=$OUT;; esac
  echo "== $name: $*" | tee -a $OUT/log.txt
  timeout 100 /tmp/forest --headless --gpu-timings --screenshot $dir/$name.png "$@" 2>>$OUT/stderr.txt | tee -a $OUT/runs.jsonl
}
S=--size=1920x1080
run overview $S --spacing 6 --pixel-error 1 --frames 30
run tree $S --view tree --spacing 6 --pixel-error 1 --frames 30
run tree-taa $S --view tree --spacing 6 --pixel-error 1 --frames 30 --aa taa --camera-step 0.1,0,0
run ground $S --view ground --spacing 6 --pixel-error 1 --frames 30
run tree-fxaa $S --view tree --spacing 6 --pixel-error 1 --frames 30 --aa fxaa
run overview-wind $S --spacing 6 --pixel-error 1 --frames 30 --wind 1
tail -c 3000 $OUT/stderr.txt
