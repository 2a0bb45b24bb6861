"""Batched inverse 2-D FFT in Warp kernels (radix-2 Stockham), on ``cpu`` and ``cuda``.

Transform (unnormalised inverse DFT, the sign convention of the whole package):

    f[z, x] = sum_{mz, mx} F[mz, mx] exp(+2 pi i (mz z + mx x) / N)   (== N*N * numpy.fft.ifft2)

applied to every field of a complex array of shape (fields, N, N), complex stored as wp.vec2
(re, im). One launch runs one radix-2 stage over all rows (or all columns) of all fields, so a
transform is 2 log2(N) launches whatever the number of fields.

Stockham autosort: stage s (stride s = 2^stage, sub-length n = N / s, half m = n / 2) reads
``src`` and writes ``dst``

    y[q + s (2p)]     = x[q + s p] + x[q + s (p + m)]
    y[q + s (2p + 1)] = (x[q + s p] - x[q + s (p + m)]) * w^(p s),   w = exp(+2 pi i / N)

for p < m, q < s; after log2 N stages the result is in natural order, no bit reversal.
Buffers ping-pong; 2 log2 N is even, so the result lands back in ``data``.
"""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.func
def complex_mul(a: wp.vec2, b: wp.vec2) -> wp.vec2:
    """(a.x + i a.y) (b.x + i b.y) as vec2 (re, im)."""
    return wp.vec2(a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0])


@wp.kernel
def stockham_rows_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    twiddle: wp.array(dtype=wp.vec2),  # (N/2,) exp(+2 pi i k / N), read
    half: int,  # m = n / 2, half the current sub-transform length
    stride: int,  # s = N / n
):
    """One Stockham stage along the last axis (x) for every row of every field; dim (F, N, N/2)."""
    f, row, b = wp.tid()
    p = b // stride
    q = b - p * stride
    a = src[f, row, q + stride * p]
    c = src[f, row, q + stride * (p + half)]
    dst[f, row, q + stride * 2 * p] = a + c
    dst[f, row, q + stride * (2 * p + 1)] = complex_mul(a - c, twiddle[p * stride])


@wp.kernel
def stockham_columns_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    twiddle: wp.array(dtype=wp.vec2),  # (N/2,) exp(+2 pi i k / N), read
    half: int,
    stride: int,
):
    """One Stockham stage along the middle axis (z); dim (F, N/2, N), column fastest (coalesced)."""
    f, b, col = wp.tid()
    p = b // stride
    q = b - p * stride
    a = src[f, q + stride * p, col]
    c = src[f, q + stride * (p + half), col]
    dst[f, q + stride * 2 * p, col] = a + c
    dst[f, q + stride * (2 * p + 1), col] = complex_mul(a - c, twiddle[p * stride])


def inverse_twiddles(resolution: int) -> np.ndarray:
    """exp(+2 pi i k / N) for k < N/2 as (N/2, 2) float32, computed in float64."""
    angle = 2.0 * np.pi * np.arange(resolution // 2) / resolution
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1).astype(np.float32)


class InverseFFT2D:
    """In-place batched inverse 2-D FFT of ``data`` (fields, N, N) vec2, allocated once.

    ``data`` (read-write, owned): complex fields, spectral before ``run()``, spatial after.
    ``scratch`` (owned): ping-pong partner. ``twiddle`` (N/2,) vec2, precomputed.
    The 2 log2 N stage launches are recorded once and replayed by ``run()``.
    """

    def __init__(self, fields: int, resolution: int, device=None):
        n = int(resolution)
        if n < 2 or n & (n - 1):
            raise ValueError(f"resolution={resolution!r}: must be a power of two >= 2")
        self.device = wp.get_device(device)
        self.fields = int(fields)
        self.resolution = n
        self.data = wp.zeros((self.fields, n, n), dtype=wp.vec2, device=self.device)
        self.scratch = wp.zeros_like(self.data)
        self.twiddle = wp.array(inverse_twiddles(n), dtype=wp.vec2, device=self.device)
        self._stages = []
        buffers = (self.data, self.scratch)
        for kernel, dim in ((stockham_rows_kernel, (self.fields, n, n // 2)),
                            (stockham_columns_kernel, (self.fields, n // 2, n))):
            half, stride = n // 2, 1
            while half >= 1:
                src, dst = buffers
                self._stages.append(wp.launch(kernel, dim=dim,
                                              inputs=[src, dst, self.twiddle, half, stride],
                                              device=self.device, record_cmd=True))
                buffers = (dst, src)
                half, stride = half // 2, stride * 2
        assert buffers[0] is self.data  # even number of stages: result back in ``data``

    @property
    def launch_count(self) -> int:
        return len(self._stages)

    def run(self) -> None:
        """Transform ``data`` in place (no allocation, no host copy)."""
        for stage in self._stages:
            stage.launch()
