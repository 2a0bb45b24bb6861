"""tools/measure_bias.py at a tiny size: its figures, files and bad input."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("measure_bias", ROOT / "tools" / "measure_bias.py")
measure_bias = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(measure_bias)


def test_measure_bias_runs_small(tmp_path, capsys):
    """The sinusoid at 32x18: a mean of 3 raw frames against a small reference; the PNG holds the mean, the
    reference and the error map side by side, the npz the mean the figures are of."""
    out = tmp_path / "bias"
    args = ["--scene", "sinusoid", "--width", "32", "--height", "18", "--rsm", "32", "--photons", "4k",
            "--frames", "3", "--reference-photons", "64k", "--reference-pass", "64k", "--reference-noise", "1",
            "--out", str(out), "--device", "cpu", "--quiet"]
    assert measure_bias.main(args) == 0
    stem = out / "bias_sinusoid_cisp_32x18_rsm32"
    meta = json.loads((stem.with_suffix(".json")).read_text())
    for k in ("rel_rmse", "noise", "bias", "energy", "energy_all"):
        assert math.isfinite(meta[k]), k
    assert meta["rel_rmse"] > 0 and meta["bias"] <= meta["rel_rmse"] and meta["frames"] == 3
    assert abs(meta["ledger_closure"]) < 1e-5
    from PIL import Image

    assert Image.open(stem.with_suffix(".png")).size == (3 * 32, 18)
    with np.load(stem.with_suffix(".npz")) as f:
        from cisp_warp import metrics as M

        ref = {"photon_map": f["reference"]}
        np.testing.assert_allclose(M.relative_rmse(f["mean"], ref["photon_map"], f["mask"]), meta["rel_rmse"],
                                   rtol=1e-5)
    assert "rel RMSE" in capsys.readouterr().out


def test_measure_bias_refuses_bad_input(tmp_path):
    with pytest.raises(SystemExit, match="unknown method"):
        measure_bias.main(["--method", "nope", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="--frames"):
        measure_bias.main(["--frames", "0", "--out", str(tmp_path)])
