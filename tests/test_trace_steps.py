"""tools/trace_steps.py (and tools/trace_ablate.py) at a tiny size: the counted trace (``kernels_cisp.counted_trace``) leaves every output of
the trace as it was (outcome records, photon map, landings: bit for bit, every warp traced), and the table's figures
hang together (no timings)."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_trace_steps_smoke(tmp_path):
    out = tmp_path / "steps.json"
    res = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "trace_steps.py"), "--smoke", "--scenes", "cornell",
                          "--json", str(out)], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": ROOT})
    assert res.returncode == 0, res.stdout + res.stderr
    assert "equal the trace's" in res.stdout and "DIFFER" not in res.stdout
    (scene,) = json.loads(out.read_text())
    rows = {r["phase"]: r for r in scene["rows"]}
    for r in rows.values():  # a warp pays its longest lane: never less than the lanes' mean
        assert r["warp_max"] >= r["warp_mean"] - 1e-6 and r["max"] >= r["p99"] >= 0
    shares = [r["share"] for r in rows.values() if r["share"] is not None]
    assert abs(sum(shares) - 1.0) < 1e-9 and len(shares) == 6
    assert rows["light march"]["mean"] > 0 and rows["camera (one site)"]["mean"] > 0
    # the two camera passes share one call site: a warp pays at most their two maxima, at least the larger
    site = rows["camera (one site)"]["warp_max"]
    assert max(rows["cascade (pass 0)"]["warp_max"], rows["rescue (pass 1)"]["warp_max"]) <= site
    assert site <= rows["cascade (pass 0)"]["warp_max"] + rows["rescue (pass 1)"]["warp_max"]
    # the whole trace as one phase is what the warps would pay without waiting between phases: no more than the sum
    assert rows["whole trace as one phase"]["warp_max"] <= sum(rows[p]["warp_max"] for p in
                                                               ("emit", "light march", "reproject", "camera (one site)",
                                                                "refine", "store"))


def test_trace_steps_bad_input():
    res = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "trace_steps.py"), "--photons", "lots"],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
    assert res.returncode != 0 and "Traceback" not in res.stderr and "trace_steps:" in res.stderr


def test_trace_ablate_smoke():
    """tools/trace_ablate.py runs every variant at a tiny size on the CPU (wall clock there; no timing checked)."""
    res = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "trace_ablate.py"), "--smoke", "--device", "cpu",
                          "--scenes", "cornell"], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": ROOT})
    assert res.returncode == 0, res.stdout + res.stderr
    for variant in ("frame", "no camera marches", "max_steps 1", "emit only", "photons unsorted"):
        assert variant in res.stdout
