"""The written frame's 8-bit image made on the device, and its way to the host off the render loop.

A 1920x1080 frame at 2x2 samples is 100 MB of float32 radiance on the sample grid; its box filter and tone map on
the host take longer than the device takes to render it (CPU numbers in the README's distributed section).
:func:`filter_tonemap` does both on the device, as :func:`cisp_warp.render.box_filter` then
:func:`cisp_warp.image_io.tonemap` do them (its naive twin, compared in ``tests/test_distributed.py``), so 6 MB of
sRGB bytes leave the device per frame, and :class:`HostFrames` copies them into pinned host memory without the
render loop waiting.
"""

from __future__ import annotations

import queue

import numpy as np
import warp as wp

SRGB_EXPONENT = wp.constant(float(np.float32(1.0 / 2.4)))  # as numpy's float32 power gets it: 1/2.4 in double, rounded


@wp.func
def mul32(a: float, b: float) -> float:
    """a * b rounded once to float32, through float64 (exact there): a compiler cannot fuse it into an FMA with
    the next add, as it may a float32 multiply; numpy rounds every float32 operation."""
    return wp.float32(wp.float64(a) * wp.float64(b))


@wp.func
def add32(a: float, b: float) -> float:
    return wp.float32(wp.float64(a) + wp.float64(b))  # float64 then float32: correctly rounded (Figueroa 1995)


@wp.func
def div32(a: float, b: float) -> float:
    return wp.float32(wp.float64(a) / wp.float64(b))


@wp.func
def aces_srgb_byte(v: float, scale: float) -> wp.uint8:
    """One channel [W/(m² sr)] -> 8-bit sRGB: the float32 operations of ``image_io.tonemap``, in its order, each
    rounded once as numpy rounds it (bit for bit on the CPU; on CUDA too, the hardware rounding each alike)."""
    x = float(0.0)
    if wp.isfinite(v):  # nan_to_num(nan=0, posinf=0); -inf becomes -max, clipped to 0 below
        x = wp.max(mul32(v, scale), 0.0)
    y = div32(mul32(x, add32(mul32(2.51, x), 0.03)), add32(mul32(x, add32(mul32(2.43, x), 0.59)), 0.14))
    y = wp.min(wp.max(y, 0.0), 1.0)
    srgb = mul32(12.92, y)
    if y > 0.0031308:
        # powf correctly rounded (as glibc's, which numpy's float32 power calls): in float64, rounded once
        p = wp.float32(wp.pow(wp.float64(y), wp.float64(SRGB_EXPONENT)))
        srgb = add32(mul32(1.055, p), -0.055)
    srgb = wp.min(wp.max(srgb, 0.0), 1.0)
    return wp.uint8(int(add32(mul32(srgb, 255.0), 0.5)))


@wp.kernel
def filter_tonemap(samples: wp.array(dtype=wp.vec3), sample_width: int, s: int, scale: float,
                   ldr: wp.array(dtype=wp.uint8)):
    """Mean of each output pixel's s x s samples, tone mapped with exposure ``scale`` (linear).

    ``samples``: (H*s)*(W*s) vec3 [W/(m² sr)], row-major on the sample grid (read); ``ldr``: H*W*3 uint8 sRGB,
    row-major RGB (write). One thread per output pixel; the samples are summed in numpy's order (row by row)
    and divided by s*s, as ``box_filter``'s mean does."""
    i = wp.tid()
    w = sample_width // s
    y = i // w
    x = i - y * w
    acc = wp.vec3(0.0)
    for dy in range(s):
        row = (y * s + dy) * sample_width + x * s
        for dx in range(s):
            acc = acc + samples[row + dx]
    n = float(s * s)
    for c in range(3):
        ldr[3 * i + c] = aces_srgb_byte(acc[c] / n, scale)


def filter_tonemap_naive(samples: np.ndarray, s: int, scale: float) -> np.ndarray:
    """The twin: (H*s, W*s, 3) float32 -> (H, W, 3) uint8 through ``box_filter`` and ``tonemap`` on the host."""
    from ..image_io import tonemap
    from ..render import box_filter

    return tonemap(box_filter(samples, s), scale)


class HostFrames:
    """The written frames' 8-bit images on their way to the host, without the render loop waiting for them.

    ``slots`` host buffers of H*W*3 uint8 (pinned on CUDA) and one device buffer. ``send(final, exposure)``
    waits for a free slot (the writers hold at most ``slots`` frames: bounded memory), launches
    :func:`filter_tonemap` on ``final`` (the renderer's (H*s)*(W*s) vec3 radiance), enqueues the copy into the
    slot on the device's stream (asynchronous into pinned memory: the next frame's kernels queue behind it)
    with an event after it, and returns the slot; a writer thread calls ``receive(slot)`` (waits for the event;
    an (H, W, 3) uint8 view) and ``release(slot)`` when done with it.
    """

    def __init__(self, renderer, slots: int):
        g = renderer.gbuffer
        self.s = renderer.settings.supersample
        self.sample_width = g.width
        self.shape = (g.height // self.s, g.width // self.s, 3)
        self.device = renderer.device
        n = self.shape[0] * self.shape[1] * 3
        pinned = self.device.is_cuda
        self.ldr = wp.empty(n, dtype=wp.uint8, device=self.device)
        self.buffers = [wp.empty(n, dtype=wp.uint8, device="cpu", pinned=pinned) for _ in range(slots)]
        self.events = [wp.Event(self.device) if pinned else None for _ in range(slots)]
        self.free = queue.SimpleQueue()
        for k in range(slots):
            self.free.put(k)

    def send(self, final: wp.array, exposure: float) -> int:
        k = self.free.get()
        wp.launch(filter_tonemap, dim=self.shape[0] * self.shape[1], device=self.device,
                  inputs=[final, self.sample_width, self.s, float(exposure), self.ldr])
        wp.copy(self.buffers[k], self.ldr)
        if self.events[k] is not None:
            self.device.stream.record_event(self.events[k])
        return k

    def receive(self, k: int) -> np.ndarray:
        if self.events[k] is not None:
            wp.synchronize_event(self.events[k])
        return self.buffers[k].numpy().reshape(self.shape)

    def release(self, k: int) -> None:
        self.free.put(k)


__all__ = ["HostFrames", "filter_tonemap", "filter_tonemap_naive"]
