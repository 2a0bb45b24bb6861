set -u
export PYTHONPATH=$PWD:$PYTHONPATH
T0=$(date +%s)
python3 -m pytest -q -x tests/test_march.py tests/test_ledger.py tests/test_cisp.py -k cuda > $OUT/tests3.txt 2>&1
echo "tests done $(( $(date +%s) - T0 )) s"; tail -3 $OUT/tests3.txt
python3 .scratch/exp1.py > $OUT/exp1.txt 2>&1
echo "exp1 done $(( $(date +%s) - T0 )) s"; grep -v "^\s" $OUT/exp1.txt | tail -30
python3 tools/bench_frame.py --scenes cornell,pool --methods cisp,sspm,caustics_map --photons 500k,2M,8M --frames 10 --kernels --json $OUT/bench3.json > $OUT/bench3.txt 2>&1
echo "bench done $(( $(date +%s) - T0 )) s"
grep -E "^(cornell|pool)|trace_|atrous|composite|^total|^sum|^trace\+|^cisp|^sspm|^caustics" $OUT/bench3.txt | head -80
