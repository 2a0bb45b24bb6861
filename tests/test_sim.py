"""Tests of the FFT water (sim/): Warp FFT and surface against numpy twins, physics, mesh, LOD.

Every kernel test runs on each ``device`` (cpu, and cuda:0 when present). Sizes are tiny.
Errors are relative to the largest magnitude of the reference, measured against float64 numpy.
"""

import math

import numpy as np
import pytest
import warp as wp

from sim import FFTWater, InverseFFT2D, WaterMesh, WaterParams
from sim.spectrum import (GRAVITY, initial_amplitudes, peak_wavelength, wavenumber_spectrum,
                          wavenumbers)


def small_params(**changes):
    """A small pool patch: JONSWAP, 1 m patch, choppy."""
    base = dict(resolution=32, patch_size=1.0, depth=1.5, wind_speed=3.0, wind_direction=0.3,
                fetch=50.0, spectrum="jonswap", amplitude=1.0, small_wave_cutoff=0.02,
                choppiness=0.8, seed=7)
    base.update(changes)
    return WaterParams(**base)


def as_complex(packed: np.ndarray) -> np.ndarray:
    """(..., 2) float (re, im) -> complex128."""
    return packed[..., 0].astype(np.float64) + 1j * packed[..., 1].astype(np.float64)


def relative_error(value: np.ndarray, reference: np.ndarray) -> float:
    """max |value - reference| / max |reference|."""
    return float(np.max(np.abs(value - reference)) / np.max(np.abs(reference)))


def numpy_twin(params: WaterParams, t: float) -> dict:
    """Naive float64 twin of FFTWater.evaluate: eight separate numpy.fft transforms."""
    n = params.resolution
    kx, kz = wavenumbers(n, params.patch_size)
    k = np.hypot(kx, kz)
    if math.isinf(params.depth):
        omega = np.sqrt(GRAVITY * k)
    else:
        omega = np.sqrt(GRAVITY * k * np.tanh(k * params.depth))
    h0 = initial_amplitudes(params)
    h0_minus = np.roll(np.flip(h0, (0, 1)), 1, axis=(0, 1))  # h0(-k) in FFT order
    h_k = h0 * np.exp(-1j * omega * t) + np.conj(h0_minus) * np.exp(1j * omega * t)
    inv_k = np.divide(1.0, k, out=np.zeros_like(k), where=k > 0)
    lam = params.choppiness

    def field(factor):
        return np.fft.ifft2(factor * h_k) * n * n

    out = {"height_complex": field(1.0)}
    out["height"] = out["height_complex"].real
    out["displacement"] = np.stack([field(-1j * lam * kx * inv_k).real,
                                    field(-1j * lam * kz * inv_k).real], axis=-1)
    out["slope"] = np.stack([field(1j * kx).real, field(1j * kz).real], axis=-1)
    dxx = field(lam * kx * kx * inv_k).real
    dzz = field(lam * kz * kz * inv_k).real
    dxz = field(lam * kx * kz * inv_k).real
    out["displacement_gradient"] = np.stack([dxx, dzz, dxz], axis=-1)
    out["jacobian"] = (1.0 + dxx) * (1.0 + dzz) - dxz**2
    return out


# --------------------------------------------------------------------------------------------
# FFT


@pytest.mark.parametrize("n", [8, 16, 32, 64, 128, 256, 512])
def test_inverse_fft_matches_numpy(device, n):
    rng = np.random.default_rng(n)
    fields = 2
    spectrum = rng.standard_normal((fields, n, n)) + 1j * rng.standard_normal((fields, n, n))
    fft = InverseFFT2D(fields, n, device)
    fft.data.assign(np.stack([spectrum.real, spectrum.imag], axis=-1).astype(np.float32))
    fft.run()
    result = as_complex(fft.data.numpy())
    reference = np.fft.ifft2(spectrum, axes=(1, 2)) * n * n
    assert fft.launch_count == 2 * math.ceil(math.log2(n) / 2)  # radix 4, one radix 2 if odd
    assert relative_error(result, reference) <= 1e-5


def test_parseval(device):
    params = small_params(resolution=64)
    water = FFTWater(params, device)
    water.evaluate_spectrum(0.9)
    spectral = as_complex(water.packed_fields.numpy())
    water.evaluate(0.9)
    spatial = as_complex(water.packed_fields.numpy())
    n = params.resolution
    for f in range(spectral.shape[0]):
        energy_x = np.sum(np.abs(spatial[f]) ** 2)
        energy_k = n * n * np.sum(np.abs(spectral[f]) ** 2)
        assert abs(energy_x - energy_k) <= 1e-5 * energy_k
    # and for the heights alone (packed[0] = h + i dDx/dz, so use choppiness 0)
    calm = FFTWater(params.replace(choppiness=0.0), device)
    calm.evaluate_spectrum(0.9)
    h_k = as_complex(calm.packed_fields.numpy()[0])
    calm.evaluate(0.9)
    heights = calm.height.numpy().astype(np.float64)
    assert abs(np.sum(heights**2) - n * n * np.sum(np.abs(h_k) ** 2)) <= 1e-5 * np.sum(heights**2)


# --------------------------------------------------------------------------------------------
# Surface


def test_heights_are_real(device):
    """h(k,t) is Hermitian: alone through the Warp FFT (choppiness 0 leaves packed[0] = h) its
    imaginary part vanishes."""
    params = small_params(resolution=64, choppiness=0.0)
    water = FFTWater(params, device)
    water.evaluate_spectrum(1.7)
    h_k = as_complex(water.packed_fields.numpy()[0])
    h_minus_k = np.roll(np.flip(h_k, (0, 1)), 1, axis=(0, 1))
    assert np.max(np.abs(h_k - np.conj(h_minus_k))) <= 1e-6 * np.max(np.abs(h_k))
    water.evaluate(1.7)
    heights = as_complex(water.packed_fields.numpy()[0])
    rms = np.sqrt(np.mean(heights.real**2))
    assert rms > 0.0
    assert np.max(np.abs(heights.imag)) <= 1e-6 * rms


@pytest.mark.parametrize("spectrum", ["jonswap", "phillips"])
def test_surface_matches_numpy_twin(device, spectrum):
    params = small_params(spectrum=spectrum, resolution=32)
    water = FFTWater(params, device)
    t = 2.3
    water.evaluate(t)
    twin = numpy_twin(params, t)
    assert water.launches_per_frame == 2 + 2 * 3  # spectrum, 2 x (4 x 4 x 2) stages, unpack
    for name in ("height", "displacement", "slope", "displacement_gradient", "jacobian"):
        value = getattr(water, name).numpy()
        reference = twin[name] - (1.0 if name == "jacobian" else 0.0)
        if name == "jacobian":
            value = value - 1.0
        assert relative_error(value, reference) <= 1e-5, name


def test_deep_water_is_finite_and_matches_twin(device):
    params = small_params(depth=math.inf, spectrum="phillips")
    water = FFTWater(params, device)
    water.evaluate(0.7)
    height = water.height.numpy()
    assert np.all(np.isfinite(height)) and np.any(height != 0.0)
    assert relative_error(height, numpy_twin(params, 0.7)["height"]) <= 1e-5


def test_zero_choppiness_gives_no_horizontal_displacement(device):
    calm = FFTWater(small_params(choppiness=0.0), device)
    calm.evaluate(0.4)
    assert np.all(calm.displacement.numpy() == 0.0)
    assert np.all(calm.jacobian.numpy() == 1.0)
    assert np.any(calm.height.numpy() != 0.0)
    choppy = FFTWater(small_params(choppiness=0.8), device)
    choppy.evaluate(0.4)
    assert np.max(np.abs(choppy.displacement.numpy())) > 0.1 * np.max(np.abs(calm.height.numpy()))


def test_single_mode_period_uses_finite_depth_dispersion(device):
    """A single mode returns to itself after 2 pi / omega(k) with omega^2 = g k tanh(k h), and not
    after the deep-water period 2 pi / sqrt(g k)."""
    n, patch, depth, mode = 16, 4.0, 0.3, 1
    params = small_params(resolution=n, patch_size=patch, depth=depth, choppiness=0.0)
    amplitude = 0.01 * np.exp(0.4j)
    h0 = np.zeros((n, n), dtype=np.complex128)
    h0[0, mode] = amplitude
    water = FFTWater(params, device, h0=h0)
    k = 2.0 * np.pi * mode / patch
    omega = math.sqrt(GRAVITY * k * math.tanh(k * depth))
    omega_deep = math.sqrt(GRAVITY * k)
    t0 = 0.37

    def heights(t):
        water.evaluate(t)
        return water.height.numpy().astype(np.float64)

    x = np.arange(n) * patch / n
    expected = 2.0 * np.real(amplitude * np.exp(1j * (k * x - omega * t0)))  # travels along +x
    start = heights(t0)
    assert np.max(np.abs(start - expected[None, :])) <= 1e-6
    assert np.max(np.abs(heights(t0 + 2.0 * np.pi / omega) - start)) <= 1e-6
    # 10^5 periods later (~3 days of animation) the phase is still exact (reduced in float64)
    assert np.max(np.abs(heights(t0 + 1e5 * 2.0 * np.pi / omega) - start)) <= 1e-6
    assert np.max(np.abs(heights(t0 + 2.0 * np.pi / omega_deep) - start)) >= 0.5 * abs(amplitude)


def test_spectral_slope_matches_finite_differences(device):
    """Spectral dh/dx, dh/dz and the normals (-hx, 1, -hz) against 6th-order central differences
    of a finely sampled height field (cutoff at 16 grid cells, where the FD truncation error is
    ~2e-4 of the largest slope; a wrong sign, axis or factor errs by O(1))."""
    n, patch = 128, 1.0
    params = small_params(resolution=n, patch_size=patch, choppiness=0.0,
                          small_wave_cutoff=16.0 * patch / n)
    water = FFTWater(params, device)
    water.evaluate(0.8)
    h = water.height.numpy().astype(np.float64)
    spacing = patch / n

    def derivative(axis):
        def shift(s):
            return np.roll(h, -s, axis=axis)
        return (shift(3) - 9.0 * shift(2) + 45.0 * shift(1) - 45.0 * shift(-1) + 9.0 * shift(-2)
                - shift(-3)) / (60.0 * spacing)

    slope_fd = np.stack([derivative(1), derivative(0)], axis=-1)
    slope = water.slope.numpy()
    assert relative_error(slope, slope_fd) <= 1e-3

    def normals(s):
        v = np.stack([-s[..., 0], np.ones(s.shape[:-1]), -s[..., 1]], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    cos_angle = np.sum(normals(slope) * normals(slope_fd), axis=-1)
    max_angle = np.arccos(np.clip(cos_angle, -1.0, 1.0)).max()
    max_tilt = np.arccos(normals(slope)[..., 1]).max()
    assert max_tilt > 0.05  # the surface is not flat
    assert max_angle <= 2e-3 * max_tilt


def test_choppy_mesh_normals_match_finite_differences(device):
    """With choppiness, mesh normals (from the Jacobian terms) against the normal of 6th-order
    differences of the displaced vertex positions on the grid nodes."""
    n, patch = 128, 1.0
    params = small_params(resolution=n, patch_size=patch, choppiness=1.0, amplitude=3.0,
                          small_wave_cutoff=16.0 * patch / n)
    water = FFTWater(params, device)
    mesh = WaterMesh(water, rect=(0.0, 0.0, patch, patch), y0=0.0, vertex_counts=(n + 1, n + 1),
                     pin_border=False)
    mesh.update(1.1)
    points = mesh.points.numpy().astype(np.float64).reshape(n + 1, n + 1, 3)
    normals = mesh.normals.numpy().reshape(n + 1, n + 1, 3)
    spacing = patch / n
    inner = slice(3, n - 2)

    def derivative(axis):
        def shift(s):
            return np.roll(points, -s, axis=axis)
        return (shift(3) - 9.0 * shift(2) + 45.0 * shift(1) - 45.0 * shift(-1) + 9.0 * shift(-2)
                - shift(-3)) / (60.0 * spacing)

    tangent_x, tangent_z = derivative(1), derivative(0)
    normal_fd = np.cross(tangent_z, tangent_x)
    normal_fd /= np.linalg.norm(normal_fd, axis=-1, keepdims=True)
    cos_angle = np.sum(normals[inner, inner] * normal_fd[inner, inner], axis=-1)
    max_angle = np.arccos(np.clip(cos_angle, -1.0, 1.0)).max()
    # the choppy normal differs visibly from the height-only normal, and FD agrees with it
    slope_normal = np.stack([-tangent_x[..., 1], np.ones((n + 1, n + 1)), -tangent_z[..., 1]], -1)
    slope_normal /= np.linalg.norm(slope_normal, axis=-1, keepdims=True)
    chop_angle = np.arccos(np.clip(np.sum(normals * slope_normal, -1), -1, 1))[inner, inner].max()
    print(f"choppy normal vs FD: {max_angle:.2e} rad; choppy vs height-only: {chop_angle:.2e} rad")
    assert chop_angle > 10.0 * max_angle
    assert max_angle <= 1e-3


def test_same_seed_same_surface_different_seed_different(device):
    a = FFTWater(small_params(seed=3), device)
    b = FFTWater(small_params(seed=3), device)
    c = FFTWater(small_params(seed=4), device)
    for water in (a, b, c):
        water.evaluate(1.25)
    for name in ("height", "displacement", "slope", "jacobian"):
        assert np.array_equal(getattr(a, name).numpy(), getattr(b, name).numpy()), name
    ha, hc = a.height.numpy(), c.height.numpy()
    assert np.sqrt(np.mean((ha - hc) ** 2)) > 0.5 * np.sqrt(np.mean(ha**2))


def test_evaluate_writes_in_place(device):
    water = FFTWater(small_params(), device)
    names = ("height", "displacement", "slope", "jacobian")
    pointers = [getattr(water, name).ptr for name in names]
    water.evaluate(0.1)
    first = water.height.numpy().copy()
    water.evaluate(0.6)
    assert [getattr(water, name).ptr for name in names] == pointers
    assert not np.array_equal(first, water.height.numpy())


def test_evaluate_is_graph_capturable(device):
    """On CUDA, one frame records into a CUDA graph (no allocation, no host sync) and replays."""
    if not wp.get_device(device).is_cuda:
        pytest.skip("CUDA graphs need a CUDA device")
    water = FFTWater(small_params(), device)
    water.evaluate(0.5)
    direct = water.height.numpy().copy()
    water.evaluate(0.0)
    with wp.ScopedCapture(device=device) as capture:
        water.evaluate(0.5)
    wp.capture_launch(capture.graph)
    assert np.array_equal(water.height.numpy(), direct)


def test_spectrum_variance_and_peak():
    """The discrete spectrum holds the variance the seeded draw realises, peaked near lambda_p."""
    params = small_params(resolution=128, patch_size=2.0, small_wave_cutoff=0.0)
    psi = wavenumber_spectrum(params)
    dk = 2.0 * np.pi / params.patch_size
    variance = np.sum(psi) * dk * dk
    kx, kz = wavenumbers(params.resolution, params.patch_size)
    k_peak = np.hypot(kx, kz).ravel()[np.argmax(psi * np.hypot(kx, kz))]
    assert abs(2.0 * np.pi / k_peak - peak_wavelength(params)) <= 0.25 * peak_wavelength(params)
    # over many seeds the realised height variance matches sum(Psi) dk^2
    samples = []
    for seed in range(40):
        h0 = initial_amplitudes(params.replace(seed=seed))
        h0_minus = np.roll(np.flip(h0, (0, 1)), 1, axis=(0, 1))
        h_k = h0 + np.conj(h0_minus)
        samples.append(np.mean((np.fft.ifft2(h_k).real * params.resolution**2) ** 2))
    assert abs(np.mean(samples) / variance - 1.0) <= 0.1


@pytest.mark.parametrize("spectrum", ["jonswap", "phillips"])
def test_waves_run_downwind(spectrum):
    """The spectrum's energy-weighted mean direction is the wind direction, and with
    h(k,t) = h0 e^{-i w t} + ... (see sim.water) each component travels along +k."""
    params = small_params(spectrum=spectrum, wind_direction=2.0)
    params = params.replace(patch_size=4.0 * peak_wavelength(params), resolution=64)
    psi = wavenumber_spectrum(params)
    kx, kz = wavenumbers(params.resolution, params.patch_size)
    k = np.hypot(kx, kz)
    k[k == 0.0] = 1.0
    mean = np.array([np.sum(psi * kx / k), np.sum(psi * kz / k)])
    assert abs(math.atan2(mean[1], mean[0]) - 2.0) <= 0.02
    assert np.sum(psi[(kx * math.cos(2.0) + kz * math.sin(2.0)) < 0.0]) < 0.05 * np.sum(psi)
