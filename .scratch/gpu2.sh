set -u
export PYTHONPATH=$PWD:$PYTHONPATH
T0=$(date +%s)
python3 .scratch/exp1.py > $OUT/exp1.txt 2>&1
echo "exp1 done $(( $(date +%s) - T0 )) s"; tail -30 $OUT/exp1.txt
python3 tools/bench_frame.py --scenes cornell,pool --methods cisp,sspm --photons 2M --frames 10 --kernels --json $OUT/new2.json > $OUT/new2.txt 2>&1
echo "bench done $(( $(date +%s) - T0 )) s"
python3 -m pytest -q -x tests/test_ledger.py tests/test_march.py tests/test_cisp.py tests/test_evaluation.py -k cuda > $OUT/tests2.txt 2>&1
echo "tests done $(( $(date +%s) - T0 )) s"; tail -3 $OUT/tests2.txt
grep -E "^(cornell|pool)|trace_|atrous|composite|^total|^sum|^trace\+" $OUT/new2.txt
python3 .scratch/exp2.py > $OUT/exp2.txt 2>&1; cat $OUT/exp2.txt | tail -4
