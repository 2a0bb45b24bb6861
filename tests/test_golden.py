"""Golden renders: every method on every shipped scene, one small CPU frame each, against tests/golden/.

The goldens and their settings are made by ``tools/make_goldens.py`` (its docstring says what each holds and
what the tolerances absorb). A failure here means a change moved pictures; regenerating them is a
deliberate command, never done by this test.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("make_goldens", ROOT / "tools" / "make_goldens.py")
goldens = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(goldens)


def test_goldens_are_small_and_complete():
    files = sorted(p.name for p in goldens.GOLDEN_DIR.glob("*.npz"))
    assert files == sorted(f"{s}_{m}.npz" for s in goldens.SCENES for m in goldens.METHODS)
    total = sum(p.stat().st_size for p in goldens.GOLDEN_DIR.iterdir())
    assert total < 512 * 1024


@pytest.mark.parametrize("method", goldens.METHODS)
@pytest.mark.parametrize("scene", goldens.SCENES)
def test_render_matches_its_golden(scene, method):
    with np.load(goldens.golden_path(scene, method)) as f:
        want = {k: f[k] for k in goldens.AOVS}
    assert np.abs(want["caustics"]).max() > 0.0 and np.abs(want["final"]).max() > 0.0  # the golden shows something
    got = goldens.render(scene, method)
    problems = goldens.compare(got, want)
    assert not problems, (f"{scene} / {method} no longer matches tests/golden/{scene}_{method}.npz:\n  "
                          + "\n  ".join(problems) + f"\n{goldens.REGENERATE}")


def test_compare_sees_a_small_change():
    """The tolerances are tight enough that moving a little caustic energy is caught."""
    with np.load(goldens.golden_path("pool", "cisp")) as f:
        want = {k: f[k] for k in goldens.AOVS}
    got = {k: v.copy() for k, v in want.items()}
    assert goldens.compare(got, want) == []
    y, x = np.unravel_index(int(np.argmax(got["caustics"][..., 1])), got["caustics"].shape[:2])
    got["caustics"][y, x] *= 1.01  # 1% more irradiance in one pixel
    assert any(p.startswith("caustics") for p in goldens.compare(got, want))
