"""A light's maps: its RSM views (whole, or fitted to the camera as cascades), and its shadow maps.

With ``LightViewSettings(fit="scene")`` a light has today's whole views (one orthographic view over the
specular geometry for a sun, the cone for a spot, six cube faces for a point light), and its RSM views
are those. With ``fit="camera"`` (the default) each whole view is also drawn small as a *pilot*, and
the RSM views photons start from are ``cascades`` windows of it per whole view, refitted every frame
to what the camera sees (:meth:`LightMaps.set_windows`, from ``cisp_warp.photons.fit``):

============  ======================  =====================================================================
list          views                   what reads them
============  ======================  =====================================================================
``rsm``       fitted cascades, or     photon emission (``rsm_batches``); an inactive cascade emits nothing
              the whole views
``pilot``     whole views, small      the fit's pilot photons; the brightest texel (luminance cutoff); the
                                      power outside every window (booked ``outside_fitted_view``); each
                                      view's cascades are windows of it turned about its axis
shadows       whole views             direct light: a sun's scene-wide view, and a spot or point light's
                                      whole views when its RSM views are fitted
============  ======================  =====================================================================

Nothing is allocated per frame: every cascade keeps its ``rsm_size``² buffers and only its view moves.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import SceneError
from ..scene.device import LAYER_BITS, DeviceScene
from ..scene.model import LAYER_OPAQUE, LAYER_SPECULAR, Light, LightKind
from . import kernels as K
from .rasterizer import Rasterizer, RSMView, visibility_buffer
from .views import (LightViewSettings, View, ViewParams, light_views, resized_view, rotated_view, shadow_view,
                    window_view)

EMPTY_WINDOW = (0.0, 0.0, 0.0, 0.0)


#: a view whose ``far`` is this draws nothing (an inactive cascade: the rasterizer culls every triangle)
INACTIVE_FAR = 0.0


@wp.struct
class CascadeState:
    """What one RSM view does this frame besides its view (``LightMaps.views``); written by the fit, on the device
    (``photons.fit``) or from the host (:meth:`LightMaps.set_windows`), read by the photon kernels."""

    active: int  #: 1: emits photons this frame
    active_views: int  #: active views of this light: its photons are split evenly over them
    skip_window: wp.vec4  #: (x0, y0, x1, y1) in this view's pixels, sampled by the finer cascade; empty when x1 <= x0
    texel_scale: float  #: whole-view (pilot) texels per texel of this view: scales the luminance cutoff
    changed: int  #: 1: the view moved this frame (its texel solid angles are rewritten)


@wp.func
def cascade_photons(state: CascadeState, light_photons: int) -> int:
    """Photons a view emits this frame: the light's ``light_photons`` split evenly over its active views
    (``PhotonPass.photons_per_view`` on the device), 0 when inactive."""
    if state.active == 0:
        return 0
    return wp.max(1, light_photons / wp.max(1, state.active_views))


@wp.func
def _corner(x: wp.float64, y: wp.float64) -> wp.float64:
    return wp.atan(x * y / wp.sqrt(wp.float64(1.0) + x * x + y * y))


@wp.func
def texel_solid_angle(view: ViewParams, p: int) -> float:
    """Exact solid angle [sr] of texel ``p`` of a perspective view, float64 inside (a fitted view's texels are
    small and the formula subtracts near-equal terms)."""
    i = p % view.width
    j = p / view.width
    fx = wp.float64(view.fx)
    fy = wp.float64(view.fy)
    x0 = (wp.float64(i) - wp.float64(view.cx)) / fx
    x1 = (wp.float64(i + 1) - wp.float64(view.cx)) / fx
    y0 = (wp.float64(j) - wp.float64(view.cy)) / fy
    y1 = (wp.float64(j + 1) - wp.float64(view.cy)) / fy
    return wp.float32(_corner(x1, y1) - _corner(x0, y1) - _corner(x1, y0) + _corner(x0, y0))


@wp.kernel
def texel_solid_angles(view: ViewParams, out: wp.array(dtype=wp.float32)):
    """Exact solid angle [sr] of every texel of a perspective view (``View.texel_solid_angle`` on the device).

    ``out``: (H*W,) float32 (write)."""
    p = wp.tid()
    out[p] = texel_solid_angle(view, p)


#: texels each thread of :func:`cascade_solid_angles` covers: a view that stands still costs one flag read per
#: thread, so fewer threads; 8 leaves ~500k threads of a 2048² view for the float64 work when it moved
CASCADE_TEXELS_PER_THREAD = wp.constant(8)


@wp.kernel
def cascade_solid_angles(views: wp.array(dtype=ViewParams), states: wp.array(dtype=CascadeState), view_index: int,
                         texels: int, out: wp.array(dtype=wp.float32)):
    """:func:`texel_solid_angles` of ``views[view_index]``, only when the fit moved it (``states[..].changed``):
    launched every frame with fixed dims, ``ceil(texels / CASCADE_TEXELS_PER_THREAD)`` threads, thread t writing
    texels t, t + threads, ... (coalesced); one flag read per thread when the view stands still.

    ``texels``: H*W; ``out``: (H*W,) float32 (write when changed)."""
    if states[view_index].changed == 0:
        return
    view = views[view_index]
    if view.orthographic != 0 or view.far <= INACTIVE_FAR:
        return
    t = wp.tid()
    threads = (texels + CASCADE_TEXELS_PER_THREAD - 1) / CASCADE_TEXELS_PER_THREAD
    for i in range(CASCADE_TEXELS_PER_THREAD):
        p = t + i * threads
        if p < texels:
            out[p] = texel_solid_angle(view, p)


#: threads per view of :func:`cascade_solid_angles_all` at most: a light's views that stand still then cost 512 blocks
#: that read one flag each (2048 a 2048² view at CASCADE_TEXELS_PER_THREAD; ~2 µs a thousand blocks to schedule on an
#: H100, perf_notes section 40), one that moved 32 texels a thread (~4 blocks of 256 an SM for its float64 work)
CASCADE_THREADS_PER_VIEW = 1 << 17


@wp.kernel
def cascade_solid_angles_all(views: wp.array(dtype=ViewParams), states: wp.array(dtype=CascadeState), texels: int,
                             threads: int, out: wp.array(dtype=wp.float32)):
    """:func:`cascade_solid_angles` of every view of a light in one launch, ``dim = (V, threads)``: thread (k, t)
    writes texels t, t + threads, ... (coalesced) of view k where the fit moved it; one flag read where it did not.

    ``texels``: H*W of each view; ``out``: (V*H*W,) float32, view k's at [k*H*W, (k+1)*H*W) (write when changed)."""
    k, t = wp.tid()
    if states[k].changed == 0:
        return
    view = views[k]
    if view.orthographic != 0 or view.far <= INACTIVE_FAR:
        return
    p = t
    while p < texels:
        out[k * texels + p] = texel_solid_angle(view, p)
        p += threads


#: 32-bit words of one ViewParams (compared bit for bit by :func:`redraw_gate`)
VIEW_WORDS = wp.types.type_size_in_bytes(ViewParams) // 4
#: texels each thread of :func:`clear_keys_if_drawn` covers (coalesced stride): a clear that is skipped costs one flag
#: read per thread, so fewer threads (H100, 2048²: 14 -> 5.5 µs). Not the resolve's: drawn, 8 texels a thread took
#: 0.144 ms for the pool's two maps against 0.117 at one (a skipped one 0.015 against 0.031), and the water moves
#: every frame of an animation (perf_notes 36)
SHADOW_TEXELS_PER_THREAD = wp.constant(8)


def view_words(views: wp.array) -> wp.array:
    """The memory of a ViewParams array as uint32 words (an alias, no copy): view k is words
    [k·VIEW_WORDS, (k + 1)·VIEW_WORDS)."""
    return wp.array(ptr=views.ptr, dtype=wp.uint32, shape=(views.shape[0] * VIEW_WORDS,), device=views.device)


@wp.func
def _gate(
    views: wp.array(dtype=ViewParams),
    words: wp.array(dtype=wp.uint32),
    view_index: int,
    generation: wp.array(dtype=wp.int32),
    layers: int,
    force: int,
    drawn_words: wp.array(dtype=wp.uint32),
    drawn_generation: wp.array(dtype=wp.int32),
) -> ViewParams:
    """:func:`redraw_gate`'s decision: the view to draw this frame (``far`` = INACTIVE_FAR: nothing), recording it as
    drawn when it is."""
    view = views[view_index]
    same = force == 0
    base = view_index * VIEW_WORDS
    for i in range(VIEW_WORDS):
        if words[base + i] != drawn_words[i]:
            same = False
    for b in range(LAYER_BITS):
        if ((layers >> b) & 1) != 0 and generation[b] != drawn_generation[b]:
            same = False
    if same:
        view.far = INACTIVE_FAR
    elif view.far > INACTIVE_FAR:
        for i in range(VIEW_WORDS):
            drawn_words[i] = words[base + i]
        for b in range(LAYER_BITS):
            drawn_generation[b] = generation[b]
    return view


@wp.kernel
def redraw_gate(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): gates views[view_index]
    words: wp.array(dtype=wp.uint32),  # (V·VIEW_WORDS,) the same memory as uint32 words (``view_words``, read)
    view_index: int,
    generation: wp.array(dtype=wp.int32),  # (LAYER_BITS,) DeviceScene.generation (read)
    layers: int,  # layer bits the view draws
    force: int,  # 1: draw whatever changed (the naive path)
    drawn_words: wp.array(dtype=wp.uint32),  # (VIEW_WORDS,) the view the maps were last drawn for (read, write)
    drawn_generation: wp.array(dtype=wp.int32),  # (LAYER_BITS,) the layers' generations then (read, write)
    draw: wp.array(dtype=ViewParams),  # (1,) the view to draw this frame (write)
):
    """One thread: whether a view's maps must be drawn this frame. They are a function of the view's parameters and
    of the triangles of ``layers``; when the view is, bit for bit, the one they were drawn for and no layer it draws
    moved since (``DeviceScene.generation``), ``draw`` gets the view with ``far`` = INACTIVE_FAR, which the raster
    and the resolves draw nothing for (the maps keep their values, the visibility stays clear); else the view itself,
    recorded as drawn. An inactive view draws nothing and records nothing. Decided on the device: a captured frame
    keeps deciding."""
    draw[0] = _gate(views, words, view_index, generation, layers, force, drawn_words, drawn_generation)


@wp.kernel
def redraw_gate_split(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): gates views[view_index]
    words: wp.array(dtype=wp.uint32),  # (V·VIEW_WORDS,) ``view_words(views)`` (read)
    view_index: int,
    generation: wp.array(dtype=wp.int32),  # (LAYER_BITS,) DeviceScene.generation (read)
    layers: int,  # layer bits the whole map draws
    opaque_layers: int,  # the layer bits whose keys are kept apart (LAYER_OPAQUE)
    drawn_words: wp.array(dtype=wp.uint32),  # (VIEW_WORDS,) the view the map was last drawn for (read, write)
    drawn_generation: wp.array(dtype=wp.int32),  # (LAYER_BITS,) its layers' generations then (read, write)
    draw: wp.array(dtype=ViewParams),  # (1,) the view to draw the specular layer and resolve for (write)
    drawn_opaque_words: wp.array(dtype=wp.uint32),  # (VIEW_WORDS,) as ``drawn_words``, for the kept opaque keys
    drawn_opaque_generation: wp.array(dtype=wp.int32),  # (LAYER_BITS,)
    draw_opaque: wp.array(dtype=ViewParams),  # (1,) the view to draw the opaque keys for (write)
):
    """A split shadow map's two gates (:func:`redraw_gate` over ``layers``, then over ``opaque_layers``) in one
    thread and one launch: the same decisions, in the same order, as the two launches (the twin)."""
    draw[0] = _gate(views, words, view_index, generation, layers, 0, drawn_words, drawn_generation)
    draw_opaque[0] = _gate(views, words, view_index, generation, opaque_layers, 0, drawn_opaque_words,
                           drawn_opaque_generation)


def _same_params(a: ViewParams, rec) -> bool:
    """Whether host view ``a`` is the record ``rec`` of ``views.numpy()``, field for field (float32)."""
    return (np.array_equal(np.asarray(a.world_to_view, np.float32).reshape(4, 4), np.asarray(rec["world_to_view"], np.float32))
            and all(np.float32(getattr(a, f)) == np.float32(rec[f]) for f in ("fx", "fy", "cx", "cy", "near", "far")))


#: threads of :func:`clear_keys_if_drawn` at most: a skipped clear (the frames whose opaque layer stood still) then
#: costs a few hundred blocks that read one flag each instead of 2048 (a 2048² map at SHADOW_TEXELS_PER_THREAD)
SHADOW_CLEAR_THREADS = 1 << 16


def shadow_clear_threads(n: int) -> int:
    """Threads :func:`clear_keys_if_drawn` is launched with for ``n`` keys."""
    return max(1, min(SHADOW_CLEAR_THREADS, (n + SHADOW_TEXELS_PER_THREAD - 1) // SHADOW_TEXELS_PER_THREAD))


@wp.kernel
def clear_keys_if_drawn(draw: wp.array(dtype=ViewParams), keys: wp.array(dtype=wp.uint64), threads: int):
    """Fill ``keys`` with EMPTY_KEY when ``draw[0]`` is drawn this frame (``redraw_gate``), else leave them.
    ``threads`` threads (:func:`shadow_clear_threads`), thread t covering texels t, t + threads, ... (coalesced)."""
    if draw[0].far <= INACTIVE_FAR:
        return
    t = wp.tid()
    n = keys.shape[0]
    p = t
    while p < n:
        keys[p] = K.EMPTY_KEY
        p += threads


@wp.kernel
def resolve_depth_over(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): resolves views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) the layers drawn this frame (read, then reset to EMPTY_KEY)
    under: wp.array(dtype=wp.uint64),  # (H*W,) keys of the layers kept from an earlier frame (read)
    points: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m] of the nearest surface of all of them (write)
):
    """``kernels.resolve_depth`` (depth only) of the nearer of two keys per texel: the minimum of the keys drawn into
    two buffers is the key one draw of both layers into one buffer leaves (``atomic_min`` of their union), so the
    depth is that draw's bit for bit. An inactive view returns at once."""
    view = views[view_index]
    if view.far <= INACTIVE_FAR:
        return
    p = wp.tid()
    key = K.take_key(visibility, p)
    u = under[p]
    if u < key:
        key = u
    tri, z, x, bary, d = K.triangle_hit(view, key, p, points, indices)
    depth[p] = z


class _ShadowView:
    """A depth-only view of every layer (a shadow map), drawn only when its view or the geometry moved
    (:func:`redraw_gate`). ``split`` (a scene whose specular triangles may move and whose opaque ones may not, such
    as the pool's water): the opaque layer's keys are kept in ``opaque_keys``, drawn only when the view or the
    opaque triangles moved, and a frame whose water moved draws the specular layer alone and resolves the nearer of
    the two keys per texel (``resolve_depth_over``): the same depth bit for bit as one draw of both layers."""

    LAYERS = LAYER_OPAQUE | LAYER_SPECULAR
    #: a split map's two gates in one launch (``redraw_gate_split``); False: two ``redraw_gate`` launches (the twin)
    FUSED_GATES = True

    def __init__(self, view: View, device, split: bool = False):
        n = view.width * view.height
        self.view, self.params = view, view.params()
        self.views = wp.array([self.params], dtype=ViewParams, device=device)
        self.visibility = visibility_buffer(n, device)
        self.depth = wp.zeros(n, dtype=wp.float32, device=device)
        self._words = view_words(self.views)
        self.draw_view = wp.zeros(1, dtype=ViewParams, device=device)  #: the view drawn this frame (``redraw_gate``)
        self.drawn_words = wp.zeros(VIEW_WORDS, dtype=wp.uint32, device=device)  #: zeros: no view, the first draws
        self.drawn_generation = wp.zeros(LAYER_BITS, dtype=wp.int32, device=device)
        self.split = bool(split)
        if self.split:
            self.opaque_keys = visibility_buffer(n, device)  #: (H*W,) uint64: the opaque layer's keys, kept
            self.draw_opaque = wp.zeros(1, dtype=ViewParams, device=device)
            self.drawn_opaque_words = wp.zeros(VIEW_WORDS, dtype=wp.uint32, device=device)
            self.drawn_opaque_generation = wp.zeros(LAYER_BITS, dtype=wp.int32, device=device)

    def set_view(self, view: View) -> None:
        self.view, self.params = view, view.params()
        self.views.assign([self.params])

    def render(self, raster: Rasterizer, cache: bool = True) -> None:
        """Draw and resolve the map; with ``cache``, only what :func:`redraw_gate` says changed (the launches are
        the same every frame: a gate's view draws nothing when its inputs stood still). Without ``cache`` (the
        naive path) both layers are drawn into one buffer and resolved every frame."""
        s = raster.scene
        w, h = self.view.width, self.view.height
        if cache and self.split and self.FUSED_GATES:  # both gates in one launch
            wp.launch(redraw_gate_split, dim=1, device=s.device,
                      inputs=[self.views, self._words, 0, s.generation, self.LAYERS, LAYER_OPAQUE, self.drawn_words,
                              self.drawn_generation, self.draw_view, self.drawn_opaque_words,
                              self.drawn_opaque_generation, self.draw_opaque])
        else:
            wp.launch(redraw_gate, dim=1, device=s.device,
                      inputs=[self.views, self._words, 0, s.generation, self.LAYERS, int(not cache), self.drawn_words,
                              self.drawn_generation, self.draw_view])
        if not (cache and self.split):
            raster.draw(self.draw_view, 0, w, h, self.LAYERS, self.visibility, clear=False)
            wp.launch(K.resolve_depth, dim=w * h, device=s.device,
                      inputs=[self.draw_view, 0, self.visibility, s.points, s.indices, self.depth, None])  # depth only
            return
        if not self.FUSED_GATES:
            wp.launch(redraw_gate, dim=1, device=s.device,
                      inputs=[self.views, self._words, 0, s.generation, LAYER_OPAQUE, 0, self.drawn_opaque_words,
                              self.drawn_opaque_generation, self.draw_opaque])
        threads = shadow_clear_threads(w * h)
        wp.launch(clear_keys_if_drawn, dim=threads, device=s.device, inputs=[self.draw_opaque, self.opaque_keys, threads])
        raster.draw(self.draw_opaque, 0, w, h, LAYER_OPAQUE, self.opaque_keys, clear=False)
        raster.draw(self.draw_view, 0, w, h, LAYER_SPECULAR, self.visibility, clear=False)
        wp.launch(resolve_depth_over, dim=w * h, device=s.device,
                  inputs=[self.draw_view, 0, self.visibility, self.opaque_keys, s.points, s.indices, self.depth])


def _params_of_record(rec) -> ViewParams:
    """A ViewParams from one record of a ViewParams array's ``numpy()`` (a structured array)."""
    v = ViewParams()
    v.world_to_view = wp.mat44(*np.asarray(rec["world_to_view"], np.float32).flatten())
    v.view_to_world = wp.mat44(*np.asarray(rec["view_to_world"], np.float32).flatten())
    v.fx, v.fy, v.cx, v.cy = (float(rec[f]) for f in ("fx", "fy", "cx", "cy"))
    v.near, v.far = float(rec["near"]), float(rec["far"])
    v.width, v.height, v.orthographic = int(rec["width"]), int(rec["height"]), int(rec["orthographic"])
    return v


def _state(active: bool, active_views: int, skip=EMPTY_WINDOW, texel_scale: float = 1.0, changed: bool = False):
    st = CascadeState()
    st.active, st.active_views = int(active), int(active_views)
    st.skip_window = wp.vec4(*(float(v) for v in skip))
    st.texel_scale, st.changed = float(texel_scale), int(changed)
    return st


class LightMaps:
    """All views of one light: RSM views (whole or fitted cascades), the fit's pilot views, shadow maps.

    What the photon passes read lives on the device, so a fit on the device needs no host copy:

    ============  =======================================  ================================================
    array         shape, dtype                             holds
    ============  =======================================  ================================================
    ``views``     (len(rsm),) ViewParams                   each RSM view this frame (``far`` = 0: inactive)
    ``states``    (len(rsm),) CascadeState                 active, photon split, finer window, texel scale
    ``pilot_views`` (len(pilot),) ViewParams               the whole views, small (static)
    ``outside``   (len(pilot),) vec4                       each pilot's coarsest window (pilot pixels turned by
                                                           ``outside_angle``), outside which nothing is sampled
    ``outside_angle`` (len(pilot),) float32                that turn [rad]
    ============  =======================================  ================================================
    """

    #: True (default): the fitted views (cascades and pilots) keep no ``shadow_depth`` (4 B a texel the resolves do
    #: not write; nothing of the frame reads it: perf_notes section 87); whole views keep theirs (``shadow_maps``
    #: reads it where the light has no shadow map of its own). False: every view keeps and writes it (main's path
    #: before section 87). Read when a ``LightMaps`` is made
    SKIP_UNREAD_SHADOW_DEPTH = True

    def __init__(self, scene: DeviceScene, light: Light, rsm_size: int,
                 view_settings: LightViewSettings | None = None):
        vs = view_settings or LightViewSettings(fit="scene")
        vs.validate()
        self.scene = scene
        self.light = light
        self.view_settings = vs
        self.fitted = vs.fit == "camera"
        self.rsm_size = int(rsm_size)
        whole = light_views(scene.scene, light, rsm_size)
        d = scene.device
        if self.fitted:
            # a fitted cascade's and a pilot's shadow depth is read by nothing of the frame (the direct light's shadow
            # lookups read the light's own shadow maps, ``_shadows``; the fit reads the pilots' two layers): not
            # allocated, not written, unless a reader asks (:meth:`keep_shadow_depth`; perf_notes section 87)
            shadow = not self.SKIP_UNREAD_SHADOW_DEPTH
            self.pilot = [RSMView.allocate(resized_view(v, vs.pilot_size, f"pilot_{v.name[4:]}"), d, False, False,
                                           shadow) for v in whole]
            self.rsm = [RSMView.allocate(window_view(v, (0, 0, v.width, v.height), rsm_size, f"{v.name}_c{c}"), d,
                                         False, False, shadow) for v in whole for c in range(vs.cascades)]
            self.cascades = vs.cascades
            # the cascades' texel solid angles in one array, each view's ``solid_angle`` a slice of it (in view order):
            # the fit rewrites the moved ones in one launch (refresh_cascade_solid_angles)
            n = rsm_size * rsm_size
            assert all(r.width * r.height == n for r in self.rsm)
            self.cascade_solid_angle = wp.zeros(len(self.rsm) * n, dtype=wp.float32, device=d)
            for k, r in enumerate(self.rsm):
                wp.copy(self.cascade_solid_angle, r.solid_angle, dest_offset=k * n, count=n)
                r.solid_angle = self.cascade_solid_angle[k * n : (k + 1) * n]
        else:
            self.pilot = []
            self.rsm = [RSMView.allocate(v, d, False, False) for v in whole]
            self.cascades = 1
            self.cascade_solid_angle = None  #: (len(rsm) * rsm_size²,) float32: fitted views' solid angles, else None
        #: host ViewParams of the RSM views: exact for whole views; for fitted ones the views they start from
        #: (the fit writes ``views`` on the device)
        self.params = [r.view.params() for r in self.rsm]
        self.views = wp.array(self.params, dtype=ViewParams, device=d)
        self.states = wp.array([_state(True, len(self.rsm)) for _ in self.rsm], dtype=CascadeState, device=d)
        self.pilot_views = wp.array([r.view.params() for r in self.pilot] or [ViewParams()], dtype=ViewParams, device=d)
        n_pilot = max(1, len(self.pilot))
        self.outside = wp.zeros(n_pilot, dtype=wp.vec4, device=d)
        self.outside_angle = wp.zeros(n_pilot, dtype=wp.float32, device=d)
        self._shadows: list[_ShadowView] = []
        self._make_shadows(light, whole)
        #: the views' specular layers keep no per-texel ``position`` and ``normal`` (24 B a texel the resolve does not
        #: write): the photon passes compute them where they need them (``kernels.texel_surface``, from ``tri_id`` and
        #: ``depth``); a reader of the arrays (wavefront splats) asks for them with :meth:`keep_surface_maps`
        #: resolve each RSM view's ``opaque_tri`` (its opaque triangle per texel): only the caustics map reads it, so a
        #: renderer of another method sets False and the opaque resolve writes 4 B per texel fewer (the array then
        #: keeps what it held; it is not an AOV of :meth:`RSMView.numpy`)
        self.write_opaque_tri = True
        #: True (default): resolve each RSM view in one tiled pass (``kernels.resolve_rsm_view``: the opaque depth, the
        #: specular layer, shadow depth and flux, and the depth bounds a photon pass asked for with
        #: :meth:`keep_depth_bounds`); False: its naive twins, ``resolve_depth`` then ``resolve_rsm_specular`` (the
        #: photon pass then builds its bounds itself). The same buffers bit for bit
        self.fused_resolve = True
        self._bounds: list[wp.array] | None = None
        self._bounds_thickness = (0.0, 0.0)
        #: True (default): a shadow map is drawn only in frames where its view or the triangles it draws moved
        #: (``redraw_gate``, decided on the device); False: every frame (the naive path). The same maps bit for bit
        self.cache_shadows = True

    # ---- host views of the device state (tests, tools: each is a device->host copy)

    def _state_records(self) -> np.ndarray:
        return self.states.numpy()

    @property
    def active(self) -> list[bool]:
        """Per RSM view: emits this frame (whole views always; a fitted cascade read back from the device)."""
        if not self.fitted:
            return [True] * len(self.rsm)
        return [bool(r["active"]) for r in self._state_records()]

    @property
    def skip_windows(self) -> list[tuple[float, float, float, float]]:
        return [tuple(float(v) for v in r["skip_window"]) for r in self._state_records()]

    @property
    def texel_scale(self) -> list[float]:
        return [float(r["texel_scale"]) for r in self._state_records()]

    @property
    def outside_windows(self) -> list[tuple[float, float, float, float]]:
        return [tuple(float(v) for v in w) for w in self.outside.numpy()[: len(self.pilot)]]

    @property
    def outside_angles(self) -> list[float]:
        return [float(a) for a in self.outside_angle.numpy()[: len(self.pilot)]]

    def host_views(self) -> list[K.ViewParams]:
        """Per RSM view, its ViewParams as the device holds them now (the fitted cascades' poses; a device->host
        copy: for passes that take views by value, such as wavefront splatting, not for the real-time frame)."""
        if not self.fitted:
            return list(self.params)
        return [_params_of_record(rec) for rec in self.views.numpy()]

    def host_active(self) -> list[bool] | None:
        """Per RSM view, whether it emits, where the host can know it without waiting for the device: always for
        whole views, on the CPU (its arrays are host memory) for fitted ones; None on CUDA (launch every view,
        inactive ones do nothing)."""
        if not self.fitted:
            return [True] * len(self.rsm)
        if self.scene.device.is_cpu:
            return [bool(a) for a in self.states.numpy()["active"]]
        return None

    def _make_shadows(self, light: Light, whole: list[View]) -> None:
        sv = shadow_view(self.scene.scene, light, self.rsm_size)
        views = [sv] if sv is not None else (whole if self.fitted else [])
        if len(self._shadows) == len(views):
            for s, v in zip(self._shadows, views):
                s.set_view(v)
        else:
            # the opaque keys kept apart where only the specular triangles may move (the pool's water)
            dyn, has = self.scene.dynamic_layers, self.scene.has_layer
            split = (has[LAYER_OPAQUE] and has[LAYER_SPECULAR] and (dyn & LAYER_SPECULAR) != 0
                     and (dyn & LAYER_OPAQUE) == 0)
            self._shadows = [_ShadowView(v, self.scene.device, split) for v in views]

    @property
    def whole_rsm(self) -> list[RSMView]:
        """The views over all the light's specular geometry (pilot views when fitted)."""
        return self.pilot if self.fitted else self.rsm

    @property
    def whole_views(self) -> wp.array:
        """The device views of :attr:`whole_rsm` (``pilot_views`` when fitted, else ``views``)."""
        return self.pilot_views if self.fitted else self.views

    def set_light(self, light: Light) -> None:
        """Move or re-aim the light for the next frame: its views are refitted, every buffer is kept.

        The light must keep its kind and its number of views (a spot's cone may change: the texels'
        solid angles are rewritten). Every pass reads ``light`` and ``params`` at launch.
        """
        whole = light_views(self.scene.scene, light, self.rsm_size)
        n_whole = len(self.pilot) if self.fitted else len(self.rsm)
        if light.kind != self.light.kind or len(whole) != n_whole:
            raise SceneError(f"light '{light.name}' changes its kind or its views; build a new renderer",
                             prim=light.name)
        if self.fitted:
            for r, v in zip(self.pilot, whole):
                r.view = resized_view(v, r.width, r.view.name)
            for k, r in enumerate(self.rsm):
                r.view = window_view(whole[k // self.cascades], (0, 0, self.rsm_size, self.rsm_size), r.width, r.view.name)
            self._refresh_solid_angles(self.pilot)
            self.pilot_views.assign([r.view.params() for r in self.pilot])
            self.states.assign([_state(True, len(self.rsm)) for _ in self.rsm])
        else:
            for r, v in zip(self.rsm, whole):
                r.view = v
        self._refresh_solid_angles(self.rsm)
        self.params = [r.view.params() for r in self.rsm]
        self.views.assign(self.params)
        self._make_shadows(light, whole)  # the new light's (a sun's shadow view kept the old one's before)
        self.light = light

    def _refresh_solid_angles(self, views: list[RSMView]) -> None:
        for r in views:
            if not r.view.orthographic:
                wp.launch(texel_solid_angles, dim=r.width * r.height, device=self.scene.device,
                          inputs=[r.view.params(), r.solid_angle])

    #: every fitted view's texel solid angles in one launch (``cascade_solid_angles_all`` over ``cascade_solid_angle``);
    #: False: one ``cascade_solid_angles`` launch per view (the twin)
    FUSED_SOLID_ANGLES = True

    def refresh_cascade_solid_angles(self) -> None:
        """Rewrite the texel solid angles of the perspective RSM views the fit moved (device flags; fixed dims)."""
        if self.light.kind == LightKind.DISTANT:
            return
        if self.FUSED_SOLID_ANGLES and self.cascade_solid_angle is not None:
            n = self.rsm_size * self.rsm_size
            threads = min(CASCADE_THREADS_PER_VIEW, (n + CASCADE_TEXELS_PER_THREAD - 1) // CASCADE_TEXELS_PER_THREAD)
            wp.launch(cascade_solid_angles_all, dim=(len(self.rsm), threads), device=self.scene.device,
                      inputs=[self.views, self.states, n, threads, self.cascade_solid_angle])
            return
        for k, r in enumerate(self.rsm):
            n = r.width * r.height
            wp.launch(cascade_solid_angles, dim=(n + CASCADE_TEXELS_PER_THREAD - 1) // CASCADE_TEXELS_PER_THREAD,
                      device=self.scene.device, inputs=[self.views, self.states, k, n, r.solid_angle])

    def set_windows(self, windows: list[list[tuple[float, float, float, float]]], angles: list[float] | None = None) -> None:
        """Fit the cascades for this frame from the host (the naive twin of the device fit, ``photons.fit``):
        ``windows[b]`` are pilot view b's windows (x0, y0, x1, y1) in the pixels of that view turned by
        ``angles[b]`` [rad] about its axis (``views.rotated_view``; 0 when None), finest first and nested
        (``views.fit_windows``); fewer than ``cascades`` leaves the finest cascades inactive, none leaves them all
        inactive (nothing of b is seen). Writes ``views``, ``states``, ``outside`` and ``outside_angle`` on the
        device exactly as the device fit does (an inactive view keeps its last pose with ``far`` = 0); nothing is
        allocated on the device."""
        if not self.fitted:
            raise ValueError("set_windows needs LightViewSettings(fit='camera')")
        angles = [0.0] * len(self.pilot) if angles is None else [float(a) for a in angles]
        old = self.views.numpy()
        params, states, outside = [], [], []
        for b, (pilot, wins) in enumerate(zip(self.pilot, windows)):
            base = rotated_view(pilot.view, angles[b])
            c_empty = self.cascades - len(wins)
            outside.append(tuple(wins[-1]) if wins else EMPTY_WINDOW)
            for c in range(self.cascades):
                k = b * self.cascades + c
                r = self.rsm[k]
                if c < c_empty:
                    rec = old[k]
                    v = _params_of_record(rec)
                    v.far = INACTIVE_FAR
                    params.append(v)
                    states.append((False, EMPTY_WINDOW, 1.0, not _same_params(v, rec)))
                    continue
                win = wins[c - c_empty]
                view = window_view(base, win, r.width, r.view.name)
                finer = wins[c - c_empty - 1] if c > c_empty else None
                sx, sy = r.width / (win[2] - win[0]), r.height / (win[3] - win[1])
                skip = EMPTY_WINDOW if finer is None else (
                    (finer[0] - win[0]) * sx, (finer[1] - win[1]) * sy, (finer[2] - win[0]) * sx, (finer[3] - win[1]) * sy)
                v = view.params()
                params.append(v)
                states.append((True, skip, 1.0 / (sx * sy), not _same_params(v, old[k])))  # pilot texels per texel
        n_active = sum(st[0] for st in states)
        self.views.assign(params)
        self.states.assign([_state(a, n_active, sk, ts, ch) for a, sk, ts, ch in states])
        self.outside.assign(np.asarray(outside, np.float32).reshape(-1, 4))
        self.outside_angle.assign(np.asarray(angles, np.float32))
        self.refresh_cascade_solid_angles()

    def shadow_maps(self) -> list[tuple[K.ViewParams, wp.array]]:
        """(view, depth of nearest surface of any layer) pairs that together cover what the light reaches."""
        if self._shadows:
            return [(s.params, s.depth) for s in self._shadows]
        assert all(r.has_shadow_depth for r in self.rsm), "whole views keep their shadow depth"
        return [(p, r.shadow_depth) for p, r in zip(self.params, self.rsm)]  # whole views: host-known

    @property
    def shadow_view(self) -> View | None:
        """A sun's scene-wide shadow view (None for point and spot lights)."""
        sv = [s.view for s in self._shadows if s.view.orthographic]
        return sv[0] if sv else None

    def keep_depth_bounds(self, bounds: list[wp.array], thickness: float, thickness_rel: float) -> None:
        """Have the resolve write the depth bounds of each RSM view's opaque depth (``photons.march.depth_bounds`` and
        ``coarsen_bounds`` with these thicknesses) into ``bounds[k]`` (``march.bounds_size`` each) every frame the view
        is drawn: a photon pass that marches the views asks for them here instead of building them after the resolve
        (:meth:`builds_depth_bounds`). Only with ``fused_resolve``."""
        if len(bounds) != len(self.rsm) or any(b.shape[0] != K.bounds_size(r.width, r.height)
                                               for b, r in zip(bounds, self.rsm)):
            raise ValueError(f"keep_depth_bounds needs one bounds array per RSM view ({len(self.rsm)}), each of "
                             f"march.bounds_size of its view")
        self._bounds = list(bounds)
        self._bounds_thickness = (float(thickness), float(thickness_rel))

    def keep_surface_maps(self) -> None:
        """Have every RSM view's specular layer keep its per-texel ``position`` and ``normal`` (allocated here and
        written by each resolve from the next on; by default they are not: ``RSMView.allocate(surface=False)``), for a
        consumer that reads the arrays (``photons.wavefront``); pilot views are left without (the fit computes them)."""
        for r in self.rsm:
            r.specular.keep_surface()

    def keep_shadow_depth(self) -> None:
        """Have every RSM view keep its ``shadow_depth`` (allocated here and written by each resolve from the next on;
        fitted views keep none by default: :attr:`SKIP_UNREAD_SHADOW_DEPTH`), for a consumer that reads the array
        (``photons.meshgrid``'s ``mesh_cells``, tests); pilot views are left without."""
        for r in self.rsm:
            r.keep_shadow_depth()

    def keep_texel_maps(self) -> None:
        """Have every RSM and pilot view keep its per-texel ``flux`` and its specular layer's ``roughness`` and ``ior``
        (allocated here, written by each resolve from the next on; by default they are not: the photon passes compute
        them from the texel's triangle with :meth:`emission`), for tests and tools that read the arrays."""
        for r in self.rsm + self.pilot:
            r.keep_texel_maps()

    def emission(self, r: RSMView) -> K.TexelEmission:
        """What RSM (or pilot) view ``r``'s texels' flux, roughness and IOR are computed from where they are read
        (``kernels.texel_emitted_flux``, ``texel_roughness``, ``texel_ior``): this light's terms as the resolve
        takes them this frame, the view's texel solid angles and the scene's materials."""
        s = self.scene
        light = self.light
        e = K.TexelEmission()
        e.light_rgb = wp.vec3(*light.radiometric_rgb.astype(np.float32))
        e.spot_axis = wp.vec3(*np.asarray(light.direction, dtype=np.float32))
        e.is_spot = int(light.kind == LightKind.SPOT)
        e.cone_angle = float(light.cone_angle)
        e.cone_softness = float(light.cone_softness)
        e.cone_cos_inner, e.cone_cos_outer = K.spot_cone_cosines(light.cone_angle, light.cone_softness)
        e.texel_solid_angle = r.solid_angle
        e.triangle_material = s.triangle_material
        e.mat_roughness = s.roughness
        e.mat_ior = s.ior
        return e

    def builds_depth_bounds(self, bounds: wp.array) -> bool:
        """Whether the resolve writes ``bounds`` (one of :meth:`keep_depth_bounds`'s) each frame the view is drawn."""
        return self.fused_resolve and self._bounds is not None and any(b is bounds for b in self._bounds)

    def _render_rsm(self, raster: Rasterizer, views: wp.array, k: int, r: RSMView,
                    bounds: wp.array | None = None) -> None:
        s = self.scene
        light = self.light
        n = r.width * r.height
        rgb = light.radiometric_rgb.astype(np.float32)
        axis = np.asarray(light.direction, dtype=np.float32)
        raster.draw(views, k, r.width, r.height, LAYER_OPAQUE, r.visibility, clear=False,
                    layer_b=LAYER_SPECULAR, visibility_b=r.specular.visibility)  # both layers in one pass
        sp = r.specular
        if self.fused_resolve:  # both layers, the flux and the depth bounds in one pass over the view
            th, th_rel = self._bounds_thickness
            coarse = ((r.width + K.BOUNDS_COARSE - 1) // K.BOUNDS_COARSE) * ((r.height + K.BOUNDS_COARSE - 1) // K.BOUNDS_COARSE)
            wp.launch_tiled(K.resolve_rsm_view, dim=coarse, block_dim=K.RESOLVE_THREADS, device=s.device,
                            inputs=[views, k, r.visibility, sp.visibility, s.points, s.normals, s.indices,
                                    s.triangle_material, s.roughness, s.ior, wp.vec3(*rgb), wp.vec3(*axis),
                                    int(light.kind == LightKind.SPOT), float(light.cone_angle),
                                    float(light.cone_softness), r.solid_angle, r.opaque_depth,
                                    r.opaque_tri if self.write_opaque_tri else None, sp.depth, sp.position,
                                    sp.normal, sp.roughness, sp.ior, sp.tri_id, r.shadow_depth, r.flux, th, th_rel,
                                    bounds])
            return
        wp.launch(K.resolve_depth, dim=n, device=s.device,
                  inputs=[views, k, r.visibility, s.points, s.indices, r.opaque_depth,
                          r.opaque_tri if self.write_opaque_tri else None])
        # its layer, the shadow depth (nearest of both layers) and the flux per texel, in one pass
        wp.launch(K.resolve_rsm_specular, dim=n, device=s.device,
                  inputs=[views, k, sp.visibility, r.opaque_depth, s.points, s.normals, s.indices, s.triangle_material,
                          s.roughness, s.ior, wp.vec3(*rgb), wp.vec3(*axis), int(light.kind == LightKind.SPOT),
                          float(light.cone_angle), float(light.cone_softness), r.solid_angle,
                          sp.depth, sp.position, sp.normal, sp.roughness, sp.ior, sp.tri_id, r.shadow_depth, r.flux])

    def render_pilot(self, raster: Rasterizer) -> None:
        """Draw the pilot views (before the fit); nothing when the views are not fitted."""
        for k, r in enumerate(self.pilot):
            self._render_rsm(raster, self.pilot_views, k, r)

    def render(self, raster: Rasterizer) -> None:
        """Draw the RSM views and the shadow maps. On CUDA every fitted cascade is launched (an inactive one,
        ``far`` = 0, draws and resolves nothing: its maps keep the values of the frame it was last active, which
        nothing reads while it emits no photons): the host never waits for the fit."""
        active = self.host_active()
        for k, r in enumerate(self.rsm):
            if active is None or active[k]:
                self._render_rsm(raster, self.views, k, r, self._bounds[k] if self._bounds is not None else None)
        for sv in self._shadows:
            sv.render(raster, self.cache_shadows)
