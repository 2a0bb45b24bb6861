"""Denoise pass: turns the sparse, noisy photon map (irradiance, W/m²) into the caustic irradiance.

:class:`CausticDenoiser` (the default) accumulates the raw photon map over frames, reacting where the
caustic changes, and filters what noise is left with a footprint that shrinks as the estimate converges;
:class:`SVGF` (Schied et al. 2017, as in Falcor's SVGFPass) is the paper's filter; :class:`GaussianGather`
(Wyman & Davis 2006, seed 004) is the cheap eye-space gather of the caustics-mapping baseline. The
à-trous level comes in two forms with one twin: :func:`.kernels_atrous.launch_atrous` (a dense guide pass and one
tiled launch a level: SVGF's and the caustics denoiser's) and :func:`launch_atrous_level` (per pixel, three passes:
the caustics denoiser's ``levels="pixel"``).
"""

from .caustic import CausticDenoiser, CausticSettings
from .gather import GaussianGather
from .kernels_atrous import launch_atrous_level
from .svgf import SVGF, SVGFSettings

__all__ = ["CausticDenoiser", "CausticSettings", "SVGF", "SVGFSettings", "GaussianGather", "launch_atrous_level"]
