"""Stage timing for benchmarks: CUDA events on a GPU, synchronised wall clock on the CPU."""

from __future__ import annotations

import statistics
import time
from contextlib import contextmanager

import warp as wp


class StageTimer:
    """Collects per-stage times [ms] over frames; ``table()`` prints medians."""

    def __init__(self, device):
        self.device = wp.get_device(device)
        self.samples: dict[str, list[float]] = {}
        self._pending: list[tuple[str, object, object]] = []

    @contextmanager
    def stage(self, name: str):
        if self.device.is_cuda:
            start, end = wp.Event(self.device, enable_timing=True), wp.Event(self.device, enable_timing=True)
            wp.record_event(start)
            yield
            wp.record_event(end)
            self._pending.append((name, start, end))
        else:
            wp.synchronize_device(self.device)
            t0 = time.perf_counter()
            yield
            wp.synchronize_device(self.device)
            self.samples.setdefault(name, []).append(1e3 * (time.perf_counter() - t0))

    def flush(self) -> None:
        """Read the CUDA events recorded so far (synchronises)."""
        wp.synchronize_device(self.device)
        for name, start, end in self._pending:
            self.samples.setdefault(name, []).append(wp.get_event_elapsed_time(start, end))
        self._pending.clear()

    def medians(self) -> dict[str, float]:
        self.flush()
        return {k: statistics.median(v) for k, v in self.samples.items()}
