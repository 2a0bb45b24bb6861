"""Tests of sim.WaterMesh: triangles, normals, periodic tiling, caller-owned outputs."""

import numpy as np
import pytest
import warp as wp

from sim import FFTWater, SimParameterError, WaterMesh, WaterParams


def water_on(device, **changes):
    base = dict(resolution=32, patch_size=1.0, depth=1.0, wind_speed=3.0, fetch=40.0,
                small_wave_cutoff=0.02, choppiness=0.8, seed=5)
    base.update(changes)
    return FFTWater(WaterParams(**base), device)


def test_mesh_indices_and_normals(device):
    water = water_on(device)
    nx, nz = 13, 9
    mesh = WaterMesh(water, rect=(-0.7, 0.2, 1.1, 1.3), y0=0.25, vertex_counts=(nx, nz))
    mesh.update(0.6)
    points = mesh.points.numpy()
    normals = mesh.normals.numpy()
    triangles = mesh.indices.numpy().reshape(-1, 3)
    assert mesh.indices.dtype == wp.int32
    assert triangles.shape == (2 * (nx - 1) * (nz - 1), 3)
    assert triangles.min() == 0 and triangles.max() == nx * nz - 1
    assert np.all(triangles[:, 0] != triangles[:, 1]) and np.all(triangles[:, 1] != triangles[:, 2])
    assert np.all(np.bincount(triangles.ravel(), minlength=nx * nz) > 0)  # every vertex used
    assert np.max(np.abs(np.linalg.norm(normals, axis=1) - 1.0)) <= 1e-5
    assert np.all(normals[:, 1] > 0.0)
    face = np.cross(points[triangles[:, 1]] - points[triangles[:, 0]],
                    points[triangles[:, 2]] - points[triangles[:, 0]])
    assert np.all(face[:, 1] > 0.0)  # counter-clockwise seen from +Y
    # the geometric normals agree with the vertex normals (mean over each triangle's corners)
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    corner_mean = normals[triangles].mean(axis=1)
    corner_mean /= np.linalg.norm(corner_mean, axis=1, keepdims=True)
    assert np.min(np.sum(face * corner_mean, axis=1)) > np.cos(np.radians(10.0))
    # rest heights around y0, border vertices pinned to the rectangle's edges
    assert abs(np.mean(points[:, 1]) - 0.25) < 0.05
    grid = points.reshape(nz, nx, 3)
    assert np.allclose(grid[:, 0, 0], -0.7) and np.allclose(grid[:, -1, 0], 1.1)
    assert np.allclose(grid[0, :, 2], 0.2) and np.allclose(grid[-1, :, 2], 1.3)


def test_mesh_tiles_periodically(device):
    water = water_on(device)
    patch = water.patch_size
    per_patch = 8  # vertices per patch length, so x and x + L are both vertices
    nx = 2 * per_patch + 1
    x0, z0 = -0.3, 0.45
    mesh = WaterMesh(water, rect=(x0, z0, x0 + 2 * patch, z0 + patch), y0=0.0,
                     vertex_counts=(nx, per_patch + 1), pin_border=False)
    mesh.update(1.9)
    points = mesh.points.numpy().reshape(per_patch + 1, nx, 3)
    normals = mesh.normals.numpy().reshape(per_patch + 1, nx, 3)
    left, right = points[:, :per_patch + 1], points[:, per_patch:]
    shifted = right - np.array([patch, 0.0, 0.0], dtype=np.float32)
    assert np.max(np.abs(shifted - left)) <= 1e-5
    assert np.max(np.abs(normals[:, per_patch:] - normals[:, :per_patch + 1])) <= 1e-5
    # across z too: first and last rows are L apart
    top = points[-1] - np.array([0.0, 0.0, patch], dtype=np.float32)
    assert np.max(np.abs(top - points[0])) <= 1e-5
    # the surface inside one patch is not constant (periodicity is not trivial)
    assert np.ptp(points[:, :, 1]) > 1e-4


def test_mesh_writes_caller_arrays_in_place(device):
    water = water_on(device)
    count = 6 * 5
    points = wp.zeros(count, dtype=wp.vec3, device=device)
    normals = wp.zeros(count, dtype=wp.vec3, device=device)
    mesh = WaterMesh(water, rect=(0.0, 0.0, 1.0, 1.0), vertex_counts=(6, 5),
                     points=points, normals=normals)
    assert mesh.points is points and mesh.normals is normals
    mesh.update(0.2)
    assert np.all(np.abs(np.linalg.norm(normals.numpy(), axis=1) - 1.0) <= 1e-5)
    other = wp.zeros(count, dtype=wp.vec3, device=device)
    mesh.update(0.2, points=other)
    assert np.array_equal(other.numpy(), points.numpy())
    with pytest.raises(SimParameterError, match="points"):
        mesh.update(0.2, points=wp.zeros(count + 1, dtype=wp.vec3, device=device))


def test_flat_water_mesh_is_the_rest_plane(device):
    water = water_on(device, amplitude=0.0)
    mesh = WaterMesh(water, rect=(0.0, 0.0, 2.0, 1.0), y0=-0.4, vertex_counts=(5, 3))
    mesh.update(3.0)
    points, normals = mesh.points.numpy(), mesh.normals.numpy()
    assert np.all(points[:, 1] == np.float32(-0.4))
    assert np.all(normals == np.array([0.0, 1.0, 0.0], dtype=np.float32))
    xs = np.linspace(0.0, 2.0, 5, dtype=np.float32)
    assert np.allclose(points[:5, 0], xs)


@pytest.mark.parametrize("rect", [(1.0, 0.0, 0.0, 1.0), (0.0, 1.0, 1.0, 1.0),
                                  (0.0, 0.0, float("nan"), 1.0), (0.0, 0.0, 1.0), "abcd"])
def test_bad_rect_is_rejected(rect):
    water = water_on("cpu")
    with pytest.raises(SimParameterError, match="rect"):
        WaterMesh(water, rect=rect, vertex_counts=(4, 4))


@pytest.mark.parametrize("counts", [(1, 4), (4, 0), (4.0, 4), (4,), (1 << 14, 1 << 14)])
def test_bad_vertex_counts_are_rejected(counts):
    water = water_on("cpu")
    with pytest.raises(SimParameterError, match="vertex_counts"):
        WaterMesh(water, rect=(0.0, 0.0, 1.0, 1.0), vertex_counts=counts)
