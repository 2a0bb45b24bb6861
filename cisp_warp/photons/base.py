"""What every photon method has: settings, the energy ledger, and a base class that owns the buffers.

Every method hands back the same thing, so that they compare pixel for pixel:

* ``photon_map``: (H*W,) vec3 irradiance [W/m²] on the camera's opaque G-buffer, per pixel, raw;
* ``photon_m2``: (H*W,) float32 Σ luminance(e)² [(W/m²)²] of the photons stored in each pixel, the frame's own
  Monte-Carlo variance of its luminance, for the denoiser; kept by the point stores (cisp, sspm), else None;
* ``ledger``: where the power went (:class:`Ledger`), closing to the sampled power;
* ``trace(gbuffer, camera_params, frame)``: fill both for one frame, all on the device.
"""

from __future__ import annotations

import hashlib
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import Iterator, NamedTuple

import numpy as np
import warp as wp

from ..errors import SceneError
from ..raster import GBuffer, LightMaps
from ..raster.views import View
from ..scene import DeviceScene
from ..frame import FrameInputs
from . import common as C


@dataclass(frozen=True)
class PhotonSettings:
    """Settings of the photon pass; every field reaches a kernel."""

    photons: int = 1 << 20  #: photons per light per frame, split evenly over a light's RSM views
    seed: int = 0  #: with the frame number, reproduces a frame exactly
    roughness_cutoff: float = 0.3  #: texels rougher than this are culled (seed 000, 3.1)
    luminance_cutoff: float = 0.01  #: texels dimmer than this fraction of the brightest are culled
    max_steps: int = 2048  #: march steps per view (about the image diagonal at 1080p)
    thickness: float = 0.02  #: [m] absolute surface thickness of the depth buffers
    thickness_rel: float = 0.02  #: relative surface thickness (× depth)
    footprint: str = "exact"  #: "exact" pixel footprint, or "paper" (seed 000 eq. 3) to reproduce its numbers
    cascade: bool = True  #: CISP: march on in the camera view (False: light view only, for comparison)
    max_bounces: int = 8  #: world-space methods (sspm, reference): specular bounces before giving up
    cmap_gather: str = "light"  #: caustics_map: "light" (Gaussian in the caustic map) or "eye" (7×7 in eye space)
    cmap_history: int = 4  #: caustics_map: frames in seed 004's temporal filter (1 = off)
    reference_photons: int = 0  #: reference: photons per light to accumulate; 0 = 1e8 on CUDA, 4e6 on CPU
    sort_photons: bool | None = None  #: trace RSM photons in texel (Morton) order; None = on CUDA only
    splat: str = "point"  #: cisp, sspm: "point" deposits, or "wavefront" (photons on an RSM grid, cells splatted)
    #: wavefront splats: cells over the RSM's texels ("rsm") or over the specular mesh's own triangles ("mesh")
    wavefront_grid: str = "rsm"
    #: mesh grid: a cell whose corners diverge (a silhouette, an occluder's shadow edge), one of them on a camera
    #: surface, is cut this many times along each edge and traced again (1: no refinement, points at its corners)
    wavefront_refine: int = 4

    def validate(self) -> None:
        if not isinstance(self.photons, (int, np.integer)) or self.photons < 1 or self.photons > 1 << 28:
            raise SceneError(f"--photons must be an integer in [1, 2^28], got {self.photons!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed < 1 << 63:
            raise SceneError(f"--seed must be an integer in [0, 2^63), got {self.seed!r}")
        if self.footprint not in ("exact", "paper"):
            raise SceneError(f"footprint must be 'exact' or 'paper', got {self.footprint!r}")
        if self.splat not in ("point", "wavefront"):
            raise SceneError(f"--splat must be 'point' or 'wavefront', got {self.splat!r}")
        if self.wavefront_grid not in ("rsm", "mesh"):
            raise SceneError(f"--wavefront-grid must be 'rsm' or 'mesh', got {self.wavefront_grid!r}")
        if self.cmap_gather not in ("light", "eye"):
            raise SceneError(f"--cmap-gather must be 'light' or 'eye', got {self.cmap_gather!r}")
        for name, lo in (("max_steps", 1), ("max_bounces", 1), ("cmap_history", 1), ("reference_photons", 0),
                         ("wavefront_refine", 1)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < lo:
                raise SceneError(f"--{name.replace('_', '-')} must be an integer >= {lo}, got {v!r}")
        for name in ("roughness_cutoff", "luminance_cutoff", "thickness", "thickness_rel"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise SceneError(f"{name} must be a finite number >= 0, got {v!r}")


def frame_random(seed: int, frame: int, stream: int) -> tuple[int, int, int]:
    """Per (seed, frame, stream): the R2 sequence's Cranley-Patterson rotation as two uint32 fixed-point
    offsets, and the seed of the photons' random streams; all as int32 bit patterns for the kernel."""
    h = hashlib.blake2b(f"{seed}:{frame}:{stream}".encode(), digest_size=12).digest()
    words = [int.from_bytes(h[4 * i : 4 * i + 4], "little") for i in range(3)]
    a, b, c = (v - (1 << 32) if v >= 1 << 31 else v for v in words)
    return a, b, c


def camera_pixel_solid_angle(view: View) -> np.ndarray:
    """Exact solid angle of every camera pixel, flat (H*W,) float32 (zeros for orthographic views)."""
    if view.orthographic:
        return np.zeros(view.width * view.height, np.float32)
    return view.texel_solid_angle().astype(np.float32).reshape(-1)


#: key bits per pass of the CUB radix sort behind ``wp.utils.radix_sort_pairs`` on CUDA (onesweep, 4-byte keys)
SORT_PASS_BITS = 8


def morton_sort_bits(side: int) -> tuple[int, int]:
    """(begin_bit, end_bit) of the Morton keys of a view of ``side`` texels to sort photons by: the key's top bits
    in an even number of radix passes. CUB sorts ping-pong between the keys and their second half; after an odd
    number of passes the result lies in the second half and Warp copies keys and values back (two device copies a
    sort). A 2048² view's 22-bit keys take 3 passes; their top 16 bits take 2, and the 6 bits left out only order
    photons within 8x8-texel blocks (which keep their R2 order, as coherent for the trace)."""
    end = 2 * max(1, (side - 1).bit_length())
    passes = -(-end // SORT_PASS_BITS)
    if passes % 2 == 1 and passes > 1:
        passes -= 1
    return max(0, end - passes * SORT_PASS_BITS), end


class Ledger:
    """Where the photons' power went in one frame, per RGB channel [W]."""

    def __init__(self, values: np.ndarray):
        self.values = np.array(values, dtype=np.float64).reshape(C.LEDGER_ENTRIES, 3)  # a copy: not a device view

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[C.LEDGER_NAMES.index(name)]

    def parts(self) -> dict[str, np.ndarray]:
        return {n: self.values[i] for i, n in enumerate(C.LEDGER_NAMES) if n not in C.INFORMATIVE}

    def closure(self) -> float:
        """Relative mismatch |sampled − Σ parts| / sampled, summed over channels (0 when it closes)."""
        whole = self["sampled"].sum()
        parts = sum(v.sum() for v in self.parts().values())
        return abs(whole - parts) / whole if whole > 0 else 0.0

    def as_dict(self) -> dict[str, float]:
        return {n: float(self.values[i].sum()) for i, n in enumerate(C.LEDGER_NAMES)}

    def table(self) -> str:
        whole = self["sampled"].sum()
        rows = [f"{'entry':<18}{'power [W]':>14}{'share':>9}"]
        for i, n in enumerate(C.LEDGER_NAMES):
            v = self.values[i].sum()
            share = f"{100.0 * v / whole:8.3f}%" if whole > 0 else "      -"
            rows.append(f"{n:<18}{v:14.6g}{share}")
        rows.append(f"closes to {self.closure():.2e} relative (reflected + refracted = traced, not summed)")
        return "\n".join(rows)


class RSMBatch(NamedTuple):
    """One RSM view's photons for one frame, as every RSM-emitting method launches them.

    The view and its photon count may live only on the device (views fitted to the camera on the device): kernels
    that take ``views[view_index]`` and ``states[view_index]`` (``LightMaps.views`` / ``states``) run ``slots``
    threads and emit ``cascade_photons(states[view_index], light_photons)`` of them. ``params``, ``n``,
    ``skip_window`` and ``luminance_cutoff`` are the host's copies, set for whole (not fitted) views only."""

    light_index: int
    view_index: int
    lights: LightMaps  #: the light's maps (``.light``, ``.scene``, ``.views``, ``.states``)
    params: wp.struct  #: the view's ViewParams (whole views; None when fitted)
    rsm: object  #: the view's RSMView
    n: int  #: photons (whole views); for fitted ones the threads launched, ``slots``
    seed: int  #: seed of the photons' random streams
    scramble: wp.vec2i  #: the R2 sequence's Cranley-Patterson rotation
    order: wp.array  #: tracing order (read when the pass's ``use_order`` is set)
    light_pos: wp.vec3  #: [m]
    skip_window: wp.vec4  #: this view's pixels a finer cascade samples (x0, y0, x1, y1); empty when x1 <= x0 (whole views)
    luminance_cutoff: float  #: the luminance cutoff against the light's brightest texel, scaled to this view's texels
    slots: int  #: threads to launch: >= this view's photons (their count read on the device)
    light_photons: int  #: the light's photons, split over its active views on the device (``cascade_photons``)
    stream: int  #: this view's random stream in ``PhotonPass.inputs.randoms`` (the same ``seed`` and ``scramble``)


class PhotonPass:
    """Base of every photon method: allocates the photon map, the ledger and per-light scratch once."""

    name = "photons"
    #: trace photons in a texel order sorted once per view size and photon slots (True), or sorted every frame
    #: over the frame's rotated R2 points (False: the twin, main's order up to section 40 of docs/perf_notes.md)
    FIXED_ORDER = True
    #: True (default): on CUDA the group partition's per-tile counts (``photon_group_keys``) and ranks
    #: (``photon_group_scatter``) by warp ballots with one barrier a tile (``common._group_count_ballot``,
    #: ``_group_scan_ballot``); False: Warp's ``tile_sum`` and ``tile_scan_exclusive`` (the twin, main's before
    #: docs/perf_notes.md section 88). The same counts and ranks; the CPU takes the tiles either way
    BALLOT_GROUPS = True
    denoise = True  #: whether the renderer's denoiser runs on ``photon_map`` (False: shown raw)
    final = None  #: a method that renders its own final image sets this (H*W,) vec3 array
    #: the photons that land where the camera cannot see, per light view (``hidden_flux.HiddenFlux``), for the
    #: composite's hidden hits; a method that keeps them sets it (:meth:`keep_hidden`), else None
    hidden = None
    #: the caustic flow (``caustic_flow.CausticFlow``) where a denoiser asked for it (:meth:`keep_caustic_flow`), else None
    flow = None

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        """``t_max``: the longest ray a photon may travel [m] (the renderer's scene-wide bound)."""
        settings.validate()
        self.scene = scene
        self.settings = settings
        self.device = wp.get_device(device)
        self.lights = lights
        n = gbuffer.width * gbuffer.height
        self.photon_map = wp.zeros(n, dtype=wp.vec3, device=self.device)
        #: (H*W,) float32 Σ luminance(e)² [(W/m²)²] of the photons stored per pixel (common.deposit), zeroed with
        #: the photon map; allocated by the methods that keep it (:meth:`keep_photon_m2`), else None
        self.photon_m2 = None
        # the frame's accumulators, zeroed together by one memset in begin(): the striped ledger, the ledger, and
        # each light's brightest texel; views of one float64 buffer (``_accumulators``), in this order
        self.ledger_stripes = C.LEDGER_STRIPES if self.device.is_cuda else 1
        n_rows = self.ledger_stripes * C.LEDGER_ROW
        n_lum = max(1, (len(lights) + 1) // 2)  # float64 words holding the float32 maxima
        self._accumulators = wp.zeros(3 * n_rows + 3 * C.LEDGER_ENTRIES + n_lum, dtype=wp.float64, device=self.device)
        base = self._accumulators.ptr
        #: (stripes * LEDGER_ROW,) vec3d: the striped ledger the photon kernels add to (block b: stripe b % stripes),
        #: summed into ``ledger`` by :meth:`fold_ledger`. One stripe on the CPU: entries added in photon order
        self.ledger_rows = wp.array(ptr=base, dtype=wp.vec3d, shape=(n_rows,), device=self.device)
        #: (3 * LEDGER_ENTRIES,) float64: the frame's ledger, power [W] per entry and RGB channel, once folded
        self.ledger = wp.array(ptr=base + 24 * n_rows, dtype=wp.float64, shape=(3 * C.LEDGER_ENTRIES,),
                               device=self.device)
        self._ledger_entries = wp.array(ptr=self.ledger.ptr, dtype=wp.vec3d, shape=(C.LEDGER_ENTRIES,),
                                        device=self.device)  # (LEDGER_ENTRIES,) vec3d alias of ``ledger``
        #: (lights,) float32: each light's brightest whole-view texel luminance [W] this frame (max_luminance)
        self.max_lum = wp.array(ptr=base + 24 * n_rows + 24 * C.LEDGER_ENTRIES, dtype=wp.float32,
                                shape=(len(lights),), device=self.device)
        for alias in (self.ledger_rows, self.ledger, self._ledger_entries, self.max_lum):
            alias._owner = self._accumulators  # views of it (host copies via numpy() too) keep the memory alive
        self._max_lum_of = [self.max_lum[i : i + 1] for i in range(len(lights))]  # per-light views, made once
        self._clear_wide_key = None  #: the arrays ``_clear_wide_cache`` aliases (:meth:`_clear_wide`)
        self._clear_wide_cache = None
        #: (H*W,) float32: the camera pixels' exact solid angles [sr] (:meth:`set_camera_view` when the camera's
        #: intrinsics change)
        self.solid_angle = wp.array(camera_pixel_solid_angle(camera_view), dtype=wp.float32, device=self.device)
        self.t_max = float(t_max)
        self.footprint_mode = C.FOOTPRINT_EXACT if settings.footprint == "exact" else C.FOOTPRINT_PAPER
        sort = settings.sort_photons if settings.sort_photons is not None else self.device.is_cuda
        self.use_order = 1 if sort else 0
        n_max = self.max_photons_per_view() if sort and settings.splat == "point" else 0  # a grid needs no order
        #: threads per block of the photon kernels; each block adds its tallies to the ledger once. Warp runs CPU
        #: tiles one thread per block unless ``wp.config.enable_cpu_blocks`` is set (a test does, to check the sums)
        self.ledger_block = C.LEDGER_BLOCK if self.device.is_cuda else 1
        #: texel order: fixed (sorted once per view size and slot count, :meth:`texel_order`) or sorted every frame
        #: (main's order before the fixed one, kept as its twin: the tests compare the two)
        self.fixed_order = self.FIXED_ORDER
        n_frame = n_max if not self.fixed_order else 0
        #: (max photons,) int32: march group per thread (photon_group_keys); with a per-frame order, (2 * max
        #: photons,): first the Morton keys of the radix sort's two halves
        self._sort_keys = wp.zeros(max(1, n_max + n_frame), dtype=wp.int32, device=self.device)
        #: (2 * max photons,) int32: the per-frame texel order (the radix sort's two halves); unused when fixed
        self._order = wp.zeros(max(1, 2 * n_frame), dtype=wp.int32, device=self.device)
        #: fixed texel orders, (slots, width, height, photon counts) -> one order of slots per count (:meth:`texel_order`)
        self._texel_orders: dict[tuple, wp.array] = {}
        #: (max photons,) int32: the photons grouped by march (photon_order's result, the trace's ``order``)
        self._grouped = wp.zeros(max(1, n_max), dtype=wp.int32, device=self.device)
        #: blocks of the group partition (photon_group_keys / photon_group_scatter) and their counts per group
        self.group_block = C.SORT_GROUP_BLOCK if self.device.is_cuda else 1
        #: most blocks of the group partition (each over many tiles of ``group_block`` slots); None: one per tile
        self.group_max_blocks = C.SORT_GROUP_BLOCKS_PER_SM * self.device.sm_count if self.device.is_cuda else None
        n_blocks = max(1, (n_max + self.group_block - 1) // self.group_block)
        self._group_counts = wp.zeros(C.SORT_GROUPS * n_blocks, dtype=wp.int32, device=self.device)
        self._group_offsets = wp.zeros(C.SORT_GROUPS * n_blocks, dtype=wp.int32, device=self.device)
        self._group_views = {}  # blocks -> (counts, offsets) views of the first SORT_GROUPS * blocks entries
        #: most blocks of the outcome pass (CUDA: each thread sums many records); None: one record per thread
        self.outcome_max_blocks = C.OUTCOME_BLOCKS_PER_SM * self.device.sm_count if self.device.is_cuda else None
        #: the cameras and random streams the kernels read (``frame.FrameInputs``); a renderer shares its own, which
        #: it writes once per frame before tracing (or replaying a captured frame)
        self.inputs = FrameInputs(lights, settings.seed, self.device)
        self._no_hidden = wp.zeros(0, dtype=wp.vec3, device=self.device)  #: the empty hidden map (hidden_args)
        #: the renderer's ``frame.FrameLanes``: in a concurrent frame each light's luminance maximum and outside
        #: booking run on its light lane, each RSM view's photon order, trace and outcome pass (SSPM; CISP's with
        #: ``FOLDED_OUTCOMES`` off) on its view lane with a scratch bank of its own (:meth:`keep_lanes`); None: every
        #: view in turn on the current stream with the pass's own arrays (the sequential twin). ``hits``
        #: (``record_hits``, tests) stays one array: the last view's
        self.lanes = None
        self._banks: list[dict] = []  #: per RSM view (lights in turn): its ``LANE_SCRATCH``; 0: the pass's own
        if sort and n_max > 0 and self.fixed_order and self.device.is_cuda:
            for lm in lights:  # the slot counts CUDA launches are fixed: sort every view's order now, not in a frame
                for r, slots in zip(lm.rsm, self.view_slots(lm)):
                    if slots > 0:
                        self._fixed_texel_order(slots, r.width, r.height, self._order_counts(lm, slots))

    #: the arrays a view's photon launches write that are not float atomics shared by all views: the photon order's
    #: scratch and result, and the trace's outcome records. Views whose photons run concurrently get a bank each
    LANE_SCRATCH = ("_sort_keys", "_order", "_grouped", "_group_counts", "_group_offsets", "outcome")

    def keep_lanes(self, lanes) -> None:
        """Run each light's begin on its light lane and each RSM view's photons on its view lane of ``lanes``
        (``frame.FrameLanes``; None: back to the sequential twin): allocates a scratch bank per view once (bank 0 is
        the pass's own arrays; the banks are kept when lanes are turned off and on again)."""
        self.lanes = lanes
        if lanes is None:
            return
        if not self._banks:
            self._banks = [dict(self._own_scratch(), _group_views=self._group_views)]
        while len(self._banks) < sum(len(lm.rsm) for lm in self.lights):
            bank = {name: wp.zeros(a.shape, dtype=a.dtype, device=self.device)
                    for name, a in self._banks[0].items() if name != "_group_views"}
            bank["_group_views"] = {}
            self._banks.append(bank)

    def _own_scratch(self) -> dict:
        """The pass's own ``LANE_SCRATCH`` arrays (those this method has), by name: bank 0, and every view's without
        lanes."""
        return {name: getattr(self, name) for name in self.LANE_SCRATCH if hasattr(self, name)}

    def _bank_index(self, light_index: int, view_index: int) -> int:
        return sum(len(lm.rsm) for lm in self.lights[:light_index]) + view_index

    def lane_scratch(self, light_index: int, view_index: int) -> list[wp.array]:
        """The scratch arrays the photon launches of light ``light_index``'s view ``view_index`` write (its bank with
        lanes; the pass's own without)."""
        if self.lanes is not None and self._banks:  # what a concurrent frame hands the view
            bank = self._banks[self._bank_index(light_index, view_index)]
        else:
            bank = self._own_scratch()
        return [a for name, a in bank.items() if name != "_group_views"]

    def _active_lanes(self):
        """``lanes`` while a concurrent frame is being issued with them, else None."""
        return self.lanes if self.lanes is not None and self.lanes.active else None

    def join_lights(self) -> None:
        """The current stream (main) waits for every lane (before work that reads all views' photons on it)."""
        if self._active_lanes() is not None:
            self.lanes.join()

    def light_lane(self, light_index: int):
        """The body's launches for light ``light_index`` (its luminance maximum, outside booking) on its light lane,
        in a concurrent frame; else on the current stream (nothing changes)."""
        return nullcontext() if self._active_lanes() is None else self.lanes.branch(light_index)

    @contextmanager
    def view_lane(self, light_index: int, view_index: int, after=()):
        """The body's launches for light ``light_index``'s RSM view ``view_index`` (photon order, trace, outcomes) on
        its view lane after the marks ``after``, with its scratch bank, in a concurrent frame; else on the current
        stream with the pass's own arrays (nothing changes)."""
        if self._active_lanes() is None:
            yield
            return
        bank = self._banks[self._bank_index(light_index, view_index)]
        for name, a in bank.items():
            setattr(self, name, a)
        try:
            with self.lanes.branch(self.lanes.view_lane(light_index, view_index), after):
                yield
        finally:
            for name, a in self._banks[0].items():
                setattr(self, name, a)

    def keep_photon_m2(self, n: int) -> None:
        """Allocate ``photon_m2`` for ``n`` camera pixels: a method whose photons are stored by ``common.deposit``
        as points calls this once at set-up."""
        self.photon_m2 = wp.zeros(n, dtype=wp.float32, device=self.device)

    def keep_caustic_flow(self, width: int, height: int) -> None:
        """Allocate ``flow`` (:class:`~.caustic_flow.CausticFlow`: each camera pixel's caustic motion, from where the
        photons of the same light-space cells landed the frame before) for a ``width`` × ``height`` camera: called once
        at set-up by a renderer whose denoiser reads it; a method that cannot keep it raises."""
        raise SceneError(f"method {self.name!r} keeps no caustic flow (cisp with point splats does)")

    def keep_hidden(self) -> None:
        """Allocate ``hidden`` (every light view's hidden flux map): a method that stores photons the camera does not
        see there calls this once at set-up."""
        from .hidden_flux import HiddenFlux

        self.hidden = HiddenFlux(self.lights, self.settings.photons, self.device)

    def hidden_args(self, batch: RSMBatch) -> list:
        """The trace kernels' last four inputs for ``batch``: its light's whole views, their landed-photon map and
        its texels across and down (an empty map where the method keeps none)."""
        if self.hidden is None:
            return [batch.lights.views, self._no_hidden, 1, 1]
        w, h = self.hidden.shape[batch.light_index]
        return [self.hidden.views[batch.light_index], self.hidden.flux[batch.light_index], w, h]

    def photons_per_view(self, lm: LightMaps) -> int:
        """A light's photons split evenly over its RSM views that emit this frame (every view, unless
        they are fitted to the camera: then the active cascades, read back from the device: not for the frame
        loop, which launches ``view_slots`` threads and lets the kernels count)."""
        return max(1, self.settings.photons // max(1, sum(lm.active)))

    def set_camera_view(self, camera_view: View) -> None:
        """The camera's intrinsics changed (``Renderer.set_camera``: a zoom, another projection): its pixels' solid
        angles, which the photons' deposit divides by, written anew in place (one host->device copy when they change,
        not every frame; a captured frame reads the same array)."""
        self.solid_angle.assign(camera_pixel_solid_angle(camera_view))

    def max_photons_per_view(self) -> int:
        """The most photon slots one view can get (all of its light's, rounded up to whole blocks on CUDA, when
        one cascade alone is active)."""
        return max((self._fitted_slots() if lm.fitted else self.photons_per_view(lm) for lm in self.lights), default=1)

    def _fitted_slots(self) -> int:
        """Threads launched for a fitted view on CUDA: the light's photons in whole blocks (so a block of slots
        past the view's count is wholly past it, and its kernels return at once)."""
        b = C.LEDGER_BLOCK
        return (self.settings.photons + b - 1) // b * b

    def view_slots(self, lm: LightMaps) -> list[int]:
        """Threads to launch per RSM view this frame, without waiting for the device: a whole view's photons; a
        fitted cascade's exact count on the CPU (its states are host memory), else all the light's photons (the
        most one cascade can get; the surplus threads emit nothing)."""
        active = lm.host_active()
        if active is None:
            return [self._fitted_slots()] * len(lm.rsm)
        n = max(1, self.settings.photons // max(1, sum(active)))
        return [n if a else 0 for a in active]

    def begin(self) -> None:
        """Zero the photon map and the ledger, find each light's brightest texel of its whole views (the
        luminance cutoff), and book the power outside every view fitted to the camera."""
        if self.WIDE_CLEAR:
            args, threads = self._clear_wide()
            wp.launch(C.clear_frame_wide, dim=threads, device=self.device, inputs=[*args, threads])
        else:
            self.photon_map.zero_()
            if self.hidden is not None:
                self.hidden.zero()
            self._accumulators.zero_()  # ledger stripes, ledger and max_lum: one memset
            if self.photon_m2 is not None:
                self.photon_m2.zero_()
        for li, lm in enumerate(self.lights):
            with self.light_lane(li):
                self.begin_light(li, lm)

    #: a fitted light's pilots in one launch each (``common.pilot_texel_pass``: the brightest texel and the power outside
    #: the fitted views from one flux per texel); False: ``max_luminance`` then ``book_outside_window`` (the twins)
    FUSED_PILOT_PASS = True

    #: True (default): the frame's accumulators zeroed by one launch of 16-byte stores (``common.clear_frame_wide``,
    #: docs/perf_notes.md section 77); False: one memset an array (the twin; section 63's one kernel of 4-byte
    #: stores, slower than the memsets on the H100, is gone)
    WIDE_CLEAR = True
    #: most threads of ``clear_frame_wide`` (each zeroes every ``threads``-th 16-byte word): 8 blocks of 256 an SM
    WIDE_CLEAR_THREADS_PER_SM = 2048

    def _clear_wide(self) -> tuple[list[wp.array], int]:
        """(vec4 aliases of the 16-byte words of the arrays :func:`~.common.clear_frame_wide` zeroes (photon map,
        Σ e², hidden flux, accumulators; empty where the pass keeps none), then float32 aliases of each one's 4-byte
        words past them; the threads to launch), made once per set of arrays (they are allocated at set-up)."""
        arrays = (self.photon_map, self.photon_m2, self.hidden.all_flux if self.hidden is not None else None,
                  self._accumulators)
        key = ("wide",) + tuple(None if a is None else (a.ptr, a.capacity) for a in arrays)
        if self._clear_wide_key != key:
            bodies, tails = [], []
            for a in arrays:
                nbytes = 0 if a is None else a.capacity
                n16, n4 = nbytes // 16, (nbytes % 16) // 4
                body = wp.array(ptr=a.ptr if n16 else 0, dtype=wp.vec4, shape=(n16,), device=self.device)
                tail = wp.array(ptr=a.ptr + 16 * n16 if n4 else 0, dtype=wp.float32, shape=(n4,), device=self.device)
                for alias in (body, tail):
                    if a is not None:
                        alias._owner = a
                bodies.append(body)
                tails.append(tail)
            longest = max(1, max(b.shape[0] for b in bodies))
            per_sm = self.WIDE_CLEAR_THREADS_PER_SM * (self.device.sm_count if self.device.is_cuda else 1)
            threads = max(4, min(longest, per_sm))
            self._clear_wide_key, self._clear_wide_cache = key, (bodies + tails, threads)
        return self._clear_wide_cache

    def begin_light(self, li: int, lm: LightMaps) -> None:
        """Light ``li``'s part of :meth:`begin`: its brightest whole-view texel, and the power outside its fitted
        views booked."""
        if lm.fitted and self.FUSED_PILOT_PASS:
            for b, r in enumerate(lm.pilot):
                self.launch_photons(C.pilot_texel_pass, r.width * r.height,
                                    [lm.pilot_views, r.specular.tri_id, lm.emission(r), r.width, r.width * r.height,
                                     lm.outside, lm.outside_angle, b, wp.vec2(r.view.cx, r.view.cy),
                                     float(r.view.fx / r.view.fy), self.ledger_rows, self._max_lum_of[li]])
            return
        for k, r in enumerate(lm.whole_rsm):
            n = r.width * r.height
            block = 256 if self.device.is_cuda else 1
            blocks = max(1, (n + block * C.MAX_LUM_TEXELS - 1) // (block * C.MAX_LUM_TEXELS))
            wp.launch_tiled(C.max_luminance, dim=blocks, block_dim=block, device=self.device,
                            inputs=[lm.whole_views, k, r.specular.tri_id, lm.emission(r), n, self._max_lum_of[li]])
        for b, r in enumerate(lm.pilot):
            self.launch_photons(C.book_outside_window, r.width * r.height,
                                [lm.pilot_views, r.specular.tri_id, lm.emission(r), r.width, r.width * r.height, lm.outside, lm.outside_angle, b,
                                 wp.vec2(r.view.cx, r.view.cy), float(r.view.fx / r.view.fy), self.ledger_rows])

    def launch_photons(self, kernel, n: int, inputs: list) -> None:
        """Launch a photon kernel over ``n`` photons as ``wp.launch_tiled`` blocks of ``ledger_block`` threads
        (the kernel computes its photon slot as ``block * wp.block_dim() + lane`` and ends with ``ledger_add``)."""
        blocks = max(1, (n + self.ledger_block - 1) // self.ledger_block)
        wp.launch_tiled(kernel, dim=blocks, block_dim=self.ledger_block, device=self.device, inputs=inputs)

    #: True (default): the outcome pass of an inactive view returns at once, and on CUDA each block sums its records
    #: by a warp reduce-scatter (``common._outcome_reduce``, one barrier, 30 float64 atomics); False: every block
    #: sums with two tile sums (the twin; docs/perf_notes.md section 77). The CPU's sums are the twin's either way
    FAST_OUTCOMES = True
    #: True (default): on CUDA the outcome pass loads each 16-byte record in one load (``common._record16``,
    #: streaming); False: Warp's four 4-byte loads a record (the twin; docs/perf_notes.md section 88). Same values
    WIDE_OUTCOMES = True
    #: True (default): records of exactly the six entries 4-9 (CISP's trace) are added by
    #: ``common.ledger_add_outcomes6`` (one 6×3 float64 sum a thread, <= 80 registers, three blocks of 256 an SM);
    #: False: ``ledger_add_outcomes`` (the twin: every final entry's sums, 124 registers, two blocks an SM; section 88)
    OUTCOMES6 = True
    #: True: the trace kernel adds its photons' final entries to the ledger itself, in its epilogue, by one block
    #: reduction (``kernels_cisp.final_add``: the emission's reduce-scatter over six entries), writing no outcome
    #: records and launching no outcome pass; False (default): each photon's outcome record, added by
    #: ``add_outcomes`` after the trace. CISP's trace only (SSPM's keeps the outcome pass). Off because it measured
    #: slower on the H100: the epilogue made the trace kernels ~0.03 ms longer than the pass it saves (pool 4.638
    #: against 4.619 ms, and 4.626 / 4.622 against 4.604 / 4.599 in another machine's call; docs/perf_notes.md
    #: sections 79, 81 and 84)
    FOLDED_OUTCOMES = False

    def add_outcomes(self, outcome: wp.array, batch: RSMBatch, runs: int, entries: int) -> None:
        """Add the final entries of ``runs`` runs of ``batch.slots`` outcome records (written by the trace kernel
        with ``record_outcome``) to the ledger (:func:`~.common.ledger_add_outcomes`): on CUDA at most
        ``outcome_max_blocks`` blocks of ``OUTCOME_BLOCK`` threads, each thread summing every ``threads``-th
        record, each block adding once per entry; on the CPU one record per thread, in photon order (the tests
        cap the blocks there to run the CUDA layout). Records past the view's photon count are skipped."""
        n = runs * batch.slots
        block = C.OUTCOME_BLOCK if self.device.is_cuda else self.ledger_block
        blocks = max(1, (n + block - 1) // block)
        kernel = C.ledger_add_outcomes
        max_blocks = self.outcome_max_blocks
        if self.OUTCOMES6 and entries == int(C.FINAL6_ENTRIES):
            kernel = C.ledger_add_outcomes6
            if max_blocks is not None:  # CUDA (or a test's cap): three blocks an SM where the twin has two
                max_blocks = max(1, max_blocks * C.OUTCOME6_BLOCKS_PER_SM // C.OUTCOME_BLOCKS_PER_SM)
        if max_blocks is not None:
            blocks = min(blocks, max_blocks)
        fast = int(self.FAST_OUTCOMES)
        if self.WIDE_OUTCOMES and self.device.is_cuda and outcome.ptr % 16 == 0 and outcome.strides[0] == 16:
            fast |= int(C.OUTCOME_WIDE)  # contiguous, 16-byte aligned records (an allocation's start)
        wp.launch_tiled(kernel, dim=blocks, block_dim=block, device=self.device,
                        inputs=[outcome, n, blocks * block, entries, self.ledger_rows, batch.lights.states,
                                batch.view_index, batch.light_photons, max(1, batch.slots), fast])

    def fold_ledger(self) -> None:
        """Sum the striped ledger into ``ledger`` and zero the stripes (one small launch; idempotent)."""
        block = self.ledger_stripes if self.device.is_cuda else 1
        wp.launch_tiled(C.ledger_fold, dim=C.LEDGER_ENTRIES, block_dim=block, device=self.device,
                        inputs=[self.ledger_rows, self._ledger_entries])

    def frame_inputs(self, camera: wp.struct, frame: int) -> None:
        """Make ``inputs`` hold ``frame``: a renderer has written them already (and while a frame is captured
        nothing may be copied); a pass driven alone writes ``camera`` and the frame's random streams now."""
        if self.inputs.frame != frame and not (self.device.is_cuda and self.device.is_capturing):
            self.inputs.write(frame, camera, camera)

    def _fixed_texel_order(self, slots: int, width: int, height: int, counts: tuple[int, ...]) -> wp.array:
        """(len(counts) * slots,) int32: per photon count n in ``counts``, the ``slots`` photon indices with the first
        n by the Morton code of their texel before the frame's rotation (:func:`~.common.photon_texel_keys`), the
        rest after them; sorted once over every key bit and kept for the views of this size."""
        key = (slots, width, height, counts)
        if key not in self._texel_orders:
            side = min(max(width, height), 1 << 14)
            code_bits = 2 * max(1, (side - 1).bit_length())
            table = wp.zeros(len(counts) * slots, dtype=wp.int32, device=self.device)
            keys = wp.zeros(2 * slots, dtype=wp.int32, device=self.device)
            values = wp.zeros(2 * slots, dtype=wp.int32, device=self.device)
            for i, n in enumerate(counts):
                wp.launch(C.photon_texel_keys, dim=slots, device=self.device,
                          inputs=[width, height, n, code_bits, keys, values])
                wp.utils.radix_sort_pairs(keys, values, slots, begin_bit=0, end_bit=code_bits + 1)
                wp.copy(table, values, dest_offset=i * slots, count=slots)
            self._texel_orders[key] = table
        return self._texel_orders[key]

    def _order_counts(self, lm: LightMaps, slots: int) -> tuple[int, ...]:
        """The photon counts a view of ``lm`` launched with ``slots`` threads may have: one per count of active views
        for fitted views (``cascade_photons``), else the view's own (its slots)."""
        if not lm.fitted:
            return (slots,)
        return tuple(min(slots, max(1, self.settings.photons // a)) for a in range(1, len(lm.rsm) + 1))

    def texel_order(self, lm: LightMaps, view_index: int, r, slots: int, stream: int) -> tuple[wp.array, int, int]:
        """The photon slots of RSM view ``r`` in texel order, as (table, stride, orders): the view's photons (its
        count, on the device) first, in texel order, from ``common.order_base`` (``stride`` × (active views − 1),
        fewer than ``orders``), then the slots past the count. Fixed (:attr:`FIXED_ORDER`): the photon indices by
        their texel before the frame's Cranley-Patterson rotation, sorted once per view size and photon count (one
        order per count of active views of a fitted light): the rotation moves all points alike, so neighbours stay
        neighbours. Per frame (the twin): a radix sort of this frame's rotated points over the key's top bits
        (:func:`morton_sort_bits`), indices past the count last, one order."""
        if self.fixed_order:
            counts = self._order_counts(lm, slots)
            return self._fixed_texel_order(slots, r.width, r.height, counts), slots, len(counts)
        wp.launch(C.photon_sort_keys, dim=slots, device=self.device,
                  inputs=[lm.views, lm.states, view_index, self.settings.photons, self.inputs.randoms, stream,
                          self._sort_keys, self._order])
        side = min(max(r.width, r.height), 1 << 14)
        begin, end = morton_sort_bits(side)
        wp.utils.radix_sort_pairs(self._sort_keys, self._order, slots, begin_bit=begin, end_bit=end)
        return self._order, 0, 1

    def photon_order(self, lm: LightMaps, view_index: int, r, slots: int, stream: int, max_lum: wp.array) -> wp.array:
        """The order in which to trace the ``slots`` photon slots of RSM view ``r`` (kernels take it with
        ``use_order``): by texel (:meth:`texel_order`), then stably grouped by how each will march (reflected,
        refracted, not traced: the longest marches first, ``common.REFLECTED_FIRST``;
        :func:`~.common.photon_group_keys` counts each group per block, a scan of the counts places the blocks,
        :func:`~.common.photon_group_scatter` writes the grouped order into ``_grouped``: no second sort, no device
        copies); slots past the view's photon count (on the device) are not written."""
        if self.use_order and slots > 0:
            order, stride, orders = self.texel_order(lm, view_index, r, slots, stream)
            sp, sc = r.specular, lm.scene
            blocks = (slots + self.group_block - 1) // self.group_block
            if blocks not in self._group_views:  # CUDA launches fixed slots: one pair of views, made at the first frame
                n = C.SORT_GROUPS * blocks
                self._group_views[blocks] = (self._group_counts[:n], self._group_offsets[:n])
            counts, offsets = self._group_views[blocks]
            grid = blocks if self.group_max_blocks is None else min(blocks, self.group_max_blocks)
            wp.launch_tiled(C.photon_group_keys, dim=grid, block_dim=self.group_block, device=self.device, inputs=[
                lm.views, lm.states, view_index, self.settings.photons, self.inputs.randoms, stream,
                lm.emission(r), sp.tri_id, sc.geometry, sc.triangle_material, sc.opacity, max_lum,
                float(self.settings.roughness_cutoff), float(self.settings.luminance_cutoff),
                order, stride, orders, slots, self._sort_keys, counts, grid, int(self.BALLOT_GROUPS)])
            wp.utils.array_scan(counts, offsets, inclusive=False)
            wp.launch_tiled(C.photon_group_scatter, dim=grid, block_dim=self.group_block, device=self.device,
                            inputs=[lm.states, view_index, self.settings.photons, self._sort_keys, order, stride,
                                    orders, slots, offsets, self._grouped, grid, int(self.BALLOT_GROUPS)])
            return self._grouped
        return self._order

    def rsm_batches(self, frame: int) -> Iterator[RSMBatch]:
        """Every light's RSM views for ``frame``, each with its photon count, random streams (the same for
        every method: cisp, sspm and caustics_map trace the same photons) and tracing order. Views that emit
        nothing are left out where the host knows it (whole views, the CPU), launched empty on CUDA."""
        s = self.settings
        for li, lm in enumerate(self.lights):
            light_pos = wp.vec3(*np.asarray(lm.light.position, np.float32))
            slots = self.view_slots(lm)
            # with lanes, each view's photons (and the caller's launches for its batch, between the yields) go on the
            # view's lane with its scratch bank, after its light's lane (its RSM views, its luminance maximum)
            after = () if self._active_lanes() is None else (self.lanes.mark(li),)
            for vi, r in enumerate(lm.rsm):
                if slots[vi] == 0:
                    continue
                with self.view_lane(li, vi, after):
                    sx, sy, seed = frame_random(s.seed, frame, li * 64 + vi)
                    scramble = wp.vec2i(sx, sy)
                    params = None if lm.fitted else lm.params[vi]
                    skip = None if lm.fitted else wp.vec4(0.0)
                    stream = self.inputs.rsm_stream(li, vi)
                    yield RSMBatch(li, vi, lm, params, r, slots[vi], seed, scramble,
                                   self.photon_order(lm, vi, r, slots[vi], stream, self._max_lum_of[li]), light_pos,
                                   skip, float(s.luminance_cutoff), slots[vi], s.photons, stream)

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        raise NotImplementedError

    def read_ledger(self) -> Ledger:
        """Host copy of this frame's ledger, folded first (a device->host copy: not for the inner frame loop)."""
        self.fold_ledger()
        return Ledger(self.ledger.numpy())

    def aovs(self, shape: tuple[int, int]) -> dict[str, np.ndarray]:
        """Method-specific AOVs beyond ``photon_map`` (host copies); none by default."""
        return {}
