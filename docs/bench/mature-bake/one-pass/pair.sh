#!/bin/bash
# The side-by-side bakes of this folder: for each mature preset, the build
# before (b0e598c) then the build after (dbcea96), release `cli` binaries
# copied to /tmp/conifer-base and /tmp/conifer-new5; JSON into OUTDIR, and
# how many bytes of the two records differ past the header's first 100
# (the bake figures live there).
#   usage: pair.sh OUTDIR
out=$1; mkdir -p $out/before-b0e598c $out/after-dbcea96
for p in scots-pine norway-spruce eastern-white-pine lawson-cypress douglas-fir silver-fir; do
  /tmp/conifer-base bake --preset $p -o /tmp/pair-before.conifer --json > $out/before-b0e598c/$p.json
  /tmp/conifer-new5 bake --preset $p -o /tmp/pair-after.conifer --json > $out/after-dbcea96/$p.json
  n=$(cmp -l /tmp/pair-before.conifer /tmp/pair-after.conifer | awk '$1>100' | wc -l)
  echo "$p differing-bytes-past-100: $n"
done
