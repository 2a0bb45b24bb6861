"""Wave spectra, dispersion and the seeded initial amplitudes h0(k) (host side, numpy, float64).

Runs once per ``FFTWater`` at setup; nothing here is on the per-frame path.

Conventions (shared with ``sim.water`` and the tests)
-----------------------------------------------------
Grid: x_n = n L / N, z_n = n L / N, n = 0..N-1. Arrays are indexed ``[row, column] = [z, x]``.
Wavenumbers: k = 2 pi m / L with m in [-N/2, N/2), stored in FFT order (index j holds m = j for
j < N/2 and m = j - N otherwise), so the surface is the *unnormalised inverse DFT*

    f(x) = sum_k F(k) exp(+i k.x)        (== N*N * numpy.fft.ifft2(F))

Spectrum normalisation: ``wavenumber_spectrum`` returns the directional variance spectrum
Psi(kx, kz) [m^4] with integral Psi d^2k = <eta^2> (before the cutoff). A component h0(k) becomes
the travelling wave 2 Re(h0 exp(i(k.x - omega t))) of variance 2|h0|^2, so
<|h0(k)|^2> = Psi(k) dk^2 / 2 with dk = 2 pi / L, and the heights have the spectrum's variance.

The zero mode (mean level) and the Nyquist row and column (m = -N/2 in either axis, which has no
distinct -k partner on the grid, so its derivatives cannot be Hermitian) are set to zero.
"""

from __future__ import annotations

import math

import numpy as np

from .params import WaterParams

#: Standard gravity [m/s^2].
GRAVITY = 9.81
#: Phillips constant alpha (Phillips 1958; Tessendorf's "A" up to normalisation).
PHILLIPS_ALPHA = 0.0081
#: JONSWAP peak enhancement factor gamma (Hasselmann et al. 1973, mean value).
JONSWAP_GAMMA = 3.3


def wavenumbers(resolution: int, patch_size: float) -> tuple[np.ndarray, np.ndarray]:
    """(kx, kz) [rad/m], each shape (N, N) float64 in FFT order, indexed [z, x]."""
    k1 = 2.0 * np.pi * np.fft.fftfreq(resolution, d=patch_size / resolution)
    kz, kx = np.meshgrid(k1, k1, indexing="ij")
    return kx, kz


def dispersion(k: np.ndarray, depth: float) -> np.ndarray:
    """Finite-depth angular frequency omega(k) = sqrt(g k tanh(k h)) [rad/s]; h = inf is deep."""
    k = np.asarray(k, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # 0 * inf at k = 0 in deep water
        kh = np.where(k > 0.0, k * depth, 0.0)
    return np.sqrt(GRAVITY * k * np.tanh(kh))


def dispersion_slope(k: np.ndarray, depth: float) -> np.ndarray:
    """Group velocity d omega / d k [m/s] of the finite-depth dispersion (k > 0)."""
    k = np.asarray(k, dtype=np.float64)
    kh = np.minimum(k * depth, 350.0)  # cosh overflows past ~710; tanh is 1 there anyway
    omega = dispersion(k, depth)
    return GRAVITY * (np.tanh(kh) + kh / np.cosh(kh) ** 2) / (2.0 * omega)


def wavenumber_of_frequency(omega: float, depth: float) -> float:
    """Invert the finite-depth dispersion: k with omega(k) = omega (Newton from the deep root)."""
    k = omega * omega / GRAVITY
    for _ in range(50):
        f = dispersion(k, depth) - omega
        k_next = max(k - f / dispersion_slope(k, depth), 0.5 * k)
        if abs(k_next - k) <= 1e-14 * k:
            break
        k = k_next
    return float(k)


def jonswap_peak_frequency(params: WaterParams) -> float:
    """JONSWAP peak angular frequency omega_p = 22 (g^2 / (U F))^(1/3) [rad/s]."""
    return 22.0 * (GRAVITY**2 / (params.wind_speed * params.fetch)) ** (1.0 / 3.0)


def peak_wavelength(params: WaterParams) -> float:
    """Wavelength [m] at the peak of the omnidirectional spectrum.

    JONSWAP: the finite-depth wavelength of omega_p. Phillips: the maximum of
    k^-3 exp(-1/(k L_w)^2), k_p = sqrt(2/3) / L_w with L_w = U^2 / g.
    """
    if params.spectrum == "jonswap":
        k_p = wavenumber_of_frequency(jonswap_peak_frequency(params), params.depth)
    else:
        k_p = math.sqrt(2.0 / 3.0) * GRAVITY / params.wind_speed**2
    return 2.0 * math.pi / k_p


def _relative_angle(kx: np.ndarray, kz: np.ndarray, wind_direction: float) -> np.ndarray:
    """Angle between the wave vector and the wind, wrapped to (-pi, pi]."""
    theta = np.arctan2(kz, kx) - wind_direction
    return np.angle(np.exp(1j * theta))


def phillips_spectrum(kx: np.ndarray, kz: np.ndarray, params: WaterParams) -> np.ndarray:
    """Phillips spectrum Psi(k) [m^4] (Tessendorf eq. 40), with a normalised spreading.

    Psi = alpha/2 k^-4 exp(-1/(k L_w)^2) D(theta), L_w = U^2/g, alpha = 0.0081, and the
    downwind-only cos^2 spreading D = (2/pi) cos^2(theta) for |theta| < pi/2, 0 otherwise
    (Tessendorf's |k.w|^2 factor, with his suggested suppression of waves against the wind,
    normalised so that the omnidirectional spectrum is Phillips' alpha/2 k^-3).
    """
    k = np.hypot(kx, kz)
    l_wind = params.wind_speed**2 / GRAVITY
    theta = _relative_angle(kx, kz, params.wind_direction)
    spreading = np.where(np.abs(theta) < 0.5 * np.pi, (2.0 / np.pi) * np.cos(theta) ** 2, 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        psi = 0.5 * PHILLIPS_ALPHA * np.exp(-1.0 / (k * l_wind) ** 2) / k**4 * spreading
    return np.where(k > 0.0, psi, 0.0)


def donelan_banner_spreading(omega: np.ndarray, omega_p: float, theta: np.ndarray) -> np.ndarray:
    """Donelan-Banner directional spreading D(omega, theta) [1/rad], integral over theta = 1.

    D = beta / (2 tanh(beta pi)) sech^2(beta theta), beta from Donelan, Hamilton & Hui (1985)
    with Banner's (1990) extension above 1.6 omega_p (as used by Horvath 2015 for JONSWAP).
    Chosen over cos^2s because it is fitted to wind seas and narrows at the peak.
    """
    r = omega / omega_p
    with np.errstate(divide="ignore", over="ignore"):
        beta_banner = 10.0 ** (-0.4 + 0.8393 * np.exp(-0.567 * np.log(r * r)))
        beta = np.where(r < 0.95, 2.61 * r**1.3, np.where(r < 1.6, 2.28 * r**-1.3, beta_banner))
        beta = np.where(r < 0.56, 2.61 * 0.56**1.3, beta)  # below the fit: hold the edge value
        return beta / (2.0 * np.tanh(beta * np.pi)) / np.cosh(beta * theta) ** 2


def tma_depth_factor(omega: np.ndarray, depth: float) -> np.ndarray:
    """Kitaigorodskii depth attenuation phi(omega, h) of the TMA spectrum (Bouws et al. 1985)."""
    w_h = omega * np.sqrt(depth / GRAVITY)
    return np.where(w_h <= 1.0, 0.5 * w_h**2,
                    np.where(w_h < 2.0, 1.0 - 0.5 * (2.0 - w_h) ** 2, 1.0))


def jonswap_spectrum(kx: np.ndarray, kz: np.ndarray, params: WaterParams) -> np.ndarray:
    """JONSWAP (TMA in finite depth) spectrum Psi(k) [m^4] with Donelan-Banner spreading.

    S(omega) = alpha g^2 omega^-5 exp(-5/4 (omega_p/omega)^4) gamma^r,
    r = exp(-(omega - omega_p)^2 / (2 sigma^2 omega_p^2)),
    sigma = 0.07 (omega <= omega_p) else 0.09,
    alpha = 0.076 (U^2/(F g))^0.22, omega_p = 22 (g^2/(U F))^(1/3), gamma = 3.3 (Hasselmann 1973).
    Converted to wavenumber: Psi(k) = S(omega) phi_TMA(omega, h) D(omega, theta) (d omega/dk) / k.
    """
    k = np.hypot(kx, kz)
    omega_p = jonswap_peak_frequency(params)
    alpha = 0.076 * (params.wind_speed**2 / (params.fetch * GRAVITY)) ** 0.22
    theta = _relative_angle(kx, kz, params.wind_direction)
    k_safe = np.where(k > 0.0, k, 1.0)
    omega = dispersion(k_safe, params.depth)
    sigma = np.where(omega <= omega_p, 0.07, 0.09)
    r = np.exp(-((omega - omega_p) ** 2) / (2.0 * sigma**2 * omega_p**2))
    s_omega = (alpha * GRAVITY**2 / omega**5 * np.exp(-1.25 * (omega_p / omega) ** 4)
               * JONSWAP_GAMMA**r)
    if math.isfinite(params.depth):
        s_omega = s_omega * tma_depth_factor(omega, params.depth)
    psi = (s_omega * donelan_banner_spreading(omega, omega_p, theta)
           * dispersion_slope(k_safe, params.depth) / k_safe)
    return np.where(k > 0.0, psi, 0.0)


def wavenumber_spectrum(params: WaterParams) -> np.ndarray:
    """Psi(k) [m^4] on the FFT grid, shape (N, N) float64, FFT order, indexed [z, x].

    Includes amplitude^2, the small-wave cutoff exp(-k^2 l^2) with l = small_wave_cutoff / (2 pi),
    and zeroes the mean and the Nyquist row/column.
    """
    n = params.resolution
    kx, kz = wavenumbers(n, params.patch_size)
    if params.spectrum == "jonswap":
        psi = jonswap_spectrum(kx, kz, params)
    else:
        psi = phillips_spectrum(kx, kz, params)
    l_cut = params.small_wave_cutoff / (2.0 * np.pi)
    psi = psi * np.exp(-(kx**2 + kz**2) * l_cut**2) * params.amplitude**2
    psi[n // 2, :] = 0.0
    psi[:, n // 2] = 0.0
    psi[0, 0] = 0.0
    return psi


def initial_amplitudes(params: WaterParams) -> np.ndarray:
    """h0(k) [m], shape (N, N) complex128, FFT order: (xi_r + i xi_i)/sqrt(2) * sqrt(Psi dk^2 / 2).

    xi_r, xi_i are standard normal draws from ``numpy.random.default_rng(seed)`` (PCG64), so the
    same (params, seed) give the same amplitudes bit for bit on every machine.
    """
    n = params.resolution
    dk = 2.0 * np.pi / params.patch_size
    xi = np.random.default_rng(params.seed).standard_normal((2, n, n))
    return (xi[0] + 1j * xi[1]) / np.sqrt(2.0) * np.sqrt(wavenumber_spectrum(params) * 0.5) * dk
