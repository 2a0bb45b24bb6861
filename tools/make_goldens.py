"""Golden renders: every method on every shipped scene, small, on the CPU, for ``tests/test_golden.py``.

    python3 tools/make_goldens.py            # rewrite tests/golden/*.npz and tests/golden/meta.json
    python3 tools/make_goldens.py --check    # render and compare only (what the test does), exit 1 on a change

Each golden is one frame of a shipped scene (``scenes_usd/cornell_flooded.usda``, ``scenes_usd/pool.usda``) at
its start time code, ``WIDTH`` × ``HEIGHT`` pixels, RSM ``RSM_SIZE``², ``PHOTONS`` photons per light (the
reference accumulates ``REFERENCE_PHOTONS``), seed ``SEED``, everything else at the renderer's defaults
(``RenderSettings()``: the denoiser, the footprint, ... as a user gets them), rendered on the CPU, where
a seed reproduces a frame exactly. Stored per (scene, method) as a compressed ``.npz`` of the AOVs in
``AOVS`` (float32).

Regenerating is deliberate: run this command only when a change is *meant* to move pictures, look at
what moved (``--check`` prints it per AOV), and say in the commit why the pictures changed.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
GOLDEN_DIR = ROOT / "tests" / "golden"
SCENES = ("cornell_flooded", "pool")
METHODS = ("cisp", "sspm", "caustics_map", "reference")
AOVS = ("depth", "direct_irradiance", "photon_map", "caustics", "final")
WIDTH, HEIGHT = 48, 27  #: [pixels], 16:9 like both scenes
RSM_SIZE = 64  #: [texels]
PHOTONS = 16_384  #: per light per frame
REFERENCE_PHOTONS = 32_768  #: per light, for the reference (2 passes)
SEED = 7

#: A golden matches when every pixel of every AOV agrees within ATOL_FRACTION of the AOV's largest
#: magnitude plus RTOL of its own value, and each AOV's sum within SUM_RTOL. The CPU is deterministic, so
#: these only absorb float reordering across compilers (LLVM versions); moving one photon's deposit, a
#: changed filter weight or a shifted pixel breaks them.
RTOL = 1e-3
ATOL_FRACTION = 1e-4
SUM_RTOL = 1e-4

REGENERATE = ("if the change is meant to move pictures, regenerate with `python3 tools/make_goldens.py`, look at "
              "what moved, and say in the commit why the pictures changed")


def golden_path(scene: str, method: str) -> Path:
    return GOLDEN_DIR / f"{scene}_{method}.npz"


def render(scene: str, method: str) -> dict[str, np.ndarray]:
    """The AOVs of one golden frame (see the module docstring), float32 host arrays."""
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    from cisp_warp.animation import Animation
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    path = ROOT / "scenes_usd" / f"{scene}.usda"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stage = load_usd(path, width=WIDTH, height=HEIGHT, device="cpu")
    settings = RenderSettings(width=WIDTH, height=HEIGHT, rsm_size=RSM_SIZE, method=method,
                              photons=PhotonSettings(photons=PHOTONS, seed=SEED, reference_photons=REFERENCE_PHOTONS))
    renderer = Renderer(stage, settings, device="cpu")
    animation = Animation(renderer, path)
    animation.set_time_code(stage.time_code)
    renderer.render_frame()
    aovs = renderer.aovs(include_rsm=False)
    return {k: np.asarray(aovs[k], dtype=np.float32) for k in AOVS}


def compare(got: dict[str, np.ndarray], want: dict[str, np.ndarray]) -> list[str]:
    """What differs, one line per AOV (empty when the render matches its golden)."""
    problems = []
    for k in AOVS:
        a, b = got[k].astype(np.float64), want[k].astype(np.float64)
        if a.shape != b.shape:
            problems.append(f"{k}: shape {a.shape}, golden {b.shape}")
            continue
        if not np.all(np.isfinite(a)):
            problems.append(f"{k}: {int((~np.isfinite(a)).sum())} non-finite values")
            continue
        scale = float(np.abs(b).max())
        tol = ATOL_FRACTION * scale + RTOL * np.abs(b)
        bad = np.abs(a - b) > tol
        sa, sb = float(a.sum()), float(b.sum())
        sum_off = abs(sa - sb) > SUM_RTOL * max(abs(sb), 1e-30)
        if np.any(bad) or sum_off:
            worst = np.unravel_index(int(np.argmax(np.abs(a - b) - tol)), a.shape)
            problems.append(f"{k}: {int(bad.sum())} of {bad.size} values off (worst at {tuple(map(int, worst))}: "
                            f"{a[worst]:.6g} vs golden {b[worst]:.6g}); sum {sa:.6g} vs golden {sb:.6g}")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="make_goldens.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="compare with the stored goldens, write nothing")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    changed = 0
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for scene in SCENES:
        for method in METHODS:
            aovs = render(scene, method)
            path = golden_path(scene, method)
            if args.check:
                if not path.exists():
                    print(f"{path.name}: missing")
                    changed += 1
                    continue
                with np.load(path) as f:
                    problems = compare(aovs, {k: f[k] for k in AOVS})
                changed += bool(problems)
                print(f"{path.name}: " + ("matches" if not problems else "CHANGED\n  " + "\n  ".join(problems)))
            else:
                np.savez_compressed(path, **aovs)
                print(f"wrote {path.relative_to(ROOT)} ({path.stat().st_size / 1024:.1f} KiB)")
    if not args.check:
        import warp as wp

        meta = {"width": WIDTH, "height": HEIGHT, "rsm_size": RSM_SIZE, "photons": PHOTONS,
                "reference_photons": REFERENCE_PHOTONS, "seed": SEED, "aovs": list(AOVS), "device": "cpu",
                "warp": wp.config.version, "numpy": np.__version__}
        (GOLDEN_DIR / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
