"""cisp_warp: real-time caustics for animated water (Cascaded Image-Space Photon Tracing) on NVIDIA Warp."""

from .errors import SceneError

__all__ = ["SceneError"]
