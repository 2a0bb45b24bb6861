"""Write scenes_usd/pool.usda (the shipped pool): a thin wrapper of ``cisp-make-pool``
(:mod:`cisp_warp.pool_scene`, where the scene is built and every flag is documented: ``--help``)."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cisp_warp.pool_scene import main  # noqa: E402  (the repository root is put on the path first)

if __name__ == "__main__":
    sys.exit(main(default_out=ROOT / "scenes_usd" / "pool.usda", prog="make_pool_scene.py"))
