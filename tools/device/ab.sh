#!/usr/bin/env bash
# A/B of the frame on a lent GPU (the device tool), after Warp is staged with ../shared/gpu/pack.sh's chunks
# (CHUNK_BYTES=50000000: three carries; the last one also installs the extra wheels of .whl/ into /tmp/cisp_site).
# Each run is a separate process, so flags read at import (CISP_* environment variables) can differ:
#   RUNS="on:pool:- off:pool:CISP_DEPTH_KEY=quotient" bash tools/device/ab.sh
# PRE=<python statements, ';'-separated, no spaces or commas> runs before bench_frame (tools/device/pre.py).
# RUNS="tag:scene:K=V,K=V ..." (env per run; '-' for none); ARGS for bench_frame;
# each run's JSON to $OUT/<i>_<tag>_<scene>.json; prints the graph/frame lines and the kernels named in GREP.
set -u
test -f /tmp/cisp_gpu/env.sh || { echo COLD; exit 3; }
. /tmp/cisp_gpu/env.sh
export PYTHONPATH=$PWD:${PYTHONPATH:-}
ARGS=${ARGS:---photons 2M --denoiser svgf --frames 10 --graph --lanes on}
GREP=${GREP:-graph/frame|graph/seq}
i=${I0:-0}
for r in $RUNS; do
  IFS=: read -r tag scene envs <<< "$r"
  i=$((i+1))
  [ "$envs" = "-" ] && envs=""
  t0=$(date +%s)
  env ${envs//,/ } timeout ${TO:-300} python3 tools/device/pre.py tools/bench_frame.py --scenes $scene --methods cisp $ARGS \
      --json $OUT/${i}_${tag}_${scene}.json > /tmp/ab_$i.txt 2>&1
  rc=$?
  echo "== $i $tag $scene [$envs] rc=$rc $(( $(date +%s) - t0 ))s"
  grep -E "$GREP" /tmp/ab_$i.txt
  [ $rc -ne 0 ] && tail -20 /tmp/ab_$i.txt
done
exit 0
