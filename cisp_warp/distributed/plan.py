"""How a shot is cut into chunks: the warm-up each chunk needs (:func:`warmup_frames`) and balanced contiguous
chunks with the warm-up counted (:func:`plan_chunks`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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
      ``max_history`` = N frames and then an exponential mean of weight 1/N; its reactive change test cuts
      the history back where the caustic changes. A chunk warmed up for ``N - 1`` frames starts its first
      written frame with a full-length history (n = N, the weight 1/N from then on, as one process). Where the
      caustic is still, that history is an unbiased estimate of the same mean as one process's: the two differ
      by the photon noise of the frames each weights differently (the chunk's equal weights over its first N
      frames against one process's 1/N (1 - 1/N)^k over all), not by a bias; where it moves, the change test
      shortens both histories and they meet. So ``W = N - 1`` (63 at the default N = 64). What is left is
      noise, not bias, and :func:`caustic_seam_factor` bounds it: the seam in units of one process's own
      frame-to-frame change, 0.48 sqrt(N) for W = N - 1 (1.9 at N = 16, 3.9 at N = 64), scaled down by the
      old-tail weight (1 - 1/N)^(W - N + 1) for longer warm-ups (``--warmup`` 105 or 149: 2 or 1 at N = 64).
      Measured on the 32x18 pool (1000 photons, ``tests/test_distributed.py``) as the mean absolute difference
      of the denoised caustic irradiance over one process's mean absolute change from the frame before, on a
      chunk's first 4 frames: still pool at N = 16, 1.7 / 1.7 / 0.9 / 0.8 (the test, bound 1.9); default
      settings (N = 64): still pool 1.2 / 1.5 / 1.1 / 0.9, animated pool 3.2 / 1.7 / 1.5 / 1.9; without a
      warm-up 4 to 23. The earlier bound, ``N - 1 + ln(1/255) / ln(1 - 1/N)`` = 415 frames, treated that
      difference as a bias as large as the caustic's range, which a full-length unbiased history does not carry.
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
        w = max(w, int(settings.caustic.max_history) - 1)
    return w


def caustic_seam_factor(max_history: int, warmup: int) -> float:
    """Expected seam of the caustics denoiser after ``warmup >= max_history - 1`` frames, in units of one
    process's own frame-to-frame change: the noise model's worst case, a pixel whose caustic is still and whose
    history is never cut (the seam where histories are cut is smaller).

    Per-frame estimates E_k of variance sigma^2, N = ``max_history``, q = 1 - 1/N. One process, long past the
    shot's start, holds the exponential mean, weights (1/N) q^k for the frame k frames back; its frame-to-frame
    change has variance sigma^2 (1/N^2) 2N / (2N - 1). A chunk after N - 1 warm-up frames holds the plain mean of
    its N frames, weights 1/N; the difference of the two has variance
    sigma^2 ((1/N^2) (N - 2N (1 - q^N)) + 1 / (2N - 1)). Each further warm-up frame multiplies the weights
    that differ by q. Returns the ratio of the standard deviations: 0.48 sqrt(N) for W = N - 1.
    """
    n = int(max_history)
    q = 1.0 - 1.0 / n
    ratio2 = (2 * n - 1) / (2 * n) * (n * (2 * q ** n - 1) + n * n / (2 * n - 1))
    return math.sqrt(max(ratio2, 0.0)) * q ** max(int(warmup) - n + 1, 0)


@dataclass(frozen=True)
class Chunk:
    """Time codes ``start`` .. ``stop - 1`` of a shot, written by one task (those not yet on disk)."""

    start: int
    stop: int

    def __len__(self) -> int:
        return self.stop - self.start


def plan_chunks(todo, shot_start: int, workers: int, warmup: int, warmup_cost: float = 1.0) -> list[Chunk]:
    """Cut the time codes ``todo`` (to write) into at most ``max(workers, runs)`` contiguous chunks.

    A chunk's cost, in written frames: its frames to write, plus ``warmup_cost`` for each frame it renders without
    writing it: its warm-up, ``min(warmup, start - shot_start)`` frames, and the gaps it renders through. A
    warm-up frame renders only what the history needs (:func:`~cisp_warp.sequence.render_history_frame`), so it
    costs less than a written one; ``warmup_cost`` is their measured ratio (:func:`~.worker.frame_costs`), 1 = as
    dear. The chunks minimise the largest cost (bisection on it, greedy cuts), so with ``warmup`` > 0 the first
    chunk of a shot is longer than the others. ``runs``: stretches of consecutive codes; a run's gap to the next
    one is rendered through (not written) when it is no longer than ``warmup``.
    """
    codes = sorted(set(int(c) for c in todo))
    if not codes:
        return []
    r = max(float(warmup_cost), 0.0)
    spans: list[list[int]] = [[codes[0], codes[0] + 1]]
    for c in codes[1:]:
        if c - spans[-1][1] <= warmup:  # rendering through the gap is no dearer than a warm-up
            spans[-1][1] = c + 1
        else:
            spans.append([c, c + 1])
    lo_code, wanted = codes[0], np.zeros(codes[-1] - codes[0] + 2, dtype=np.int64)
    wanted[np.asarray(codes) - lo_code + 1] = 1
    written = np.cumsum(wanted)  # written[c - lo_code]: codes to write before c

    def cost(a: int, b: int) -> float:
        w = int(written[b - lo_code] - written[a - lo_code])
        return w + r * (b - a - w + min(warmup, a - shot_start))

    def cut(limit: float) -> list[Chunk] | None:
        """Greedy chunks of cost <= limit (each as long as it may be), or None where one frame exceeds it."""
        out = []
        for a, b in spans:
            while a < b:
                if cost(a, a + 1) > limit:
                    return None
                lo, hi = a + 1, b  # the longest chunk from a within the limit (cost grows with its end)
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    lo, hi = (mid, hi) if cost(a, mid) <= limit else (lo, mid - 1)
                out.append(Chunk(a, lo))
                a = lo
        return out

    pieces = max(workers, len(spans))
    lo, hi = 0.0, max(cost(a, b) for a, b in spans)  # one chunk per run fits
    for _ in range(64):  # smallest largest-cost with no more than `pieces` chunks
        if hi - lo <= 1e-9 * hi:
            break
        mid = 0.5 * (lo + hi)
        chunks = cut(mid)
        if chunks is not None and len(chunks) <= pieces:
            hi = mid
        else:
            lo = mid
    return cut(hi)


__all__ = ["Chunk", "OUTPUT_STEP", "caustic_seam_factor", "plan_chunks", "warmup_frames"]
