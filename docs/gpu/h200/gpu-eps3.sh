#!/usr/bin/env bash
set -u
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export XDG_RUNTIME_DIR=$(mktemp -d)
mkdir -p /work && [ -e /work/main ] || ln -s "$PWD" /work/main
[ -x /tmp/forest ] || { xz -dc .devbin/forest.xz > /tmp/forest && chmod +x /tmp/forest; }
run() { local name=$1; shift; local dir=/tmp; case $name in overview3) dir=$OUT;; esac
  echo "== $name: $*" | tee -a $OUT/log.txt
  timeout 60 /tmp/forest --headless --gpu-timings --screenshot $dir/$name.png "$@" 2>>$OUT/stderr.txt | tee -a $OUT/runs.jsonl; }
S=--size=1920x1080
run overview3 $S --spacing 6 --pixel-error 3 --frames 20
run overview3-noshadow $S --spacing 6 --pixel-error 3 --frames 20 --no-shadows
run tree3-noshadow $S --view tree --spacing 6 --pixel-error 3 --frames 20 --no-shadows
run tree3-taa $S --view tree --spacing 6 --pixel-error 3 --frames 20 --aa taa --camera-step 0.1,0,0
