"""Batched inverse 2-D FFT in Warp kernels (Stockham radix-4, radix-2 for odd log2 N), on
``cpu`` and ``cuda``.

Transform (unnormalised inverse DFT, the sign convention of the whole package):

    f[z, x] = sum_{mz, mx} F[mz, mx] exp(+2 pi i (mz z + mx x) / N)   (== N*N * numpy.fft.ifft2)

applied to every field of a complex array of shape (fields, N, N), complex stored as wp.vec2
(re, im). One launch runs one stage over all rows (or all columns) of all fields, so a
transform is 2 ceil(log4 N) launches whatever the number of fields.

Stockham autosort (after OTFFT's formulation), stride s, current sub-length n = N / s, with
w = exp(+2 pi i / N):

    radix 4 (n >= 4, quarter r = n/4, p < r, q < s), x_j = x[q + s (p + j r)]:
        y[q + s (4p)]     = (x0 + x2) + (x1 + x3)
        y[q + s (4p + 1)] = ((x0 - x2) + i (x1 - x3)) w^(p s)
        y[q + s (4p + 2)] = ((x0 + x2) - (x1 + x3)) w^(2 p s)
        y[q + s (4p + 3)] = ((x0 - x2) - i (x1 - x3)) w^(3 p s)
        then s *= 4
    radix 2 (n == 2, last stage when log2 N is odd):
        y[q] = x[q] + x[q + s],  y[q + s] = x[q] - x[q + s]

After the stages the result is in natural order (no bit reversal). Buffers ping-pong; rows and
columns take the same number of stages, so the count is even and the result lands back in
``data``. Radix 4 halves the passes over memory (and the per-thread overhead on the CPU)
compared with radix 2.
"""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.func
def complex_mul(a: wp.vec2, b: wp.vec2) -> wp.vec2:
    """(a.x + i a.y) (b.x + i b.y) as vec2 (re, im)."""
    return wp.vec2(a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0])


@wp.func
def times_i(a: wp.vec2) -> wp.vec2:
    """i (a.x + i a.y)."""
    return wp.vec2(-a[1], a[0])


@wp.kernel
def radix4_rows_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    twiddle: wp.array(dtype=wp.vec2),  # (N,) exp(+2 pi i k / N), read
    quarter: int,  # r = n / 4, a quarter of the current sub-transform length
    stride: int,  # s = N / n
    log2_stride: int,  # log2(s): p = b / s, q = b % s by shift and mask (no integer division)
):
    """One radix-4 stage along the last axis (x) of every row of every field; dim (F, N, N/4)."""
    f, row, b = wp.tid()
    p = b >> log2_stride
    q = b & (stride - 1)
    x0 = src[f, row, q + stride * p]
    x1 = src[f, row, q + stride * (p + quarter)]
    x2 = src[f, row, q + stride * (p + 2 * quarter)]
    x3 = src[f, row, q + stride * (p + 3 * quarter)]
    sum02 = x0 + x2
    dif02 = x0 - x2
    sum13 = x1 + x3
    idif13 = times_i(x1 - x3)
    ps = p * stride
    out = q + stride * 4 * p
    dst[f, row, out] = sum02 + sum13
    dst[f, row, out + stride] = complex_mul(dif02 + idif13, twiddle[ps])
    dst[f, row, out + 2 * stride] = complex_mul(sum02 - sum13, twiddle[2 * ps])
    dst[f, row, out + 3 * stride] = complex_mul(dif02 - idif13, twiddle[3 * ps])


@wp.kernel
def radix4_columns_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    twiddle: wp.array(dtype=wp.vec2),  # (N,) exp(+2 pi i k / N), read
    quarter: int,
    stride: int,
    log2_stride: int,
):
    """One radix-4 stage along the middle axis (z); dim (F, N/4, N), column fastest (coalesced)."""
    f, b, col = wp.tid()
    p = b >> log2_stride
    q = b & (stride - 1)
    x0 = src[f, q + stride * p, col]
    x1 = src[f, q + stride * (p + quarter), col]
    x2 = src[f, q + stride * (p + 2 * quarter), col]
    x3 = src[f, q + stride * (p + 3 * quarter), col]
    sum02 = x0 + x2
    dif02 = x0 - x2
    sum13 = x1 + x3
    idif13 = times_i(x1 - x3)
    ps = p * stride
    out = q + stride * 4 * p
    dst[f, out, col] = sum02 + sum13
    dst[f, out + stride, col] = complex_mul(dif02 + idif13, twiddle[ps])
    dst[f, out + 2 * stride, col] = complex_mul(sum02 - sum13, twiddle[2 * ps])
    dst[f, out + 3 * stride, col] = complex_mul(dif02 - idif13, twiddle[3 * ps])


@wp.kernel
def radix2_rows_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    half: int,  # s = N / 2
):
    """Last radix-2 stage (n == 2, no twiddle) along x; dim (F, N, N/2)."""
    f, row, q = wp.tid()
    a = src[f, row, q]
    c = src[f, row, q + half]
    dst[f, row, q] = a + c
    dst[f, row, q + half] = a - c


@wp.kernel
def radix2_columns_kernel(
    src: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, read
    dst: wp.array3d(dtype=wp.vec2),  # (fields, N, N) complex, write
    half: int,  # s = N / 2
):
    """Last radix-2 stage (n == 2, no twiddle) along z; dim (F, N/2, N)."""
    f, q, col = wp.tid()
    a = src[f, q, col]
    c = src[f, q + half, col]
    dst[f, q, col] = a + c
    dst[f, q + half, col] = a - c


def inverse_twiddles(resolution: int) -> np.ndarray:
    """exp(+2 pi i k / N) for k < N as (N, 2) float32, computed in float64."""
    angle = 2.0 * np.pi * np.arange(resolution) / resolution
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1).astype(np.float32)


class InverseFFT2D:
    """In-place batched inverse 2-D FFT of ``data`` (fields, N, N) vec2, allocated once.

    ``data`` (read-write, owned): complex fields, spectral before ``run()``, spatial after.
    ``scratch`` (owned): ping-pong partner. ``twiddle`` (N,) vec2, precomputed.
    The 2 ceil(log2(N) / 2) stage launches are recorded once and replayed by ``run()``.
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
        axes = ((radix4_rows_kernel, (self.fields, n, n // 4), radix2_rows_kernel,
                 (self.fields, n, n // 2)),
                (radix4_columns_kernel, (self.fields, n // 4, n), radix2_columns_kernel,
                 (self.fields, n // 2, n)))
        for radix4, dim4, radix2, dim2 in axes:
            length, stride = n, 1  # current sub-transform length n and stride s
            while length >= 2:
                src, dst = buffers
                if length >= 4:
                    launch = wp.launch(radix4, dim=dim4,
                                       inputs=[src, dst, self.twiddle, length // 4, stride,
                                               stride.bit_length() - 1],
                                       device=self.device, record_cmd=True)
                    length, stride = length // 4, stride * 4
                else:
                    launch = wp.launch(radix2, dim=dim2, inputs=[src, dst, stride],
                                       device=self.device, record_cmd=True)
                    length, stride = 1, stride * 2
                self._stages.append(launch)
                buffers = (dst, src)
        assert buffers[0] is self.data  # even number of stages: result back in ``data``

    @property
    def launch_count(self) -> int:
        return len(self._stages)

    def run(self) -> None:
        """Transform ``data`` in place (no allocation, no host copy)."""
        for stage in self._stages:
            stage.launch()
