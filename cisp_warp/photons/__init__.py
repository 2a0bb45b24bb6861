"""Photon passes: every method hands back the same camera-resolution photon map (irradiance, W/m²).

=============  ==========================================================================================
method         what it is
=============  ==========================================================================================
cisp           Cascaded Image-Space Photon Tracing (seed 000): light view, then the camera view
sspm           Screen-Space Photon Mapping (seed 003): world-space BVH tracing, stored in screen space
caustics_map   Caustics Mapping (seed 004): light space only, projected like a shadow map
reference      world-space photon tracing accumulated over passes, no denoising: the ground truth
=============  ==========================================================================================
"""

from __future__ import annotations

from .base import Ledger, PhotonPass, PhotonSettings
from .cisp import CISP

PHOTON_METHODS = ("cisp", "sspm", "caustics_map", "reference")


def photon_pass_class(method: str) -> type[PhotonPass]:
    """The class implementing ``method`` (one of :data:`PHOTON_METHODS`)."""
    if method == "cisp":
        return CISP
    if method == "sspm":
        from .world import SSPM

        return SSPM
    if method == "reference":
        from .world import Reference

        return Reference
    if method == "caustics_map":
        from .caustics_map import CausticsMap

        return CausticsMap
    raise ValueError(f"unknown photon method {method!r}; one of {', '.join(PHOTON_METHODS)}")


__all__ = ["CISP", "Ledger", "PHOTON_METHODS", "PhotonPass", "PhotonSettings", "photon_pass_class"]
