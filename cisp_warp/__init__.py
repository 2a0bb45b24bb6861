"""cisp_warp: real-time caustics for animated water (Cascaded Image-Space Photon Tracing) on NVIDIA Warp.

>>> import cisp_warp
>>> aovs = cisp_warp.render(cisp_warp.demo("pool"), device="cpu", width=320, height=180)   # doctest: +SKIP
>>> aovs["final"]            # (180, 320, 3) float32 HDR radiance [W/(m² sr)]                 # doctest: +SKIP

The names below are imported on first use (Warp and USD load only when needed).
"""

from __future__ import annotations

import importlib

from .errors import SceneError, SceneWarning


def _version() -> str:
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("cisp-warp")
    except PackageNotFoundError:  # a checkout on PYTHONPATH, not installed
        return "0.1.0"


__version__ = _version()

_LAZY = {
    "render": ".render",  # the module, callable as cisp_warp.api.render (see render._CallableModule)
    "demo": ".api",
    "Renderer": ".render",
    "RenderSettings": ".render",
    "SettingsError": ".render",
    "PhotonSettings": ".photons",
    "SVGFSettings": ".denoise",
    "load_usd": ".usd",
    "Animation": ".animation",
}

__all__ = ["SceneError", "SceneWarning", "__version__", *_LAZY]


def __getattr__(name: str):
    if name == "render":
        return importlib.import_module(".render", __name__)
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cisp_warp' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
