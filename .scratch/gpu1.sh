set -u
nvidia-smi --query-gpu=name,clocks.max.sm,memory.total --format=csv,noheader
ROOT=$(cd ../.. && pwd)
MINE=$PWD
T0=$(date +%s)
(cd $ROOT && python3 $MINE/tools/bench_frame.py --scenes cornell,pool --methods cisp,sspm --photons 2M --frames 10 --kernels --json $OUT/base.json) > $OUT/base.txt 2>&1
echo "base done $(( $(date +%s) - T0 )) s"
export PYTHONPATH=$MINE:$PYTHONPATH
python3 tools/bench_frame.py --scenes cornell,pool --methods cisp,sspm --photons 2M --frames 10 --kernels --json $OUT/new.json > $OUT/new.txt 2>&1
echo "new done $(( $(date +%s) - T0 )) s"
python3 -m pytest -q -x tests/test_ledger.py tests/test_cisp.py tests/test_methods.py tests/test_caustics_map.py -k cuda > $OUT/tests.txt 2>&1
echo "tests done $(( $(date +%s) - T0 )) s"
tail -3 $OUT/tests.txt
grep -A40 "^cornell_flooded, cisp" $OUT/new.txt | head -45
