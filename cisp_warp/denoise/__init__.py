"""Denoise pass: turns the sparse, noisy photon map (irradiance, W/m²) into the caustic irradiance.

:class:`SVGF` (Schied et al. 2017, as in Falcor's SVGFPass) is the default; :class:`GaussianGather`
(Wyman & Davis 2006, seed 004) is the cheap eye-space gather of the caustics-mapping baseline.
"""

from .gather import GaussianGather
from .svgf import SVGF, SVGFSettings, launch_atrous_level

__all__ = ["SVGF", "SVGFSettings", "GaussianGather", "launch_atrous_level"]
