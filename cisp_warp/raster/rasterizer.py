"""The software rasterizer and the two kinds of view it fills: the camera G-buffer and light RSMs
(a light's set of views is ``light_maps.LightMaps``).

Every buffer is a flat Warp array of ``height * width`` pixels in row-major order (row 0 at the
top); ``numpy()`` helpers reshape to (height, width[, C]). Buffers are allocated once, when the
pass is built, and overwritten every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import warp as wp

from ..scene.device import DeviceScene, check_memory
from ..scene.model import LAYER_OPAQUE, LAYER_SPECULAR
from . import kernels as K
from .views import View


#: blocks of 256 threads of ``kernels.raster_tile_columns`` resident on one SM: 65536 registers / (74 registers x 256)
#: (sm_90 cubin, ``tools/regcount.py --modules cisp_warp.raster.kernels``)
COLUMN_BLOCKS_PER_SM = 3


class Rasterizer:
    """Visibility-buffer rasterizer over one :class:`DeviceScene`; its scratch is allocated once."""

    def __init__(self, scene: DeviceScene):
        self.scene = scene
        d = scene.device
        n_sub = 2 * scene.triangle_count
        self.sub_v = wp.zeros(3 * n_sub, dtype=wp.vec3, device=d)  # screen vertices of clipped triangles
        self.sub_bbox = wp.zeros(n_sub, dtype=wp.vec4i, device=d)  # their pixel boxes
        self.tile_count = wp.zeros(n_sub, dtype=wp.int32, device=d)  # 8x8 tiles each touches
        self.tile_end = wp.zeros(n_sub, dtype=wp.int32, device=d)  # inclusive scan of tile_count
        # grid-stride width of the tile kernel: enough threads to fill a GPU; the CPU runs them serially (a multiple
        # of kernels.WARP: the column raster hands work out by warps)
        self.stride = (1 << 18) if d.is_cuda else (1 << 10)
        #: True: draw with ``kernels.raster_tile_columns`` (a thread per pixel column of a tile); False (default): a
        #: thread per tile (``reject`` below, or the naive twin ``raster_tiles``; the same buffers bit for bit on the
        #: CPU). The column raster lost on the H100 (perf_notes section 24: pool 1.09 -> 1.81 ms, Cornell 0.40 -> 0.62
        #: ms per frame), so it is opt-in
        self.columns = False
        #: True (default): draw with ``kernels.raster_tiles_reject`` (a thread per tile as ``raster_tiles``, the tiles
        #: proven outside an edge skipped, blocks of ``kernels.RASTER_BLOCK``; perf_notes section 52); False: its naive
        #: twin ``raster_tiles``. The same buffers bit for bit on the CPU
        self.reject = True
        #: with ``reject``: views of at most this many pixels (the pilots) are drawn with ``kernels.raster_tile_rows`` (a
        #: thread per tile row: their few items fill the GPU 8x better); 0: never
        self.rows_max_pixels = 512 * 512
        #: threads of the column raster on CUDA: one resident wave (``COLUMN_BLOCKS_PER_SM`` blocks of 256 an SM), so
        #: that its equal chunks of work end together (2^18 threads were 2.6 waves); None: ``stride``
        self.column_threads = d.sm_count * COLUMN_BLOCKS_PER_SM * 256 if d.is_cuda and d.sm_count > 0 else None

    def draw(self, views: wp.array, view_index: int, width: int, height: int, layer: int, visibility: wp.array,
             clear: bool = True, layer_b: int = 0, visibility_b: wp.array | None = None) -> None:
        """Rasterize the triangles of ``layer`` into ``visibility`` (H*W uint64) for the view ``views[view_index]`` (a
        device array of :class:`ViewParams`, so a view fitted on the device, or a camera written once per frame, is
        drawn without the host knowing it; ``width`` × ``height`` is its size, fixed). An inactive view (``far`` = 0,
        ``light_maps.INACTIVE_FAR``) draws nothing. ``layer_b``, ``visibility_b``: a second layer drawn in the same
        pass into its own buffer (one set-up, scan and tile walk for both; a triangle in both layers is drawn into
        both). ``clear``: fill the buffers with ``EMPTY_KEY`` first; False when they are clear already: the resolve
        kernels reset every pixel they read (``kernels.take_key``), so a buffer made by :func:`visibility_buffer`
        and always resolved after its draw needs no fill per frame."""
        d = self.scene.device
        s = self.scene
        if visibility_b is None:
            layer_b, visibility_b = 0, visibility
        if clear:
            visibility.fill_(K.EMPTY_KEY_VALUE)
            if layer_b != 0:
                visibility_b.fill_(K.EMPTY_KEY_VALUE)
        self._setup(views, view_index, width, height, layer | layer_b, back_only=False)
        if self.columns:
            threads = self.column_threads or self.stride
            wp.launch(K.raster_tile_columns, dim=threads, device=d,
                      inputs=[views, int(view_index), self.sub_v, self.sub_bbox, self.tile_end, 2 * s.triangle_count,
                              threads // K.WARP, s.triangle_layers, int(layer), visibility, int(layer_b),
                              visibility_b])
        elif self.reject and width * height <= self.rows_max_pixels:
            wp.launch(K.raster_tile_rows, dim=self.stride, device=d,
                      inputs=[views, int(view_index), self.sub_v, self.sub_bbox, self.tile_end, 2 * s.triangle_count,
                              self.stride, s.triangle_layers, int(layer), visibility, int(layer_b), visibility_b])
        elif self.reject:
            wp.launch(K.raster_tiles_reject, dim=self.stride, device=d, block_dim=K.RASTER_BLOCK,
                      inputs=[views, int(view_index), self.sub_v, self.sub_bbox, self.tile_end, 2 * s.triangle_count,
                              self.stride, s.triangle_layers, int(layer), visibility, int(layer_b), visibility_b])
        else:
            wp.launch(K.raster_tiles, dim=self.stride, device=d,
                      inputs=[views, int(view_index), self.sub_v, self.sub_bbox, self.tile_end, 2 * s.triangle_count,
                              self.stride, s.triangle_layers, int(layer), visibility, int(layer_b), visibility_b])

    def _setup(self, views: wp.array, view_index: int, width: int, height: int, layer_mask: int,
               back_only: bool) -> None:
        """Near-clip and project the triangles of ``layer_mask`` (only those facing away from the view with
        ``back_only``) into ``sub_v`` / ``sub_bbox``, count their tiles and scan the counts into ``tile_end``."""
        s = self.scene
        tiles_x = (width + K.TILE - 1) // K.TILE
        tiles_y = (height + K.TILE - 1) // K.TILE
        wp.launch(K.setup_triangles, dim=s.triangle_count, device=s.device,
                  inputs=[views, int(view_index), s.points, s.indices, s.triangle_layers, int(layer_mask), tiles_x,
                          tiles_y, self.sub_v, self.sub_bbox, self.tile_count, s.normals, int(back_only)])
        wp.utils.array_scan(self.tile_count, self.tile_end, inclusive=True)

    def draw_back(self, views: wp.array, view_index: int, width: int, height: int, layer: int,
                  front_depth: wp.array, visibility: wp.array) -> None:
        """The back-face layer of ``layer`` behind the resolved front depth ``front_depth`` (H*W float32, 0 = none)
        into ``visibility`` (clear, as :func:`visibility_buffer` makes it and ``kernels.resolve_back`` leaves it):
        per pixel the nearest fragment of a triangle that faces away from the view (``kernels.faces_away``) at or
        behind the front surface. The same set-up and scan as :meth:`draw`, culled to back faces, then
        ``kernels.raster_back_tiles``."""
        d = self.scene.device
        s = self.scene
        self._setup(views, view_index, width, height, layer, back_only=True)
        wp.launch(K.raster_back_tiles, dim=self.stride, device=d,
                  inputs=[views, int(view_index), self.sub_v, self.sub_bbox, self.tile_end, 2 * s.triangle_count,
                          self.stride, front_depth, visibility])


def view_array(views, device) -> wp.array:
    """A device array of :class:`ViewParams` from host views (``View`` or ``ViewParams``), for kernels that read
    their view from an array (set-up and tests; the frame loop keeps its arrays)."""
    return wp.array([v.params() if isinstance(v, View) else v for v in views], dtype=K.ViewParams, device=device)


def _pixels(shape_hw, dtype, device):
    return wp.zeros(shape_hw[0] * shape_hw[1], dtype=dtype, device=device)


def visibility_buffer(n: int, device) -> wp.array:
    """(n,) uint64 visibility buffer, clear (every pixel ``EMPTY_KEY``): filled once here; a resolve kernel leaves it
    clear again after reading it, so the frame draws into it with ``Rasterizer.draw(clear=False)``."""
    return wp.full(n, K.EMPTY_KEY_VALUE, dtype=wp.uint64, device=device)


class _Buffers:
    """Mixin: flat (H*W) Warp arrays that ``numpy()`` reshapes to images."""

    width: int
    height: int

    def numpy(self, prefix: str = "") -> dict[str, np.ndarray]:
        out = {}
        for f in fields(self):
            a = getattr(self, f.name)
            if isinstance(a, wp.array) and a.shape[0] == self.width * self.height:
                arr = a.numpy()
                out[prefix + f.name] = arr.reshape((self.height, self.width) + arr.shape[1:])
        return out


@dataclass
class SpecularLayer(_Buffers):
    """Nearest specular surface in front of the opaque one, per pixel (RSM specular texels, camera water layer)."""

    width: int
    height: int
    visibility: wp.array  #: (H*W,) uint64 packed depth | triangle id (scratch)
    depth: wp.array  #: (H*W,) float32 linear depth [m]; 0 = none
    position: wp.array  #: (H*W,) vec3 world position [m]
    normal: wp.array  #: (H*W,) vec3 authored (outward) unit normal
    roughness: wp.array  #: (H*W,) float32 (empty unless kept: RSM views, see :meth:`allocate`)
    ior: wp.array  #: (H*W,) float32 index of refraction behind the surface (empty with ``roughness``)
    tri_id: wp.array  #: (H*W,) int32 triangle id; -1 = none

    @staticmethod
    def allocate(width: int, height: int, device, surface: bool = True, material: bool = True) -> "SpecularLayer":
        """``surface`` False: ``position`` and ``normal`` empty (not written by the resolves; a reader computes them
        from ``tri_id`` and ``depth`` with ``kernels.texel_surface``) until :meth:`keep_surface`. ``material`` False:
        ``roughness`` and ``ior`` empty (a reader takes them from ``tri_id``'s material: ``kernels.texel_roughness``,
        ``kernels.texel_ior``) until :meth:`keep_material`."""
        hw = (height, width) if surface else (0, 0)
        hm = (height, width) if material else (0, 0)
        return SpecularLayer(width, height, visibility_buffer(width * height, device),
                             _pixels((height, width), wp.float32, device), _pixels(hw, wp.vec3, device),
                             _pixels(hw, wp.vec3, device), _pixels(hm, wp.float32, device),
                             _pixels(hm, wp.float32, device), _pixels((height, width), wp.int32, device))

    @property
    def has_surface(self) -> bool:
        """Whether the resolves write ``position`` and ``normal``."""
        return self.position.shape[0] == self.width * self.height

    def keep_surface(self) -> None:
        """Allocate ``position`` and ``normal`` (zero), so the resolves write them from the next one on."""
        if not self.has_surface:
            d = self.depth.device
            self.position = _pixels((self.height, self.width), wp.vec3, d)
            self.normal = _pixels((self.height, self.width), wp.vec3, d)

    @property
    def has_material(self) -> bool:
        """Whether the resolves write ``roughness`` and ``ior``."""
        return self.roughness.shape[0] == self.width * self.height

    def keep_material(self) -> None:
        """Allocate ``roughness`` and ``ior`` (zero), so the resolves write them from the next one on."""
        if not self.has_material:
            d = self.depth.device
            self.roughness = _pixels((self.height, self.width), wp.float32, d)
            self.ior = _pixels((self.height, self.width), wp.float32, d)

    def resolve(self, scene: DeviceScene, views: wp.array, view_index: int, opaque_depth: wp.array,
                nearest_depth: wp.array | None = None) -> None:
        """Resolve the layer drawn into ``visibility`` (and clear it); ``nearest_depth``: also write the depth of the
        nearest surface of either layer there ((H*W,) float32 [m], 0 = none), e.g. an RSM's shadow depth."""
        wp.launch(K.resolve_specular, dim=self.width * self.height, device=scene.device,
                  inputs=[views, int(view_index), self.visibility, opaque_depth, scene.points, scene.normals,
                          scene.indices, scene.triangle_material, scene.roughness, scene.ior,
                          self.depth, self.position, self.normal, self.roughness, self.ior, self.tri_id, nearest_depth])


@dataclass
class GBuffer(_Buffers):
    """Camera G-buffer: the opaque layer and the water (specular, transmissive) layer in front of it."""

    width: int
    height: int
    visibility: wp.array  #: (H*W,) uint64 (scratch)
    depth: wp.array  #: (H*W,) float32 linear depth [m]; 0 = no surface
    position: wp.array  #: (H*W,) vec3 world position [m]
    normal: wp.array  #: (H*W,) vec3 unit normal, facing the camera
    albedo: wp.array  #: (H*W,) vec3 diffuse reflectance
    roughness: wp.array  #: (H*W,) float32
    tri_id: wp.array  #: (H*W,) int32; -1 = no surface
    motion: wp.array  #: (H*W,) vec2 [pixels]: where this surface point was in the previous frame, minus here
    water: SpecularLayer  #: nearest specular surface in front of the opaque one
    #: (2·H*W,) float32 [m]: ``depth`` (its first half: ``depth`` is a view of it), then per pixel the depth of the
    #: nearest opaque back face behind the front surface (0 = none: an open surface, or nothing behind). The
    #: screen-space tests that take it (``photons.march.surface_far``) bound a closed object's thickness by it
    depth_layers: wp.array = None
    #: draw the back-face layer (False: its half of ``depth_layers`` is zeroed each frame instead, every surface keeps
    #: the constant thickness, as before the layer existed)
    back_faces: bool = True
    #: True (default): the back-face layer is resolved with the depth bounds a photon pass asked for
    #: (:meth:`keep_depth_bounds`) in one pass (``kernels.resolve_back_view``); False: its twin ``resolve_back`` (the
    #: photon pass then builds its bounds itself). The same buffers bit for bit
    fused_resolve: bool = True
    #: True: both layers resolved in one pass (``kernels.resolve_camera``); False (default): its twins
    #: ``resolve_opaque`` + ``resolve_specular``. The same buffers bit for bit; the fused pass lost on the H100
    #: (perf_notes 36: pool 0.129 -> 0.151 ms, Cornell 0.089 -> 0.097), so it is opt-in
    fused_layers: bool = False
    _bounds: tuple | None = None  #: (bounds array, thickness, thickness_rel) of :meth:`keep_depth_bounds`

    def keep_depth_bounds(self, bounds: wp.array, thickness: float, thickness_rel: float) -> None:
        """Have the back-face resolve write the depth bounds of ``depth_layers`` (``photons.march.depth_bounds`` and
        ``coarsen_bounds`` with these thicknesses) into ``bounds`` (``march.bounds_size``) every frame, instead of
        the photon pass building them after the resolve (:meth:`builds_depth_bounds`)."""
        if bounds.shape[0] != K.bounds_size(self.width, self.height):
            raise ValueError(f"keep_depth_bounds needs march.bounds_size({self.width}, {self.height}) = "
                             f"{K.bounds_size(self.width, self.height)} bounds, got {bounds.shape[0]}")
        self._bounds = (bounds, float(thickness), float(thickness_rel))

    def builds_depth_bounds(self, bounds: wp.array) -> bool:
        """Whether :meth:`render` writes ``bounds`` (:meth:`keep_depth_bounds`'s) each frame."""
        return self.back_faces and self.fused_resolve and self._bounds is not None and self._bounds[0] is bounds

    @staticmethod
    def allocate(width: int, height: int, device) -> "GBuffer":
        check_memory(width * height * 164, f"a {width}x{height} G-buffer", device)
        hw = (height, width)
        n = width * height
        layers = wp.zeros(2 * n, dtype=wp.float32, device=device)
        return GBuffer(width, height, visibility_buffer(n, device), layers[0:n],
                       _pixels(hw, wp.vec3, device), _pixels(hw, wp.vec3, device), _pixels(hw, wp.vec3, device),
                       _pixels(hw, wp.float32, device), _pixels(hw, wp.int32, device), _pixels(hw, wp.vec2, device),
                       SpecularLayer.allocate(width, height, device), layers)

    def render(self, raster: Rasterizer, views, prev_view=None) -> None:
        """Fill both layers for the camera ``views[0]``; motion is measured against ``views[1]``, the previous
        frame's camera (``views``: (2,) device array of ViewParams, written once per frame by the renderer).
        Host ``ViewParams`` (``view``, ``prev_view``) are accepted too, for tests and tools."""
        s = raster.scene
        if not isinstance(views, wp.array):
            views = view_array([views, views if prev_view is None else prev_view], s.device)
        raster.draw(views, 0, self.width, self.height, LAYER_OPAQUE, self.visibility, clear=False,
                    layer_b=LAYER_SPECULAR, visibility_b=self.water.visibility)  # both layers in one pass
        if self.fused_layers:  # both layers in one pass
            w = self.water
            wp.launch(K.resolve_camera, dim=self.width * self.height, device=s.device,
                      inputs=[views, 0, 1, self.visibility, w.visibility, s.points, s.prev_points, s.normals,
                              s.indices, s.triangle_material, s.albedo, s.roughness, s.ior, self.depth, self.position,
                              self.normal, self.albedo, self.roughness, self.tri_id, self.motion, w.depth, w.position,
                              w.normal, w.roughness, w.ior, w.tri_id, None])
        else:
            wp.launch(K.resolve_opaque, dim=self.width * self.height, device=s.device,
                      inputs=[views, 0, 1, self.visibility, s.points, s.prev_points, s.normals, s.indices,
                              s.triangle_material, s.albedo, s.roughness, self.depth, self.position, self.normal,
                              self.albedo, self.roughness, self.tri_id, self.motion])
            self.water.resolve(s, views, 0, self.depth)
        if not self.back_faces:
            self.depth_layers[self.width * self.height:].zero_()
        else:
            # into the opaque layer's visibility buffer, which its resolve left clear
            raster.draw_back(views, 0, self.width, self.height, LAYER_OPAQUE, self.depth, self.visibility)
            if self.fused_resolve:  # with the depth bounds of both layers, when a photon pass asked for them
                bounds, th, th_rel = self._bounds or (None, 0.0, 0.0)
                coarse = (((self.width + K.BOUNDS_COARSE - 1) // K.BOUNDS_COARSE)
                          * ((self.height + K.BOUNDS_COARSE - 1) // K.BOUNDS_COARSE))
                wp.launch_tiled(K.resolve_back_view, dim=coarse, block_dim=K.RESOLVE_THREADS, device=s.device,
                                inputs=[views, 0, self.visibility, s.points, s.normals, s.indices, self.tri_id,
                                        self.depth_layers, th, th_rel, bounds])
            else:
                wp.launch(K.resolve_back, dim=self.width * self.height, device=s.device,
                          inputs=[views, 0, self.visibility, s.points, s.normals, s.indices, self.tri_id,
                                  self.depth_layers])

    def numpy(self, prefix: str = "") -> dict[str, np.ndarray]:
        out = super().numpy(prefix)
        out.update(self.water.numpy(prefix + "water_"))
        n = self.width * self.height
        out[prefix + "back_depth"] = self.depth_layers.numpy()[n:].reshape(self.height, self.width)
        out.pop(prefix + "visibility", None)
        out.pop(prefix + "water_visibility", None)
        return out


@dataclass
class RSMView(_Buffers):
    """One view of a reflective shadow map: opaque depth, the specular layer and the flux it receives."""

    view: View
    width: int
    height: int
    visibility: wp.array  #: (H*W,) uint64 (scratch)
    opaque_depth: wp.array  #: (H*W,) float32 linear depth of the nearest opaque surface [m]; 0 = none
    opaque_tri: wp.array  #: (H*W,) int32
    shadow_depth: wp.array  #: (H*W,) float32 depth of the nearest surface of any kind [m]; 0 = none (empty, not
    #: written by the resolves, unless kept: :meth:`keep_shadow_depth`; ``LightMaps`` says which views keep it)
    specular: SpecularLayer
    flux: wp.array  #: (H*W,) vec3 [W]: power the light sends through the texel onto its specular surface (empty
    #: unless kept, :meth:`keep_texel_maps`; ``LightMaps.emission`` gives it where it is read)
    solid_angle: wp.array  #: (H*W,) float32 [sr] per texel (perspective views; zeros for orthographic)

    @staticmethod
    def allocate(view: View, device, surface: bool = True, texel_maps: bool = True,
                 shadow_depth: bool = True) -> "RSMView":
        """``surface``: whether the specular layer keeps ``position`` and ``normal`` (:meth:`SpecularLayer.allocate`);
        ``texel_maps``: whether the view keeps ``flux`` and its layer ``roughness`` and ``ior`` (else they are empty,
        not written by the resolves: a reader computes them from ``tri_id`` with ``kernels.TexelEmission``) until
        :meth:`keep_texel_maps`; ``shadow_depth``: whether it keeps ``shadow_depth`` (else empty and not written:
        nothing reads a fitted cascade's or a pilot's) until :meth:`keep_shadow_depth`."""
        w, h = view.width, view.height
        check_memory(w * h * (48 + (4 if shadow_depth else 0) + (24 if surface else 0) + (20 if texel_maps else 0)),
                     f"a {w}x{h} reflective shadow map", device)
        hw = (h, w)
        sa = view.texel_solid_angle().astype(np.float32).reshape(-1) if not view.orthographic else np.zeros(w * h, np.float32)
        return RSMView(view, w, h, visibility_buffer(w * h, device), _pixels(hw, wp.float32, device),
                       _pixels(hw, wp.int32, device), _pixels(hw if shadow_depth else (0, 0), wp.float32, device),
                       SpecularLayer.allocate(w, h, device, surface, texel_maps),
                       _pixels(hw if texel_maps else (0, 0), wp.vec3, device),
                       wp.array(sa, dtype=wp.float32, device=device))

    @property
    def has_texel_maps(self) -> bool:
        """Whether the resolves write ``flux`` and the layer's ``roughness`` and ``ior``."""
        return self.flux.shape[0] == self.width * self.height

    @property
    def has_shadow_depth(self) -> bool:
        """Whether the resolves write ``shadow_depth``."""
        return self.shadow_depth.shape[0] == self.width * self.height

    def keep_shadow_depth(self) -> None:
        """Allocate ``shadow_depth`` (zero), so the resolves write it from the next one on (a reader of the array:
        ``LightMaps.shadow_maps`` of whole views, the mesh wavefront's ``mesh_cells``, tests)."""
        if not self.has_shadow_depth:
            self.shadow_depth = _pixels((self.height, self.width), wp.float32, self.opaque_depth.device)

    def keep_texel_maps(self) -> None:
        """Allocate ``flux`` and the layer's ``roughness`` and ``ior`` (zero), so the resolves write them from the
        next one on (tests, and tools that compare them with the twins')."""
        if not self.has_texel_maps:
            self.flux = _pixels((self.height, self.width), wp.vec3, self.opaque_depth.device)
        self.specular.keep_material()

    def numpy(self, prefix: str = "") -> dict[str, np.ndarray]:
        out = super().numpy(prefix)
        out.update({k: v for k, v in self.specular.numpy(prefix + "specular_").items() if not k.endswith("visibility")})
        for k in ("visibility", "solid_angle", "opaque_tri"):
            out.pop(prefix + k, None)
        return out
