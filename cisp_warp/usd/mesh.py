"""``UsdGeom.Mesh`` -> world-space triangles with unit normals and a material per triangle.

Rules (each one a test in ``tests/test_usd_import.py``):

* Polygons of any size are triangulated: a fan from the first corner when the fan is valid (every
  fan triangle faces along the polygon's Newell normal, which holds for convex polygons), else ear
  clipping in the polygon's plane. Ear clipping costs O(n²) in a polygon's n corners, so a
  non-convex polygon may have at most ``MAX_EAR_CLIP_CORNERS`` corners and the non-convex polygons of a
  mesh at most ``MAX_EAR_CLIP_WORK`` squared corners together (else :class:`SceneError`); the fan test
  and the fan are linear. ``holeIndices`` faces are dropped.
* ``orientation = leftHanded`` and transforms with a negative determinant each flip the winding, so
  output triangles are counter-clockwise seen from the side their normal points to.
* Points go through ``XformCache.GetLocalToWorldTransform`` and the stage's unit/up-axis map; normals
  through its inverse transpose.
* Authored normals (``primvars:normals`` over ``normals``) of any interpolation are used. Without
  them, normals are "auto-smooth": at each corner, the area-weighted mean of the normals of the
  faces around its point that are within ``CREASE_ANGLE_DEG`` of the corner's own face, so curved
  surfaces are smooth and hard edges (a cube's) stay hard. A polygon counts once per point (its
  triangles there are summed), so an n-gon costs O(n); a point shared by more than
  ``MAX_SMOOTH_VALENCE`` faces is smooth when all their normals lie within half the crease angle of
  their mean, else its corners keep their face's normal (one :class:`SceneWarning`): linear in the
  corners either way.
* Types, counts and ranges are checked where they are read: ``points`` an array of 3-vectors within
  ``MAX_EXTENT_M`` of the origin once transformed, ``faceVertexCounts``/``faceVertexIndices``/
  ``holeIndices`` int arrays; authored ``normals`` or ``displayColor`` of another type, count or
  non-finite values are ignored with a warning. A ``cisp:water`` mesh's parameters and rest grid are
  checked here too (:func:`cisp_warp.usd.water.check_water`).
* Vertex layout: when every corner of a point has the same normal, output vertex ``i`` is the prim's
  point ``i`` (unused points kept), so ``sim/`` and time-sampled updates can write points in place.
  Otherwise (face-varying / uniform normals, hard edges) corners are split into one vertex per distinct
  (point, normal). **Dynamic meshes are never split**: their corner normals are averaged per point.
* Triangles of zero area (relative to the mesh size) are dropped with one warning naming the prim and
  the count; a mesh left with no triangle is skipped (the caller reports it).
* ``cisp:water:*`` attributes -> ``water`` dict (namespace stripped, plain Python values), ``dynamic``;
  time-sampled ``points`` -> ``dynamic`` too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom

from ..errors import SceneError
from .material import MaterialTable, face_materials
from .stage import MAX_EXTENT_M, StageContext, python_value, typed_get
from .water import check_water

CREASE_ANGLE_DEG = 45.0  #: computed normals: faces meeting at more than this form a hard edge
MAX_SMOOTH_VALENCE = 64  #: faces per point up to which every pair is crease-tested (see the docstring)
MAX_EAR_CLIP_CORNERS = 2000  #: most corners of a non-convex polygon (ear clipping is O(n²))
MAX_EAR_CLIP_WORK = 4_000_000  #: most squared corners of a mesh's non-convex polygons together
DEGENERATE_AREA = 1e-12  #: a triangle with |cross| <= this × (mesh bounding diagonal)² has zero area
WATER_NAMESPACE = "cisp:water:"


@dataclass
class MeshPart:
    """One imported mesh in world space, before it is concatenated into the scene arrays."""

    path: str
    points: np.ndarray  #: (V, 3) float32 [m]
    normals: np.ndarray  #: (V, 3) float32, unit
    indices: np.ndarray  #: (T, 3) int32, counter-clockwise, into ``points``
    triangle_material: np.ndarray  #: (T,) int32 into the MaterialTable
    dynamic: bool = False
    water: dict | None = None


def _unit(v: np.ndarray, fallback=(0.0, 1.0, 0.0)) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out = np.where(n > 0.0, v / np.where(n > 0.0, n, 1.0), np.asarray(fallback, dtype=v.dtype))
    return out


def _ear_clip(p2: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles (local corner ids) of a simple polygon given counter-clockwise in 2-D.

    O(n²) ears × O(n) vectorised containment tests; a polygon with no ear left (self-intersecting
    or degenerate) is finished with a fan.
    """
    remaining = list(range(len(p2)))
    tris = []
    while len(remaining) > 3:
        m = len(remaining)
        r = np.asarray(remaining)
        q = p2[r]
        prev, nxt = np.roll(q, 1, axis=0), np.roll(q, -1, axis=0)
        e1, e2 = q - prev, nxt - prev
        convex = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0.0  # corner turns left: an ear candidate
        for k in np.nonzero(convex)[0]:
            a, b, c = prev[k], q[k], nxt[k]
            others = np.delete(q, [(k - 1) % m, k, (k + 1) % m], axis=0)

            def side(u, v):
                return (v[0] - u[0]) * (others[:, 1] - u[1]) - (v[1] - u[1]) * (others[:, 0] - u[0]) >= 0.0

            if np.any(side(a, b) & side(b, c) & side(c, a)):
                continue
            tris.append((remaining[(k - 1) % m], remaining[k], remaining[(k + 1) % m]))
            remaining.pop(int(k))
            break
        else:
            break
    tris += [(remaining[0], remaining[k], remaining[k + 1]) for k in range(1, len(remaining) - 1)]
    return tris


def triangulate(points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate polygons; returns (face id per triangle (T,), face-vertex corner ids (T, 3)).

    ``points`` (N, 3) float64 world positions, ``counts`` (F,) corners per face (>= 3), ``indices``
    (sum(counts),) point id per corner. Winding follows the polygon's corner order.
    """
    starts = np.cumsum(counts) - counts
    ntri = counts - 2
    tri_face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(len(tri_face)) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    c0 = starts[tri_face]
    corners = np.stack([c0, c0 + 1 + k, c0 + 2 + k], axis=1)
    poly = counts > 3
    if not np.any(poly):
        return tri_face, corners
    # Newell normal per face: sum over edges of cross(p_c, p_next(c)).
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    nxt = np.arange(len(indices)) + 1
    nxt[starts + counts - 1] = starts
    newell = np.zeros((len(counts), 3))
    np.add.at(newell, face_of_corner, np.cross(points[indices], points[indices[nxt]]))
    p = points[indices[corners]]
    tri_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    bad_tri = np.einsum("ij,ij->i", tri_n, newell[tri_face]) <= 0.0
    bad_faces = np.unique(tri_face[bad_tri & poly[tri_face]])
    # A non-convex quad is split along its other diagonal (vectorised); larger polygons are ear-clipped.
    quads = bad_faces[counts[bad_faces] == 4]
    if quads.size:
        first = np.searchsorted(tri_face, quads)  # the first of each quad's two fan triangles
        s = starts[quads]
        corners[first] = np.stack([s + 1, s + 2, s + 3], axis=1)
        corners[first + 1] = np.stack([s + 1, s + 3, s], axis=1)
        bad_faces = bad_faces[counts[bad_faces] != 4]
    if bad_faces.size == 0:
        return tri_face, corners
    big = counts[bad_faces] > MAX_EAR_CLIP_CORNERS
    if np.any(big):
        f = int(bad_faces[np.argmax(big)])
        raise SceneError(f"face {f} has {int(counts[f])} corners and is not convex: a non-convex polygon may have at "
                         f"most {MAX_EAR_CLIP_CORNERS} corners (ear clipping is quadratic); split or triangulate it "
                         "(faceVertexCounts)")
    work = int(np.sum(counts[bad_faces].astype(np.float64) ** 2))
    if work > MAX_EAR_CLIP_WORK:
        raise SceneError(f"{len(bad_faces)} non-convex polygons of up to {int(counts[bad_faces].max())} corners need "
                         f"{work:.3g} steps of ear clipping, more than {MAX_EAR_CLIP_WORK:g}: triangulate the mesh "
                         "(faceVertexCounts)")
    keep = ~np.isin(tri_face, bad_faces)
    extra_face, extra_corners = [], []
    for f in bad_faces:
        s, n = int(starts[f]), int(counts[f])
        q = points[indices[s : s + n]]
        axis = int(np.argmax(np.abs(newell[f])))
        u, v = ((axis + 1) % 3, (axis + 2) % 3) if newell[f, axis] >= 0.0 else ((axis + 2) % 3, (axis + 1) % 3)
        for t in _ear_clip(q[:, [u, v]]):
            extra_face.append(f)
            extra_corners.append([s + t[0], s + t[1], s + t[2]])
    tri_face = np.concatenate([tri_face[keep], np.asarray(extra_face, dtype=tri_face.dtype)])
    corners = np.concatenate([corners[keep], np.asarray(extra_corners, dtype=corners.dtype).reshape(-1, 3)])
    order = np.argsort(tri_face, kind="stable")
    return tri_face[order], corners[order]


def auto_smooth_normals(tri_point: np.ndarray, tri_n: np.ndarray, n_points: int, tri_face: np.ndarray | None = None):
    """Normals where none are authored: (per-point (N, 3), None, 0) when the mesh has no hard edge, else
    (None, per-corner (T, 3, 3), number of points left flat).

    ``tri_point`` (T, 3) point ids, ``tri_n`` (T, 3) area-weighted triangle normals, ``tri_face`` (T,) the
    polygon of each triangle (default: each triangle its own). An *element* is one polygon at one point
    (its triangles there summed). A corner's normal is the sum of the normals of the elements at its
    point within ``CREASE_ANGLE_DEG`` of its own element; points with more than ``MAX_SMOOTH_VALENCE``
    elements are smooth if all lie within half the crease angle of their mean, else flat. O(corners).
    """
    T = len(tri_point)
    if tri_face is None:
        tri_face = np.arange(T)
    pid = tri_point.reshape(-1).astype(np.int64)
    n_faces = int(tri_face.max()) + 1 if T else 1
    key = pid * n_faces + np.repeat(tri_face.astype(np.int64), 3)
    uniq, elem = np.unique(key, return_inverse=True)
    elem = elem.reshape(-1)
    e_point = uniq // n_faces  # sorted by point: the elements of a point are contiguous
    corner_n = np.repeat(tri_n, 3, axis=0)
    e_n = np.stack([np.bincount(elem, weights=corner_n[:, c], minlength=len(uniq)) for c in range(3)], axis=1)
    e_u = _unit(e_n)
    size = np.bincount(e_point, minlength=n_points)
    start = np.cumsum(size) - size
    k = size[e_point]
    cos_crease = math.cos(math.radians(CREASE_ANGLE_DEG))
    # Points of small valence: every pair of elements tested.
    es = np.nonzero(k <= MAX_SMOOTH_VALENCE)[0]
    ks = k[es]
    i = np.repeat(es, ks)
    j = np.repeat(start[e_point[es]], ks) + (np.arange(int(ks.sum())) - np.repeat(np.cumsum(ks) - ks, ks))
    smooth = np.einsum("ij,ij->i", e_u[i], e_u[j]) >= cos_crease
    acc = np.zeros_like(e_n)
    for c in range(3):
        acc[:, c] = np.bincount(i[smooth], weights=e_n[j[smooth], c], minlength=len(uniq))
    point_sum = np.stack([np.bincount(e_point, weights=e_n[:, c], minlength=n_points) for c in range(3)], axis=1)
    # Points of large valence: smooth when the normals' cone is narrow enough, else flat.
    eb = np.nonzero(k > MAX_SMOOTH_VALENCE)[0]
    n_flat = 0
    all_smooth = bool(np.all(smooth))
    if eb.size:
        mean = _unit(point_sum)
        spread = np.ones(n_points)
        np.minimum.at(spread, e_point[eb], np.einsum("ij,ij->i", e_u[eb], mean[e_point[eb]]))
        narrow = spread[e_point[eb]] >= math.cos(math.radians(CREASE_ANGLE_DEG / 2.0))
        acc[eb] = np.where(narrow[:, None], point_sum[e_point[eb]], e_n[eb])
        n_flat = int(np.unique(e_point[eb][~narrow]).size)
        all_smooth = all_smooth and bool(np.all(narrow))
    if all_smooth:
        return _unit(point_sum), None, 0
    return None, _unit(acc)[elem].reshape(-1, 3, 3), n_flat


def _authored_normals(ctx: StageContext, mesh: UsdGeom.Mesh, n_points, n_faces, n_corners, path):
    """(values (K, 3), interpolation) of authored normals, or None (warns when they are unusable)."""
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("normals")
    if pv and pv.HasAuthoredValue():
        attr, interp = pv.GetAttr(), pv.GetInterpolation()
    elif mesh.GetNormalsAttr().HasAuthoredValue():
        attr, interp = mesh.GetNormalsAttr(), mesh.GetNormalsInterpolation()
    else:
        return None
    try:
        typed_get(ctx, attr, "vec3[]", path)
    except SceneError as exc:
        ctx.warn(f"{exc.reason}: ignored, normals computed instead", path)
        return None
    values = pv.ComputeFlattened(ctx.time) if attr == pv.GetAttr() else ctx.get(attr)
    if values is None or len(values) == 0:
        return None
    n = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    expected = {"constant": 1, "uniform": n_faces, "vertex": n_points, "varying": n_points, "faceVarying": n_corners}
    if interp not in expected or len(n) != expected[interp]:
        ctx.warn(f"normals have {len(n)} values for interpolation '{interp}' (expected "
                 f"{expected.get(interp, '?')}): ignored, normals computed instead", path)
        return None
    length = np.linalg.norm(n, axis=1) if np.all(np.isfinite(n)) else np.zeros(1)
    if not (np.all(length > 1e-30) and np.all(length < 1e30)):
        ctx.warn("normals contain NaN, Inf, zero or huge vectors: ignored, normals computed instead", path)
        return None
    return n, interp


def _display_color(ctx, mesh, tri_face, tri_point, tri_corner, n_points, n_faces, n_corners, path):
    """Colour per triangle (T, 3) from ``primvars:displayColor``, or None."""
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("displayColor")
    if not (pv and pv.HasAuthoredValue()):
        return None
    try:
        typed_get(ctx, pv.GetAttr(), "vec3[]", path)
    except SceneError as exc:
        ctx.warn(f"{exc.reason}: ignored", path)
        return None
    values = pv.ComputeFlattened(ctx.time)
    if values is None or len(values) == 0:
        return None
    c = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    interp = pv.GetInterpolation()
    expected = {"constant": 1, "uniform": n_faces, "vertex": n_points, "varying": n_points, "faceVarying": n_corners}
    if interp not in expected or len(c) != expected[interp] or not np.all(np.abs(c) < 1e30):
        ctx.warn(f"displayColor has {len(c)} values for interpolation '{interp}' (expected "
                 f"{expected.get(interp, '?')}) or non-finite values: ignored", path)
        return None
    if interp == "constant":
        return np.repeat(c, len(tri_face), axis=0)
    if interp == "uniform":
        return c[tri_face]
    if interp == "faceVarying":
        return c[tri_corner].mean(axis=1)
    return c[tri_point].mean(axis=1)


def read_water(ctx: StageContext, prim) -> dict | None:
    """``cisp:water:*`` attributes as {name without the namespace: plain Python value}, or None."""
    water = {}
    for attr in prim.GetAttributes():
        name = attr.GetName()
        if name.startswith(WATER_NAMESPACE):
            water[name[len(WATER_NAMESPACE):]] = python_value(ctx.get(attr))
    return water or None


def read_mesh(ctx: StageContext, mesh: UsdGeom.Mesh, table: MaterialTable) -> tuple[MeshPart | None, str]:
    """Import one mesh; returns (part, "") or (None, reason it was skipped). Bad data -> SceneError."""
    prim = mesh.GetPrim()
    path = str(prim.GetPath())
    points_attr = mesh.GetPointsAttr()
    raw = typed_get(ctx, points_attr, "vec3[]", path)
    if raw is None or len(raw) == 0:
        return None, "the mesh has no points"
    P = np.asarray(raw, dtype=np.float64).reshape(-1, 3)
    bad = ~np.all(np.isfinite(P), axis=1)
    if np.any(bad):
        raise SceneError(f"points contain NaN or Inf ({int(bad.sum())} points, first at index "
                         f"{int(np.argmax(bad))})", prim=path)
    counts = np.asarray(typed_get(ctx, mesh.GetFaceVertexCountsAttr(), "int[]", path) or [], dtype=np.int64)
    indices = np.asarray(typed_get(ctx, mesh.GetFaceVertexIndicesAttr(), "int[]", path) or [], dtype=np.int64)
    if counts.size == 0:
        return None, "the mesh has no faces (faceVertexCounts is empty)"
    if np.any(counts < 3):
        f = int(np.argmax(counts < 3))
        raise SceneError(f"face {f} has {int(counts[f])} vertices: a face needs at least 3 "
                         "(faceVertexCounts)", prim=path)
    if int(counts.sum()) != indices.size:
        raise SceneError(f"faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                         f"{indices.size} entries", prim=path)
    out = (indices < 0) | (indices >= len(P))
    if np.any(out):
        k = int(np.argmax(out))
        raise SceneError(f"faceVertexIndices[{k}] = {int(indices[k])} is out of range: the mesh has "
                         f"{len(P)} points", prim=path)

    M = ctx.to_world(prim)
    lin = M[:3, :3]
    det = float(np.linalg.det(lin))
    if not (abs(det) > 1e-300):
        return None, "its transform is singular (zero scale): no area"
    with np.errstate(over="ignore", invalid="ignore"):
        Pw = P @ lin.T + M[:3, 3]
    far = ~np.all(np.abs(Pw) <= MAX_EXTENT_M, axis=1)
    if np.any(far):
        k = int(np.argmax(far))
        raise SceneError(f"points[{k}] lies at {tuple(float(f'{v:.3g}') for v in Pw[k])} m (after its transform and "
                         f"metersPerUnit {ctx.meters_per_unit:g}): every point must lie within {MAX_EXTENT_M:g} m of "
                         "the origin", prim=path)

    try:
        tri_face, tri_corner = triangulate(Pw, counts, indices)
    except SceneError as exc:
        raise SceneError(exc.reason, prim=path) from None
    holes = np.asarray(typed_get(ctx, mesh.GetHoleIndicesAttr(), "int[]", path) or [], dtype=np.int64)
    if holes.size:
        keep = ~np.isin(tri_face, holes)
        tri_face, tri_corner = tri_face[keep], tri_corner[keep]
    orientation = str(typed_get(ctx, mesh.GetOrientationAttr(), "token", path))
    if orientation not in ("rightHanded", "leftHanded"):
        raise SceneError(f"orientation = '{orientation}': it must be rightHanded or leftHanded", prim=path)
    if (orientation == "leftHanded") != (det < 0.0):
        tri_corner = tri_corner[:, [0, 2, 1]]
    tri_point = indices[tri_corner]

    # Degenerate (zero-area) triangles.
    tp = Pw[tri_point]
    tri_n = np.cross(tp[:, 1] - tp[:, 0], tp[:, 2] - tp[:, 0])
    diag2 = float(np.sum((Pw.max(axis=0) - Pw.min(axis=0)) ** 2))
    good = np.linalg.norm(tri_n, axis=1) > DEGENERATE_AREA * diag2
    n_tri = len(good)
    if not np.any(good):
        return None, f"all {n_tri} triangles are degenerate (zero area)"
    if not np.all(good):
        ctx.warn(f"{n_tri - int(good.sum())} of {n_tri} triangles are degenerate (zero area): dropped", path)
        tri_face, tri_corner, tri_point, tri_n = tri_face[good], tri_corner[good], tri_point[good], tri_n[good]

    water = read_water(ctx, prim)
    if water is not None:
        default = points_attr.Get(Usd.TimeCode.Default())
        rest = (np.asarray(default, dtype=np.float64).reshape(-1, 3) @ lin.T + M[:3, 3]
                if default is not None and len(default) == len(P) else None)
        check_water(water, rest, path, ctx.on_cpu)
    dynamic = water is not None or points_attr.GetNumTimeSamples() > 1

    # Normals per triangle corner (T, 3, 3), or per point (N, 3) when authored per vertex.
    normal_map = np.linalg.inv(lin).T
    authored = _authored_normals(ctx, mesh, len(P), len(counts), indices.size, path)
    point_normals = corner_normals = None
    if authored is not None:
        n, interp = authored
        n = _unit(n @ normal_map.T)
        if interp in ("vertex", "varying"):
            point_normals = n
        elif interp == "constant":
            point_normals = np.repeat(n, len(P), axis=0)
        elif interp == "uniform":
            corner_normals = np.repeat(n[tri_face][:, None, :], 3, axis=1)
        else:
            corner_normals = n[tri_corner]
    else:
        point_normals, corner_normals, n_flat = auto_smooth_normals(tri_point, tri_n, len(P), tri_face)
        if n_flat:
            ctx.warn(f"{n_flat} points are shared by more than {MAX_SMOOTH_VALENCE} faces that bend by more than "
                     f"{CREASE_ANGLE_DEG / 2:g} degrees: their corners keep their face's normal (author normals "
                     "to smooth them)", path)

    if point_normals is None and dynamic:  # keep vertex i = point i for in-place updates
        acc = np.zeros_like(Pw)
        for j in range(3):
            np.add.at(acc, tri_point[:, j], corner_normals[:, j])
        point_normals, corner_normals = _unit(acc), None

    if point_normals is not None:
        vert_points, vert_normals, tri_vert = Pw, point_normals, tri_point
    else:
        flat_pid = tri_point.reshape(-1)
        flat_n = np.ascontiguousarray(corner_normals.reshape(-1, 3), dtype=np.float32)
        key = np.column_stack([flat_pid, flat_n.view(np.int32).astype(np.int64)])
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        vert_points, vert_normals = Pw[flat_pid[first]], flat_n[first]
        tri_vert = inverse.reshape(-1, 3)

    # Materials: bound per face, else displayColor per triangle, else the default.
    face_mat = face_materials(ctx, prim, len(counts), table)
    tri_mat = face_mat[tri_face]
    unbound = tri_mat < 0
    if np.any(unbound):
        colors = _display_color(ctx, mesh, tri_face, tri_point, tri_corner, len(P), len(counts), indices.size, path)
        if colors is None:
            tri_mat[unbound] = table.default()
        else:
            tri_mat[unbound] = table.display_colors(colors[unbound])

    return MeshPart(
        path=path,
        points=vert_points.astype(np.float32),
        normals=vert_normals.astype(np.float32),
        indices=tri_vert.astype(np.int32),
        triangle_material=tri_mat.astype(np.int32),
        dynamic=bool(dynamic),
        water=water,
    ), ""
