"""What changes from one frame to the next, as kernels read it: one small device buffer, one copy per frame.

A steady frame launches the same kernels with the same arguments every frame, except for the camera (this
frame's and the last) and the photons' random streams (the R2 scramble and the rng seed of every RSM view, the
seed of every pilot view). Kernels read those from :class:`FrameInputs`' device arrays, so a frame captured once
as a CUDA graph replays frame after frame: the host writes the next frame's values into a host mirror and copies
the whole buffer (a few hundred bytes) before the replay.

==============  =============================  ====================================================================
array           shape, dtype                   holds
==============  =============================  ====================================================================
``cameras``     (2,) ViewParams                this frame's camera, then the last frame's (motion vectors)
``randoms``     (S,) vec3i                     per stream: (scramble x, scramble y, seed) as int32 bit patterns;
                                               stream ``rsm_stream(li, vi)`` of light li's RSM view vi
                                               (``photons.base.frame_random``), then ``pilot_stream(li, b)`` of its
                                               pilot view b (scramble 0, seed ``seed·7919 + frame·131 + b`` mod 2^32, as int32)
==============  =============================  ====================================================================
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import warp as wp

from .raster.views import ViewParams

_ALIGN = 16



def int32_bits(x: int) -> int:
    """``x`` mod 2^32 as the int32 of the same bits: any seed and frame number give a valid stream seed (Python
    ints have no bound; ``np.int32(x)`` refuses x outside [-2^31, 2^31) and the seeds of those that fit keep their
    value)."""
    return (int(x) + (1 << 31)) % (1 << 32) - (1 << 31)

class FrameInputs:
    """The per-frame device inputs of one renderer (or one photon pass driven alone); allocated once."""

    def __init__(self, lights, seed: int, device):
        """``lights``: the renderer's ``LightMaps`` (their RSM and pilot view counts fix the streams)."""
        self.device = wp.get_device(device)
        self.seed = int(seed)
        self._views = [(len(lm.rsm), len(lm.pilot)) for lm in lights]
        self._base = np.cumsum([0] + [r + p for r, p in self._views]).tolist()
        n = max(1, self._base[-1])
        cam_bytes = 2 * wp.types.type_size_in_bytes(ViewParams)
        self._offset = (cam_bytes + _ALIGN - 1) // _ALIGN * _ALIGN
        nbytes = self._offset + 12 * n
        #: the whole buffer on the device and its host mirror (pageable: a copy from it is staged at once, so the
        #: host may overwrite it for the next frame without waiting)
        self.buffer = wp.zeros(nbytes, dtype=wp.uint8, device=self.device)
        self.host = wp.zeros(nbytes, dtype=wp.uint8, device="cpu")
        self.cameras = wp.array(ptr=self.buffer.ptr, dtype=ViewParams, shape=(2,), device=self.device)
        self.randoms = wp.array(ptr=self.buffer.ptr + self._offset, dtype=wp.vec3i, shape=(n,), device=self.device)
        self._cameras_host = wp.array(ptr=self.host.ptr, dtype=ViewParams, shape=(2,), device="cpu")
        self._randoms_host = self.host.numpy()[self._offset :].view(np.int32).reshape(n, 3)
        self.frame = None  #: the frame whose values the buffer holds (None: not written yet)

    def rsm_stream(self, light_index: int, view_index: int) -> int:
        return self._base[light_index] + view_index

    def pilot_stream(self, light_index: int, pilot_index: int) -> int:
        return self._base[light_index] + self._views[light_index][0] + pilot_index

    def values(self, frame: int) -> np.ndarray:
        """The random streams of ``frame``, (S, 3) int32 (the host twin of ``randoms``)."""
        from .photons.base import frame_random

        out = np.zeros_like(self._randoms_host)
        for li, (n_rsm, n_pilot) in enumerate(self._views):
            for vi in range(n_rsm):
                out[self.rsm_stream(li, vi)] = frame_random(self.seed, frame, li * 64 + vi)
            for b in range(n_pilot):
                out[self.pilot_stream(li, b), 2] = int32_bits(self.seed * 7919 + frame * 131 + b)
        return out

    def write(self, frame: int, camera: ViewParams, prev_camera: ViewParams) -> None:
        """Write ``frame``'s cameras and random streams to the device: one host->device copy (not while a graph
        is being captured: the copy comes before the capture or the replay)."""
        self._cameras_host.assign([camera, prev_camera])
        self._randoms_host[:] = self.values(frame)
        wp.copy(self.buffer, self.host)
        self.frame = frame


class FrameLanes:
    """The frame's independent work on CUDA streams ("lanes") that run beside the frame's own stream ("main"), inside
    one captured graph: CUDA stream capture records an event recorded on one captured stream and waited on by another
    as a graph edge, so a lane forked from the capturing stream is part of the graph, and the graph's nodes keep only
    the dependencies the frame states (``branch``, ``mark`` / ``wait``, ``join``).

    Lanes: ``light i`` (i < ``lights``): light i's pilots, fit, RSM views, shadow maps, luminance maximum; ``shade``
    (index ``lights``): the sky's and the direct light's irradiance; then one per RSM view of every light
    (:meth:`view_lane`): that view's photon order, trace and outcome pass. Work on one lane runs in the order it is
    issued; across lanes only through the edges. Every buffer two lanes write is the lane's own (a rasterizer per light
    lane, a photon scratch bank per view lane) or is written by float atomics only (photon map, ledger stripes).

    ``enabled`` False, or the CPU: no streams, every call is a no-op, so the concurrent program runs in the order it is
    written (the CPU test runs it so)."""

    def __init__(self, device, views: list[int], enabled: bool = True):
        """``views``: per light, its RSM views (one photon lane each)."""
        self.device = wp.get_device(device)
        self.lights = len(views)
        self.shade = self.lights  #: the sky's and the direct light's lane
        self._view_base = [int(v) for v in np.cumsum([self.lights + 1] + list(views))]
        self.count = self._view_base[-1]  #: lanes in all
        self.streams = []
        self._events = []
        self.enabled = bool(enabled) and self.device.is_cuda
        #: events one frame may record (a fork per branch, its ``after`` marks, a join per lane): made once, here
        self.events = 8 * self.count + 16
        if self.enabled:
            self.streams = [wp.Stream(self.device) for _ in range(self.count)]
            self._events = [wp.Event(self.device) for _ in range(self.events)]
        self._next = 0
        #: lanes branched in this frame, in order (tracked on the CPU too): only they hold work to join
        self.used: list[int] = []
        self.main = None  #: the stream the frame was issued on (the capturing one), set by :meth:`begin`
        #: whether a concurrent program is being issued (between :meth:`begin` and :meth:`end`): passes that hold the
        #: lanes use them only then (a frame issued in turn, e.g. timed by stages, leaves them alone)
        self.active = False

    def view_lane(self, light_index: int, view_index: int) -> int:
        """The lane of light ``light_index``'s RSM view ``view_index``'s photons."""
        return self._view_base[light_index] + view_index

    def view_lanes(self) -> list[int]:
        return list(range(self.lights + 1, self.count))

    def begin(self) -> None:
        """Start a frame: the device's current stream is main."""
        self._next = 0
        self.used = []
        self.main = self.device.stream if self.enabled else None
        self.active = True

    def end(self) -> None:
        """End a frame: main waits for every lane."""
        self.join()
        self.active = False

    def _event(self) -> "wp.Event":
        if self._next >= len(self._events):
            raise RuntimeError(f"FrameLanes: more than {self.events} events in one frame")
        e = self._events[self._next]
        self._next += 1
        return e

    @contextmanager
    def branch(self, lane: int, after=()):
        """Issue the body's work on ``lane``, after everything issued on main so far (an edge main -> lane) and after
        the marks ``after`` (:meth:`mark`)."""
        if lane not in self.used:
            self.used.append(lane)
        if not self.enabled:
            yield
            return
        s = self.streams[lane]
        s.wait_event(self.main.record_event(self._event()))
        for m in after:
            if m is not None:
                s.wait_event(m)
        self.device.set_stream(s, sync=False)
        try:
            yield
        finally:
            self.device.set_stream(self.main, sync=False)

    def mark(self, lane: int):
        """An event at ``lane``'s current end (what it issued so far), for :meth:`wait`; None when disabled."""
        if not self.enabled:
            return None
        return self.streams[lane].record_event(self._event())

    def wait(self, marks) -> None:
        """Make the device's current stream (main, or the lane in a ``branch``) wait for ``marks``."""
        if not self.enabled:
            return
        for m in marks:
            if m is not None:
                self.device.stream.wait_event(m)

    def joinable(self, lanes=None) -> list[int]:
        """Of ``lanes`` (default: all), those branched in this frame so far: a lane not branched yet holds no work of
        this frame, and during a capture an event recorded on it would be outside the capture (CUDA error 905, a
        dependency on uncaptured work: a join in mid-frame, e.g. the caustic flow's after the traces, came before the
        shade lane's branch)."""
        return [i for i in (range(self.count) if lanes is None else lanes) if i in self.used]

    def join(self, lanes=None) -> None:
        """Main waits for everything issued so far on ``lanes`` (default: all) that were branched in this frame
        (:meth:`joinable`); :meth:`end` joins every lane used, before the capture ends."""
        targets = self.joinable(lanes)
        if not self.enabled:
            return
        for i in targets:
            self.main.wait_event(self.streams[i].record_event(self._event()))
