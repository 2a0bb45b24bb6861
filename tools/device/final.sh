#!/usr/bin/env bash
# The README's per-kernel run (both shipped scenes, cisp and sspm, 2M photons a light, SVGF) into $OUT/final.json;
# tools/device/ksum.py turns bench_frame JSONs into a per-kernel table side by side.
set -u
test -f /tmp/cisp_gpu/env.sh || { echo COLD; exit 3; }
. /tmp/cisp_gpu/env.sh
export PYTHONPATH=$PWD:${PYTHONPATH:-}
t0=$(date +%s)
timeout ${TO:-580} python3 tools/bench_frame.py --scenes cornell,pool --methods cisp,sspm --photons 2M --frames 10 \
   --kernels --graph --lanes both --denoiser svgf --json $OUT/final.json > $OUT/final.txt 2>&1
echo "final rc=$? $(( $(date +%s) - t0 ))s"
grep -E "^(cornell|pool)|graph/" $OUT/final.txt
