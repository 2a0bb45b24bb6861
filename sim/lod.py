"""Level of detail: FFT size, patch size, cutoff and mesh density from what the views resolve."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .mesh import check_rect
from .params import SimParameterError, WaterParams, check_finite

#: Default FFT size cap. 1024^2 is 4 packed complex fields x 2 ping-pong buffers = 64 MiB plus
#: 28 MiB of output fields and 20 stage launches per frame. 2048 would quadruple both to resolve
#: waves shorter than 4 L / 1024 = L / 256; with L = 4 peak wavelengths that is under 1/64 of the
#: peak wavelength, finer than a 1080p view resolves unless one patch fills the screen.
DEFAULT_MAX_RESOLUTION = 1024
#: Default mesh vertex cap: 2^22 = 4 M vertices, one per pixel of a 2560 x 1600 view.
DEFAULT_MAX_VERTICES = 1 << 22
#: Smallest FFT size chosen: 16 modes per axis still give a non-trivial random surface.
MIN_LOD_RESOLUTION = 16


@dataclass(frozen=True)
class LevelOfDetail:
    """Result of ``choose_lod``.

    - ``resolution``: FFT size N (power of two).
    - ``patch_size``: L [m].
    - ``small_wave_cutoff``: shortest simulated wavelength [m] (``WaterParams.small_wave_cutoff``).
    - ``vertex_counts``: (nx, nz) for ``WaterMesh`` over the rectangle.
    - ``finest_footprint``: min(camera, light) pixel footprint [m] that drove the choice.
    """

    resolution: int
    patch_size: float
    small_wave_cutoff: float
    vertex_counts: tuple[int, int]
    finest_footprint: float

    def apply(self, params: WaterParams) -> WaterParams:
        """``params`` with this resolution, patch size and small-wave cutoff."""
        return params.replace(resolution=self.resolution, patch_size=self.patch_size,
                              small_wave_cutoff=self.small_wave_cutoff)


def choose_lod(camera_footprint: float, light_footprint: float, rect, peak_wavelength: float,
               samples_per_wavelength: int = 4, peak_wavelengths_per_patch: float = 4.0,
               max_resolution: int = DEFAULT_MAX_RESOLUTION,
               max_vertices: int = DEFAULT_MAX_VERTICES) -> LevelOfDetail:
    """Pick N, L, the small-wave cutoff and the mesh vertex counts for a water rectangle.

    Inputs: ``camera_footprint``, ``light_footprint``: world-space size [m] of one pixel of the
    camera view and of the light view (RSM) where they see the water (take the finest over the
    water); ``rect`` (x_min, z_min, x_max, z_max) [m]; ``peak_wavelength`` [m] of the spectrum
    (``sim.spectrum.peak_wavelength(params)``).

    Reasoning:

    1. Shortest wavelength. The finest view samples the water every d = min(footprints). A wave
       shorter than 2 d is past both views' Nyquist limit: it cannot be seen, and in the RSM and
       G-buffer normals it only aliases into noise that the photon tracer would turn into false
       caustics. So l_min = 2 d is the shortest wave simulated, and ``small_wave_cutoff = l_min``
       suppresses everything shorter (spectrum factor exp(-(l_min / lambda)^2)).
    2. Patch size. L = ``peak_wavelengths_per_patch`` x peak wavelength, so the spectral peak is
       sampled by several modes (k_p >= 4 dk) and tiling repeats only every few wavelengths; but
       no larger than the rectangle's longer side (waves longer than the pool cannot be seen as
       waves in it), and at least 2 l_min.
    3. Grid. N = the power of two with ``samples_per_wavelength`` (4) grid samples per l_min
       (the cutoff is soft: with 4 samples the grid's Nyquist wavelength is l_min / 2, where the
       spectrum keeps exp(-4) = 2 % of its power, so the grid's band edge clips almost nothing;
       with 2 the band edge would sit at the cutoff and clip its tail). Clamped to
       [16, ``max_resolution``]; if capped, l_min grows to 4 L / N instead of L shrinking: the
       long waves near the peak carry most of the variance, the shortest carry the least.
    4. Mesh. A vertex every max(d, L/N): finer triangles than the finest pixel add nothing a
       rasteriser can show, and finer than the FFT grid adds no simulated detail. Then grown
       until nx * nz <= ``max_vertices``.
    """
    cam = check_finite("camera_footprint", camera_footprint, 0.0, strict=True)
    light = check_finite("light_footprint", light_footprint, 0.0, strict=True)
    peak = check_finite("peak_wavelength", peak_wavelength, 0.0, strict=True)
    x0, z0, x1, z1 = check_rect(rect)
    samples = int(samples_per_wavelength)
    if samples < 2:
        raise SimParameterError(
            f"samples_per_wavelength={samples_per_wavelength!r} is invalid: must be >= 2 (Nyquist)")
    per_patch = check_finite("peak_wavelengths_per_patch", peak_wavelengths_per_patch, 0.0,
                             strict=True)
    cap = int(max_resolution)
    if cap < MIN_LOD_RESOLUTION or cap & (cap - 1):
        raise SimParameterError(
            f"max_resolution={max_resolution!r} is invalid: a power of two >= {MIN_LOD_RESOLUTION}")
    if int(max_vertices) < 4:
        raise SimParameterError(f"max_vertices={max_vertices!r} is invalid: must be >= 4")

    footprint = min(cam, light)
    shortest = 2.0 * footprint
    width, depth = x1 - x0, z1 - z0
    patch = max(min(per_patch * peak, max(width, depth)), 2.0 * shortest)
    wanted = samples * patch / shortest
    resolution = 1 << max(0, math.ceil(math.log2(wanted)))
    resolution = min(max(resolution, MIN_LOD_RESOLUTION), cap)
    shortest = max(shortest, samples * patch / resolution)

    spacing = max(footprint, patch / resolution)
    spacing = max(spacing, math.sqrt(width * depth / int(max_vertices)))
    nx = nz = 0
    for _ in range(64):  # the sqrt bound ignores the +1 of each axis; grow until it fits
        nx = max(2, math.ceil(width / spacing) + 1)
        nz = max(2, math.ceil(depth / spacing) + 1)
        if nx * nz <= int(max_vertices):
            break
        spacing *= 1.01
    return LevelOfDetail(resolution=resolution, patch_size=patch, small_wave_cutoff=shortest,
                         vertex_counts=(nx, nz), finest_footprint=footprint)
