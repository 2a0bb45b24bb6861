"""How a shot is cut into chunks: the warm-up each chunk needs (:func:`warmup_frames`) and balanced contiguous
chunks with the warm-up counted (:func:`plan_chunks`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..render import RenderSettings

OUTPUT_STEP = 1.0 / 255.0  #: one step of the 8-bit output, relative to full scale: what a seam may differ by


def warmup_frames(settings: RenderSettings) -> int:
    """Frames a chunk renders (unwritten) before its first frame so its temporal state matches one process's.

    * ``caustics_map``'s temporal filter is the mean of the last ``cmap_history`` frames: ``cmap_history - 1``
      frames rebuild it exactly (bit for bit on the CPU).
    * SVGF (where it denoises the method's map) blends each frame into its colour and moment histories with
      weight ``max(1/h, alpha)``, ``h`` the pixel's history length. After ``1/alpha`` frames the weights of a
      chunk equal a single-process run's (``h`` differs, but enters only through that weight and the
      spatial-variance threshold of 4 frames); from then on the difference between the two histories is
      multiplied by ``1 - alpha`` per frame in the linear model (the à-trous level fed back is non-expansive
      for given weights: energy-conserving, row sums <= 1; its variance-guided weights depend on the history
      too, which the model leaves out and the measurement below includes). It starts no larger than the
      caustic's own range, so ``W = ln(1/255) / ln(1 - alpha)`` frames (25 at the default alpha = 0.2) bring
      it below one step of the 8-bit output, relative to the frame's peak. Measured on the pool (32x18 in ``tests/test_distributed.py``, 64x36 by hand): 0.04% to 0.13% of
      the peak radiance of ``final`` after 25 frames, 1.7% after 8, and float32 resolution only after ~100:
      a chunk after a warm-up is close to one process, not bit-identical; a chunk whose warm-up reaches the
      shot's first frame starts there and is identical.
    * The caustics denoiser (the default) keeps a running mean of the raw photon map, capped at
      ``max_history`` = N frames and then an exponential mean of weight 1/N: a fresh chunk's weights equal a
      single process's after N - 1 frames, and the difference then shrinks by 1 - 1/N per frame, so
      ``N - 1 + ln(1/255) / ln(1 - 1/N)`` frames (415 at N = 64; fewer where the caustic moves and the history
      is cut back, which this bound leaves out).
    * The Gaussian gather, the reference and raw maps keep no history: 0.
    """
    w = 0
    ps = settings.photons
    if settings.method == "caustics_map":
        w = int(ps.cmap_history) - 1
    denoised = settings.method in ("cisp", "sspm") or (settings.method == "caustics_map" and ps.cmap_gather != "light")
    alpha = min(settings.svgf.alpha_color, settings.svgf.alpha_moments)
    if denoised and settings.denoiser == "svgf" and alpha < 1.0:
        w = max(w, math.ceil(1.0 / alpha), math.ceil(math.log(OUTPUT_STEP) / math.log1p(-alpha)))
    if denoised and settings.denoiser == "caustic":
        n = settings.caustic.max_history
        w = max(w, n - 1 + math.ceil(math.log(OUTPUT_STEP) / math.log1p(-1.0 / n)))
    return w


@dataclass(frozen=True)
class Chunk:
    """Time codes ``start`` .. ``stop - 1`` of a shot, written by one task (those not yet on disk)."""

    start: int
    stop: int

    def __len__(self) -> int:
        return self.stop - self.start


def plan_chunks(todo, shot_start: int, workers: int, warmup: int) -> list[Chunk]:
    """Cut the time codes ``todo`` (to write) into at most ``max(workers, runs)`` contiguous chunks.

    A chunk's cost is its frames plus its warm-up, ``min(warmup, start - shot_start)`` frames (warm-up and
    written frames cost about the same on a device: both trace, denoise and shade; writing is overlapped).
    The chunks minimise the largest cost (binary search on it, greedy cuts), so with ``warmup`` > 0 the
    first chunk of a shot is longer than the others. ``runs``: stretches of consecutive codes; a run's gap
    to the next one is rendered through (not written) when it is no longer than ``warmup``.
    """
    codes = sorted(set(int(c) for c in todo))
    if not codes:
        return []
    spans: list[list[int]] = [[codes[0], codes[0] + 1]]
    for c in codes[1:]:
        if c - spans[-1][1] <= warmup:  # rendering through the gap is no dearer than a warm-up
            spans[-1][1] = c + 1
        else:
            spans.append([c, c + 1])

    def warm(start: int) -> int:
        return min(warmup, start - shot_start)

    def cut(limit: int) -> list[Chunk] | None:
        """Greedy chunks of cost <= limit, or None where a chunk's warm-up alone reaches the limit."""
        out = []
        for a, b in spans:
            while a < b:
                n = limit - warm(a)
                if n < 1:
                    return None
                out.append(Chunk(a, min(b, a + n)))
                a += n
        return out

    pieces = max(workers, len(spans))
    lo, hi = 1, max(b - a + warm(a) for a, b in spans)
    while lo < hi:  # smallest largest-cost with no more than `pieces` chunks
        mid = (lo + hi) // 2
        chunks = cut(mid)
        if chunks is not None and len(chunks) <= pieces:
            hi = mid
        else:
            lo = mid + 1
    return cut(lo)


__all__ = ["Chunk", "OUTPUT_STEP", "plan_chunks", "warmup_frames"]
