"""tools/denoiser_crop.py: its arguments (rendering is the renderer's, tested elsewhere)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))

import denoiser_crop  # noqa: E402


def test_crop_fractions_parse():
    assert denoiser_crop.parse_crop("0.1,0.2,0.5,0.9") == (0.1, 0.2, 0.5, 0.9)


@pytest.mark.parametrize("bad", ["0.1,0.2,0.5", "a,b,c,d", "0.5,0.2,0.4,0.9", "0,0,1.5,1"])
def test_bad_crop_is_one_sentence(bad, tmp_path):
    out = tmp_path / "crop.png"
    p = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "denoiser_crop.py"), "--crop", bad, "--out", str(out)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--crop" in p.stderr and "Traceback" not in p.stderr
    assert not out.exists()
