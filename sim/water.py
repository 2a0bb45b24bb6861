"""FFT water surface: spectral evolution, inverse FFT and the spatial fields, all in Warp kernels.

The surface at time t is a pure function of (params, seed, t), evaluated directly, never stepped.
Conventions (grid, wavenumbers, transform sign) are those of ``sim.spectrum`` and ``sim.fft``.

Time evolution. Tessendorf writes h(k,t) = h0(k) e^{+i w t} + conj(h0(-k)) e^{-i w t}; with the
transform sign exp(+i k.x) used here that moves each component h0(k) *against* k (phase
k.x + w t). We use the time-reversed form

    h(k, t) = h0(k) e^{-i w t} + conj(h0(-k)) e^{+i w t},   w = sqrt(g k tanh(k h)),

so h0(k) is the wave 2 Re(h0 e^{i(k.x - w t)}) travelling along +k, i.e. downwind where the
spectrum puts its energy. h(-k, t) = conj(h(k, t)), so the heights are real.

Fields, all from the same h(k, t) by exact spectral factors (k = |k|, lambda = choppiness):

    displacement  lambda D = sum -i lambda (k_vec / k) h e^{ik.x}            [m]
    slope         (dh/dx, dh/dz) = sum i k_vec h e^{ik.x}                     [1]
    gradient      (d lDx/dx, d lDz/dz, d lDx/dz) = sum lambda (kx^2, kz^2, kx kz) / k h e^{ik.x}
    jacobian      J = (1 + dDx/dx)(1 + dDz/dz) - (dDx/dz)^2   (dDx/dz == dDz/dx)   [1]

Packing: every field is real, so two Hermitian spectra A, B share one complex transform of
A + iB (real part A, imaginary part B). The eight real fields travel as four complex ones,
halving the FFT work:

    packed[0] = h        + i dDx/dz       packed[2] = dh/dx    + i dh/dz
    packed[1] = lambda Dx + i lambda Dz   packed[3] = dDx/dx   + i dDz/dz
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .fft import InverseFFT2D, complex_mul
from .params import SimParameterError, WaterParams
from .spectrum import dispersion, initial_amplitudes, wavenumbers

#: Number of packed complex fields (eight real fields, two per complex transform).
PACKED_FIELDS = 4
#: 2 pi in float64 for the phase reduction (a float32 2 pi drifts 1e-7 rad per period).
TWO_PI = wp.constant(wp.float64(2.0 * math.pi))


@wp.func
def signed_mode(index: int, resolution: int) -> float:
    """Mode number m in [-N/2, N/2) of FFT-order index ``index``."""
    m = index
    if index >= resolution // 2:
        m = index - resolution
    return float(m)


@wp.kernel
def evolve_spectrum_kernel(
    h0: wp.array2d(dtype=wp.vec2),  # (N, N) initial amplitudes h0(k) [m], complex, read
    omega: wp.array2d(dtype=wp.float64),  # (N, N) angular frequency w(|k|) [rad/s], read
    wavenumber_step: float,  # dk = 2 pi / L [rad/m]
    choppiness: float,  # lambda [1]
    t: wp.float64,  # time [s]
    packed: wp.array3d(dtype=wp.vec2),  # (4, N, N) packed spectra (see module doc), write
):
    """h(k, t) and its spectral derivatives, packed in pairs; dim (N, N) over [z, x]."""
    iz, ix = wp.tid()
    n = h0.shape[0]
    kx = wavenumber_step * signed_mode(ix, n)
    kz = wavenumber_step * signed_mode(iz, n)
    k = wp.sqrt(kx * kx + kz * kz)
    inv_k = float(0.0)
    if k > 0.0:
        inv_k = 1.0 / k
    # phase w t reduced in float64 so long animations keep their precision in float32 sin/cos
    phase = float(wp.mod(omega[iz, ix] * t, TWO_PI))
    rotor = wp.vec2(wp.cos(phase), -wp.sin(phase))  # e^{-i w t}
    h0_minus = h0[(n - iz) % n, (n - ix) % n]  # h0(-k)
    h0_minus_conj = wp.vec2(h0_minus[0], -h0_minus[1])
    h = complex_mul(h0[iz, ix], rotor) + complex_mul(h0_minus_conj, wp.vec2(rotor[0], -rotor[1]))
    lam_inv_k = choppiness * inv_k
    # each packed field is (a + i b) h with a, b the real fields' spectral factors
    packed[0, iz, ix] = complex_mul(wp.vec2(1.0, lam_inv_k * kx * kz), h)
    packed[1, iz, ix] = complex_mul(wp.vec2(lam_inv_k * kz, -lam_inv_k * kx), h)
    packed[2, iz, ix] = complex_mul(wp.vec2(-kz, kx), h)
    packed[3, iz, ix] = complex_mul(wp.vec2(lam_inv_k * kx * kx, lam_inv_k * kz * kz), h)


@wp.kernel
def unpack_fields_kernel(
    packed: wp.array3d(dtype=wp.vec2),  # (4, N, N) packed spatial fields, read
    height: wp.array2d(dtype=float),  # (N, N) h [m], write
    displacement: wp.array2d(dtype=wp.vec2),  # (N, N) (lambda Dx, lambda Dz) [m], write
    slope: wp.array2d(dtype=wp.vec2),  # (N, N) (dh/dx, dh/dz) [1], write
    displacement_gradient: wp.array2d(dtype=wp.vec3),  # (N, N) (dDx/dx, dDz/dz, dDx/dz), write
    jacobian: wp.array2d(dtype=float),  # (N, N) J [1], write
):
    """Split the packed transforms into the named real fields; dim (N, N) over [z, x]."""
    iz, ix = wp.tid()
    p0 = packed[0, iz, ix]
    p3 = packed[3, iz, ix]
    height[iz, ix] = p0[0]
    displacement[iz, ix] = packed[1, iz, ix]
    slope[iz, ix] = packed[2, iz, ix]
    displacement_gradient[iz, ix] = wp.vec3(p3[0], p3[1], p0[1])
    jacobian[iz, ix] = (1.0 + p3[0]) * (1.0 + p3[1]) - p0[1] * p0[1]


class FFTWater:
    """One periodic water patch; allocates once, ``evaluate(t)`` fills the fields in place.

    Read-only outputs after ``evaluate(t)`` (device arrays, indexed [z, x], sample (iz, ix) at
    x = ix L/N, z = iz L/N in patch coordinates):

    - ``height``: (N, N) float32, h [m] above the rest level.
    - ``displacement``: (N, N) vec2, horizontal displacement (x, z) [m], choppiness included.
    - ``slope``: (N, N) vec2, exact spectral (dh/dx, dh/dz) [1].
    - ``displacement_gradient``: (N, N) vec3, (dDx/dx, dDz/dz, dDx/dz) [1], choppiness included.
    - ``jacobian``: (N, N) float32, J of x -> x + D(x) [1]; J <= 0 where the surface folds.

    Setup-time data: ``h0`` (N, N) vec2 [m], ``omega`` (N, N) float64 [rad/s],
    ``packed_fields`` (4, N, N) vec2 (spectral after ``evaluate_spectrum``, spatial after
    ``evaluate``; see the module doc for the packing).

    ``h0`` may be given as an (N, N) complex array in FFT order to replace the seeded draw
    (single modes for tests, measured spectra); the Nyquist row/column must then be zero.
    """

    def __init__(self, params: WaterParams, device=None, h0: np.ndarray | None = None):
        if not isinstance(params, WaterParams):
            raise SimParameterError(f"params={params!r} is invalid: expected a WaterParams")
        self.params = params
        self.device = wp.get_device(device)
        n = params.resolution
        self.resolution = n
        self.patch_size = params.patch_size
        if h0 is None:
            h0 = initial_amplitudes(params)
        h0 = np.asarray(h0)
        if h0.shape != (n, n):
            raise SimParameterError(f"h0 shape {h0.shape} is invalid: expected ({n}, {n})")
        if np.any(h0[n // 2, :] != 0) or np.any(h0[:, n // 2] != 0):
            raise SimParameterError(
                "h0 is invalid: the Nyquist row and column (index N/2) must be zero, their "
                "spectral derivatives have no Hermitian partner on the grid")
        kx, kz = wavenumbers(n, params.patch_size)
        omega = dispersion(np.hypot(kx, kz), params.depth)

        self.h0 = wp.array(np.stack([h0.real, h0.imag], axis=-1).astype(np.float32),
                           dtype=wp.vec2, device=self.device)
        self.omega = wp.array(omega, dtype=wp.float64, device=self.device)
        self.fft = InverseFFT2D(PACKED_FIELDS, n, self.device)
        self.packed_fields = self.fft.data
        self.height = wp.zeros((n, n), dtype=float, device=self.device)
        self.displacement = wp.zeros((n, n), dtype=wp.vec2, device=self.device)
        self.slope = wp.zeros((n, n), dtype=wp.vec2, device=self.device)
        self.displacement_gradient = wp.zeros((n, n), dtype=wp.vec3, device=self.device)
        self.jacobian = wp.zeros((n, n), dtype=float, device=self.device)
        self.time = None  # time of the last evaluate(), None before the first

        self._evolve = wp.launch(
            evolve_spectrum_kernel, dim=(n, n),
            inputs=[self.h0, self.omega, 2.0 * math.pi / params.patch_size, params.choppiness,
                    0.0, self.packed_fields],
            device=self.device, record_cmd=True)
        self._unpack = wp.launch(
            unpack_fields_kernel, dim=(n, n),
            inputs=[self.packed_fields, self.height, self.displacement, self.slope,
                    self.displacement_gradient, self.jacobian],
            device=self.device, record_cmd=True)

    @property
    def launches_per_frame(self) -> int:
        """Kernel launches per ``evaluate``: spectrum, 2 ceil(log4 N) FFT stages, unpack."""
        return 2 + self.fft.launch_count

    def evaluate_spectrum(self, t: float) -> None:
        """Fill ``packed_fields`` with the packed spectra at time ``t`` [s] (no transform)."""
        t = float(t)
        if not math.isfinite(t):
            raise SimParameterError(f"t={t!r} is invalid: time must be finite seconds")
        self._evolve.set_param_by_name("t", t)
        self._evolve.launch()

    def evaluate(self, t: float) -> None:
        """Evaluate the surface at time ``t`` [s] into the output arrays (no allocation)."""
        self.evaluate_spectrum(t)
        self.fft.run()
        self._unpack.launch()
        self.time = float(t)
