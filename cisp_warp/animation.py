"""Animated frames: simulated water written in place, the camera read from the open USD stage per time code.

>>> r = Renderer(load_usd("scenes_usd/pool.usda"), settings, device="cpu")
>>> anim = Animation(r, "scenes_usd/pool.usda")
>>> for code in range(0, 120):
...     anim.set_time_code(code)       # water at t = code / timeCodesPerSecond, BVHs refit, camera of `code`
...     r.render_frame()

Water (``sim/``): every mesh with ``cisp:water:*`` attributes (``MeshRange.water``) becomes one
:class:`sim.FFTWater` + :class:`sim.WaterMesh`, built once, whose kernel writes the mesh's points and
normals straight into :meth:`DeviceScene.mesh_points` (views of the scene arrays, no copy).

Vertex map. The importer keeps vertex ``i`` = the prim's point ``i`` for water (dynamic meshes are never
split), and ``WaterMesh`` writes vertex ``iz * nx + ix`` at the rest position
(x0 + ix (x1 - x0)/(nx - 1), y0, z0 + iz (z1 - z0)/(nz - 1)), patch anchored at the world origin. So a
water prim's **rest grid** must be such a grid, in world space (Y up, metres): it is the points'
*default* (un-sampled) value brought to the world by the importer's transform, because time samples, if
any, hold an already displaced surface (``tools/make_pool_scene.py --bake``). From it
(:func:`water_grid`): ``nx`` = the points of the first row (same z as point 0), ``nz`` = V / nx,
``rect`` = (point 0's x, z, the last point's x, z), ``y0`` = the mean rest height (exact for a flat rest
grid), and every point must lie on that grid, else :class:`SceneError` names the prim. Borders are
pinned (``WaterMesh(pin_border=True)``): border vertices never leave the basin's walls. Hence the water
the renderer draws at time t is exactly what ``make_pool_scene.py`` bakes at t (``tests/test_pool.py``).

Per frame (:meth:`Animation.set_time_code`), nothing is allocated on the device and nothing is copied to
the host: ``DeviceScene.begin_frame`` (points -> prev_points, for motion vectors), the water kernels at
t = time code / ``timeCodesPerSecond``, ``DeviceScene.refit`` (BVHs of the photon passes), and the camera
of that time code, read from the stage kept open (:class:`StageClock`: a few attribute reads, instead of
re-importing every mesh). Meshes whose points are time-sampled without ``cisp:water`` (baked animation)
still need the stage's points per frame: then the whole stage is re-imported (``Renderer.update_scene``,
a host copy), and the water is simulated over it. On the first frame the previous points and camera are
set equal to the current ones, so the first frame has no motion.
"""

from __future__ import annotations

import os

import numpy as np
import warp as wp
from pxr import Tf, Usd, UsdGeom, UsdRender

from sim import FFTWater, SimParameterError, WaterMesh

from .errors import SceneError
from .scene.device import DeviceScene
from .scene.model import Camera, Scene
from .usd.stage import StageContext, finite_float, open_stage, tf_reason
from .usd.water import GRID_TOLERANCE, WaterGrid, water_grid, water_params  # noqa: F401 (re-exported)

class WaterSimulation:
    """Every ``cisp:water`` mesh of a :class:`DeviceScene`, simulated in place.

    ``rest``: {mesh index: rest points (V, 3) [m], world space}; by default the scene's own points (right
    for stages without time-sampled water). ``update(t)`` writes points and normals of every water mesh
    at time ``t`` [s] into ``gpu.points`` / ``gpu.normals`` (no allocation, no host copy).
    """

    def __init__(self, gpu: DeviceScene, rest: dict[int, np.ndarray] | None = None):
        self.gpu = gpu
        scene = gpu.scene
        self.meshes: list[WaterMesh] = []
        self.paths: list[str] = []
        for i, m in enumerate(scene.meshes):
            if not m.water:
                continue
            where = m.path
            params = water_params(m.water, where)
            if rest is not None and i in rest:
                points = rest[i]
            else:
                points = scene.points[m.vertex_start : m.vertex_start + m.vertex_count]
            if len(points) != m.vertex_count:
                raise SceneError(f"the rest grid has {len(points)} points but the imported mesh {m.vertex_count}",
                                 prim=where)
            grid = water_grid(points, where)
            target_points, target_normals = gpu.mesh_points(i)
            try:
                water = FFTWater(params, gpu.device)
                mesh = WaterMesh(water, rect=grid.rect, y0=grid.y0, vertex_counts=grid.counts,
                                 points=target_points, normals=target_normals)
            except SimParameterError as exc:
                raise SceneError(f"water simulation: {exc}", prim=where) from None
            self.meshes.append(mesh)
            self.paths.append(where)

    def __len__(self) -> int:
        return len(self.meshes)

    def update(self, t: float) -> None:
        """Simulate every water mesh at time ``t`` [s], written in place (a move of their layers counted,
        ``DeviceScene.geometry_moved``)."""
        for mesh in self.meshes:
            mesh.update(t)
        if self.meshes:
            self.gpu.geometry_moved()


class StageClock:
    """A USD stage kept open for per-frame reads: time codes -> seconds, the camera, rest points.

    The camera is chosen as :func:`cisp_warp.usd.load_usd` chooses it (``camera_path``, else the
    render settings' camera, else the first camera) and read with the importer's own
    :func:`~cisp_warp.usd.read_camera`, so a frame's camera equals the imported one at that code.
    """

    def __init__(self, path, camera_path=None):
        self.path = os.fspath(path)
        try:
            self.stage = open_stage(self.path)
            self.time_codes_per_second = finite_float(self.stage.GetTimeCodesPerSecond(), "timeCodesPerSecond", "/")
            if self.time_codes_per_second <= 0.0:
                raise SceneError(f"timeCodesPerSecond must be positive, got {self.time_codes_per_second}", prim="/")
            self.camera_prim, self.policy = self._camera(camera_path)
        except SceneError as exc:
            raise SceneError(exc.reason, file=exc.file or self.path, prim=exc.prim) from None
        except Tf.ErrorException as exc:
            raise SceneError(f"USD error: {tf_reason(exc)}", file=self.path) from None

    def _camera(self, camera_path):
        from .usd.load import _pick_camera, _render_settings  # the importer's own choice, not a copy of it

        settings = [p for p in self.stage.Traverse() if p.IsA(UsdRender.Settings)]
        rs = _render_settings(self.stage, settings)
        cameras = [p for p in Usd.PrimRange(self.stage.GetPseudoRoot(),
                                            Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
                   if p.IsA(UsdGeom.Camera)][:1]
        prim = _pick_camera(self.stage, cameras, camera_path, rs)
        policy = str(rs.GetAspectRatioConformPolicyAttr().Get()) if rs else "expandAperture"
        return prim, policy

    def seconds(self, code: float) -> float:
        """Stage time [s] of a time code."""
        return float(code) / self.time_codes_per_second

    def context(self, code) -> StageContext:
        time = Usd.TimeCode.Default() if code is None else Usd.TimeCode(float(code))
        return StageContext.from_stage(self.stage, self.path, time)

    def camera(self, code: float, width: int, height: int) -> Camera:
        """The camera at time ``code`` for a ``width`` × ``height`` image."""
        from .usd import read_camera

        try:
            return read_camera(self.context(code), self.camera_prim, width, height, self.policy)
        except SceneError as exc:
            raise SceneError(exc.reason, file=self.path, prim=exc.prim) from None

    def rest_points(self, mesh_path: str, code: float) -> np.ndarray:
        """Default (un-sampled) ``points`` of a mesh in world space [m], transformed as at time ``code``."""
        prim = self.stage.GetPrimAtPath(mesh_path)
        raw = UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode.Default()) if prim else None
        if raw is None or len(raw) == 0:
            raise SceneError("a cisp:water mesh needs its rest grid as the default (un-sampled) value of points; "
                             "it has only time samples", file=self.path, prim=mesh_path)
        m = self.context(code).to_world(prim)
        return np.asarray(raw, dtype=np.float64).reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]

    def has_sampled_points(self, mesh_path: str) -> bool:
        prim = self.stage.GetPrimAtPath(mesh_path)
        return bool(prim) and UsdGeom.Mesh(prim).GetPointsAttr().GetNumTimeSamples() > 1


class Animation:
    """Drives a :class:`~cisp_warp.render.Renderer` through the time codes of a USD stage.

    ``simulate``: simulate ``cisp:water`` meshes (default); False renders the stage's own points
    (time-sampled ones re-imported per frame). ``width``/``height``/``device`` are only used for the
    re-import of stages with baked (time-sampled) non-water meshes. Lights are those of the first frame.
    """

    def __init__(self, renderer, path, camera_path=None, simulate: bool = True):
        try:
            self._setup(renderer, path, camera_path, simulate)
        except SceneError as exc:  # every message names the file
            raise SceneError(exc.reason, file=exc.file or os.fspath(path), prim=exc.prim) from None

    def _setup(self, renderer, path, camera_path, simulate):
        self.renderer = renderer
        self.clock = StageClock(path, camera_path)
        self.camera_path = camera_path
        gpu: DeviceScene = renderer.gpu
        scene: Scene = renderer.scene
        self.rest_code = scene.time_code
        sim_meshes = [(i, m) for i, m in enumerate(scene.meshes) if m.water] if simulate else []
        rest = {i: self.clock.rest_points(m.path, self.rest_code) for i, m in sim_meshes}
        self.water = WaterSimulation(gpu, rest) if sim_meshes else None
        simulated = {m.path for _, m in sim_meshes}
        self.baked = [m.path for m in scene.meshes
                      if m.dynamic and m.path not in simulated and self.clock.has_sampled_points(m.path)]
        self.frames = 0

    def seconds(self, code: float) -> float:
        return self.clock.seconds(code)

    def set_time_code(self, code: float) -> None:
        """Bring the scene on the device to time code ``code``: water, BVHs and camera (see the module doc)."""
        r = self.renderer
        g = r.gbuffer
        if self.baked:
            from .usd import load_usd

            r.update_scene(load_usd(self.clock.path, time_code=code, width=g.width, height=g.height,
                                    camera_path=self.camera_path, device=r.device))
        else:
            r.gpu.begin_frame()
            r.set_camera(self.clock.camera(code, g.width, g.height))
        if self.water is not None:
            self.water.update(self.clock.seconds(code))
        r.gpu.refit()
        if self.frames == 0:  # no motion into the first frame
            wp.copy(r.gpu.prev_points, r.gpu.points)
            r.prev_view_params = r.view_params
        r.scene.time_code, r.scene.time = float(code), self.clock.seconds(code)
        self.frames += 1


def memory_in_use(device) -> dict[str, float]:
    """Memory figures [MiB] to watch across frames: process RSS (``/proc/self/statm``, current, not peak);
    on CUDA also the device memory in use (total - free) and Warp's mempool in use."""
    out = {}
    try:
        with open("/proc/self/statm") as f:
            out["rss"] = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        import resource

        out["rss_peak"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    dev = wp.get_device(device)
    if dev.is_cuda:
        out["device_used"] = (dev.total_memory - dev.free_memory) / 2**20
        if wp.is_mempool_enabled(dev):
            out["mempool"] = wp.get_mempool_used_mem_current(dev) / 2**20
    return out


__all__ = ["Animation", "StageClock", "WaterGrid", "WaterSimulation", "memory_in_use", "water_grid", "water_params"]
