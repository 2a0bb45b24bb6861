"""A seeded smoke run of tools/fuzz_usd.py: mutated stages end in a render or one clear sentence."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_fuzz_smoke_run_has_no_failures(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "fuzz_usd.py"), "--cases", "30", "--seed", "16", "--jobs", "2",
         "--smoke", "--quiet", "--deadline", "120", "--out", str(tmp_path / "fuzz"), "--tmp", str(tmp_path)],
        env=env, capture_output=True, text=True, timeout=600,
    )
    report = json.loads((tmp_path / "fuzz" / "cases.json").read_text())
    outcomes = {c["outcome"] for c in report["results"]}
    failures = [c for c in report["results"] if c["outcome"] not in ("rendered", "scene_error")]
    assert proc.returncode == 0 and not failures, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert len(report["results"]) == 30
    assert outcomes == {"rendered", "scene_error"}  # the mutations both break stages and leave some renderable
    assert "| hang | 0 |" in proc.stdout and "| Python traceback | 0 |" in proc.stdout


def test_caustic_map_aovs_of_another_size_than_the_image(tmp_path):
    """Found by the fuzzer: `--method caustics_map --aovs all` put the light-space caustic map (RSM size) into
    aovs.exr beside the camera images and raised; it belongs with the RSM maps."""
    from cisp_warp import cli

    rc = cli.main([str(ROOT / "scenes_usd" / "cornell_flooded.usda"), "--out", str(tmp_path), "--device", "cpu",
                   "--width", "40", "--height", "20", "--rsm-size", "32", "--photons", "2k", "--supersample", "1",
                   "--method", "caustics_map", "--aovs", "all", "--npy", "--rsm-aovs", "--quiet"])
    assert rc == 0
    assert (tmp_path / "aovs.exr").is_file() and (tmp_path / "rsm.exr").is_file()
    import numpy as np

    assert np.load(tmp_path / "caustics.npy").shape[:2] == (20, 40)
