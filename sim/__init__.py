"""FFT water surface simulation on NVIDIA Warp (knows nothing of rendering).

Public API::

    from sim import WaterParams, FFTWater, WaterMesh, choose_lod, SimParameterError
    p = WaterParams(resolution=256, patch_size=4.0, depth=1.5, wind_speed=3.0, spectrum="jonswap")
    water = FFTWater(p, device="cpu")      # allocates once
    water.evaluate(t)                       # height, displacement, slope, jacobian (device arrays)
    mesh = WaterMesh(water, rect=(x0, z0, x1, z1), y0=0.0, vertex_counts=(nx, nz))
    mesh.update(t)                          # mesh.points, mesh.normals written in place

Modules: ``params`` (settings), ``spectrum`` (host-side spectra and h0), ``fft`` (Warp inverse
FFT), ``water`` (evolution and fields), ``mesh`` (renderer mesh), ``lod`` (level of detail).
"""

from .fft import InverseFFT2D
from .lod import LevelOfDetail, choose_lod
from .mesh import WaterMesh
from .params import SimParameterError, WaterParams
from .spectrum import peak_wavelength
from .water import FFTWater

__all__ = [
    "FFTWater",
    "InverseFFT2D",
    "LevelOfDetail",
    "SimParameterError",
    "WaterMesh",
    "WaterParams",
    "choose_lod",
    "peak_wavelength",
]
