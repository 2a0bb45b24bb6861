#!/usr/bin/env bash
# CUDA test batches on a lent GPU (Warp staged as for ab.sh): TESTS="tests/test_raster.py" K="cuda" bash tools/device/tests.sh
# TT: the timeout [s]; TAILN: lines of pytest's output kept.
set -u
test -f /tmp/cisp_gpu/env.sh || { echo COLD; exit 3; }
. /tmp/cisp_gpu/env.sh
export PYTHONPATH=$PWD:${PYTHONPATH:-}
t0=$(date +%s)
timeout ${TT:-500} python3 -m pytest -q -p no:cacheprovider $TESTS -k "${K:-cuda}" 2>&1 | tail -${TAILN:-15}
echo "tests rc=${PIPESTATUS[0]} $(( $(date +%s) - t0 ))s"
