"""Water settings: a frozen, hashable, validated dataclass (no arrays, no device).

``WaterParams`` is the *settings* part of the simulation (STYLE.md 2): it is fixed for the life of
an ``FFTWater``; the per-frame state (time) is an argument of ``FFTWater.evaluate``.
"""

from __future__ import annotations

import dataclasses
import math
import reprlib
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any, Mapping

#: Spectra that ``WaterParams.spectrum`` accepts (see ``sim.spectrum``).
SPECTRA = ("phillips", "jonswap")

#: Largest FFT size accepted. 4096^2 x 4 packed complex fields x 2 ping-pong buffers is 1 GiB of
#: float32; beyond it the surface no longer fits a real-time frame on any current GPU.
MAX_RESOLUTION = 4096
#: Smallest FFT size accepted (a radix-2 transform needs at least two butterfly stages).
MIN_RESOLUTION = 4

#: Upper bounds, far beyond any real water but low enough that the spectrum (which squares and
#: exponentiates these) stays finite in float32: a patch of 10 km, an ocean trench 20 km deep, wind of
#: 100 m/s (above the strongest gust measured, 113 m/s, as a sustained speed), a fetch of 10,000 km,
#: waves 100x the physical spectrum, a choppy displacement 10x the heights' gradient, a cutoff of 10 km.
MAX_PATCH_SIZE = 1e4  #: [m]
MAX_DEPTH = 2e4  #: [m]; +inf (deep water) is accepted too
MAX_WIND_SPEED = 100.0  #: [m/s]
MAX_FETCH = 1e7  #: [m]
MAX_AMPLITUDE = 100.0
MAX_CHOPPINESS = 10.0
MAX_SMALL_WAVE_CUTOFF = 1e4  #: [m]
MAX_SEED = 2**31 - 1  #: seeds reach Warp kernels as int32


class SimParameterError(ValueError):
    """A simulation parameter is out of range; the message names it, its value and the fix."""


def _fail(name: str, value: Any, fix: str) -> SimParameterError:
    return SimParameterError(f"{name}={reprlib.repr(value)} is invalid: {fix}")  # long values abbreviated


def check_finite(name: str, value: Any, minimum: float | None = None, strict: bool = False,
                 allow_inf: bool = False, maximum: float | None = None) -> float:
    """Return ``value`` as float, or raise ``SimParameterError`` naming ``name``.

    ``minimum``/``strict`` bound it from below (``>`` when strict, else ``>=``); ``maximum`` from above
    (``<=``); ``allow_inf`` lets +inf through (used for infinite depth).
    """
    if isinstance(value, bool) or not isinstance(value, Real):
        raise _fail(name, value, "expected a real number")
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and not (allow_inf and v > 0.0)):
        raise _fail(name, value, "expected a finite number" + (" (or +inf)" if allow_inf else ""))
    if minimum is not None and (v < minimum or (strict and v == minimum)):
        raise _fail(name, value, f"must be {'>' if strict else '>='} {minimum}")
    if maximum is not None and v > maximum and not (allow_inf and math.isinf(v)):
        raise _fail(name, value, f"must be <= {maximum:g}" + (" (or +inf)" if allow_inf else ""))
    return v


@dataclass(frozen=True)
class WaterParams:
    """Settings of one periodic FFT water patch (Tessendorf 2001, "Simulating Ocean Water").

    Every field is a plain scalar, so the dataclass hashes and round-trips through
    ``to_dict``/``from_dict``; a pool-scene generator stores each key ``k`` as the USD attribute
    ``cisp:water:<k>``. Keys (units):

    - ``resolution``: FFT grid size N per axis, a power of two in [4, 4096].

    Every real field has an upper bound too (``MAX_*`` above), so the spectrum stays finite.
    - ``patch_size``: side L of the square periodic patch [m]; the patch tiles the water.
    - ``depth``: still-water depth h [m] used in the finite-depth dispersion
      omega^2 = g k tanh(k h) (and the TMA depth factor for JONSWAP); ``math.inf`` = deep water.
    - ``wind_speed``: wind speed U [m/s] (U10 for JONSWAP), > 0.
    - ``wind_direction``: direction the wind blows *towards*, angle from +X towards +Z [rad].
      A 2-vector (wx, wz) is accepted and converted to ``atan2(wz, wx)``.
    - ``fetch``: distance over which the wind has blown [m]; JONSWAP only (ignored by Phillips).
    - ``spectrum``: ``"phillips"`` or ``"jonswap"`` (see ``sim.spectrum`` for the formulas).
    - ``amplitude``: dimensionless scale on the wave heights (the spectrum scales by its square);
      1 is the physical spectrum, 0 is flat water.
    - ``small_wave_cutoff``: wavelength l_c [m] below which waves are suppressed: the spectrum is
      multiplied by exp(-k^2 l^2) with Tessendorf's l = l_c / (2 pi), i.e. exp(-(l_c/lambda)^2),
      so a wave of wavelength l_c keeps 1/e of its power. 0 disables the cutoff.
    - ``choppiness``: lambda >= 0, scale of the horizontal (choppy) displacement; 0 = heights only.
    - ``seed``: non-negative integer seed of the Gaussian draw of h0(k).
    """

    resolution: int = 256
    patch_size: float = 4.0
    depth: float = 1.5
    wind_speed: float = 3.0
    wind_direction: float = 0.0
    fetch: float = 50.0
    spectrum: str = "jonswap"
    amplitude: float = 1.0
    small_wave_cutoff: float = 0.01
    choppiness: float = 0.8
    seed: int = 1

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalise fields once, here
        n = self.resolution
        if isinstance(n, bool) or not isinstance(n, Integral):
            raise _fail("resolution", n, "expected an integer power of two")
        if n < MIN_RESOLUTION or n > MAX_RESOLUTION or (n & (n - 1)) != 0:
            raise _fail("resolution", n,
                        f"must be a power of two in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], e.g. 256")
        set_(self, "resolution", int(n))
        set_(self, "patch_size", check_finite("patch_size", self.patch_size, 0.0, strict=True,
                                              maximum=MAX_PATCH_SIZE))
        set_(self, "depth", check_finite("depth", self.depth, 0.0, strict=True, allow_inf=True, maximum=MAX_DEPTH))
        set_(self, "wind_speed", check_finite("wind_speed", self.wind_speed, 0.0, strict=True,
                                              maximum=MAX_WIND_SPEED))
        set_(self, "wind_direction", _wind_angle(self.wind_direction))
        set_(self, "fetch", check_finite("fetch", self.fetch, 0.0, strict=True, maximum=MAX_FETCH))
        if not isinstance(self.spectrum, str) or self.spectrum.lower() not in SPECTRA:
            raise _fail("spectrum", self.spectrum, f"must be one of {SPECTRA}")
        set_(self, "spectrum", self.spectrum.lower())
        set_(self, "amplitude", check_finite("amplitude", self.amplitude, 0.0, maximum=MAX_AMPLITUDE))
        set_(self, "small_wave_cutoff",
             check_finite("small_wave_cutoff", self.small_wave_cutoff, 0.0, maximum=MAX_SMALL_WAVE_CUTOFF))
        set_(self, "choppiness", check_finite("choppiness", self.choppiness, 0.0, maximum=MAX_CHOPPINESS))
        if isinstance(self.seed, bool) or not isinstance(self.seed, Integral) or not 0 <= self.seed <= MAX_SEED:
            raise _fail("seed", self.seed, f"expected an integer in [0, {MAX_SEED}]")
        set_(self, "seed", int(self.seed))

    def to_dict(self) -> dict[str, Any]:
        """Plain ``{key: scalar}`` of every field (the ``cisp:water:<key>`` USD attributes)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "WaterParams":
        """Inverse of ``to_dict``; missing keys take defaults, unknown keys are rejected."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise _fail("keys", unknown,
                        f"unknown WaterParams keys; known keys are {sorted(known)}")
        return cls(**dict(values))

    def replace(self, **changes: Any) -> "WaterParams":
        """Copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @property
    def wind_vector(self) -> tuple[float, float]:
        """Unit wind direction (x, z) in the water plane."""
        return (math.cos(self.wind_direction), math.sin(self.wind_direction))


def _wind_angle(value: Any) -> float:
    """Wind direction as an angle [rad] from an angle or an (x, z) 2-vector."""
    if isinstance(value, (tuple, list)) or hasattr(value, "__len__"):
        try:
            wx, wz = (float(c) for c in value)
        except (TypeError, ValueError):
            raise _fail("wind_direction", value, "expected an angle [rad] or a 2-vector (x, z)")
        if not (math.isfinite(wx) and math.isfinite(wz)) or not 1e-30 < math.hypot(wx, wz) < 1e30:
            raise _fail("wind_direction", value, "2-vector must be finite and non-zero")
        return math.atan2(wz, wx)
    return check_finite("wind_direction", value, -1e6, maximum=1e6)
