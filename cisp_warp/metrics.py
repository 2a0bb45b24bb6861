"""Error figures against the reference, on the host (numpy): what ``tools/evaluate.py`` and
``tools/stability.py`` report, defined once.

Every figure reads the AOVs of :meth:`cisp_warp.render.Renderer.aovs` (images of shape (H, W[, C])) and
works on the **luminance** Y of an irradiance (Rec. 709 weights, which sum to 1: for a white light Y is
the irradiance itself) [W/m²].

================  =====================================================================================
figure            definition
================  =====================================================================================
caustic mask      pixels where the reference shows a caustic: Y_ref > ``MASK_FRACTION`` × P99(Y_ref) and
                  Y_ref > ``MASK_SIGMAS`` × σ_ref (σ_ref: the reference's standard error, ``caustics_stderr``),
                  not at a geometric edge (:func:`geometric_edges`): there a pixel holds several surfaces, the
                  reference counts photons on any of them (exact visibility) and the G-buffer methods those on
                  the pixel centre's surface, so the two estimate different things
relative RMSE     sqrt(mean_M (Y − Y_ref)²) / mean_M Y_ref over the mask M
reference noise   sqrt(mean_M σ_ref²) / mean_M Y_ref: the floor under which a relative RMSE is not resolved
power             Σ_p Y(p) · A(p) [W] over the camera's pixels, A the exact world-space footprint of pixel p
energy ratio      power(method) / power(reference)
flicker           Σ_valid |Y_t(p) − Y_{t−1}(p + m(p))| / Σ_valid Y_t(p) between consecutive frames, m the
                  ``motion`` AOV (nearest pixel); valid: inside the image, the same triangle, the same surface
                  point within two pixel widths, and inside the reference's caustic mask
FLIP              LDR-FLIP (``flip-evaluator``) of the method's ``final`` against the reference's, both tone
                  mapped by :func:`cisp_warp.image_io.tonemap` with the reference's exposure
================  =====================================================================================
"""

from __future__ import annotations

import math

import numpy as np

from .image_io import auto_exposure, luminance, tonemap
from .raster.views import View

MASK_FRACTION = 0.05  #: a caustic pixel is brighter than this fraction of the reference's 99th percentile
MASK_SIGMAS = 3.0  #: ... and brighter than this many of the reference's own standard errors
EDGE_SINE = 0.25  #: a neighbour's surface point more than asin(0.25) ≈ 14.5° out of a pixel's tangent plane: an edge


def irradiance_y(aov: np.ndarray) -> np.ndarray:
    """Luminance [W/m²] of an (H, W, 3) irradiance AOV, float64."""
    return luminance(np.asarray(aov, dtype=np.float64))


def pixel_footprint(aovs: dict, view: View) -> np.ndarray:
    """Exact world-space area [m²] of every camera pixel's footprint on the opaque G-buffer, (H, W) float64.

    Perspective: Ω_p · r² / |cos θ| (Ω_p the pixel's exact solid angle, r the distance to the eye);
    orthographic: 1 / (fx · fy) / |cos θ|; θ is the angle between the surface normal and the view ray.
    0 where the pixel sees no surface.
    """
    x = aovs["position"].astype(np.float64)
    n = aovs["normal"].astype(np.float64)
    hit = aovs["depth"] > 0
    if view.orthographic:
        forward = -np.asarray(view.to_world, np.float64)[:3, 2]
        cos_t = np.abs(n @ forward)
        area = 1.0 / (view.fx * view.fy) / np.maximum(cos_t, 1e-6)
    else:
        to_eye = np.asarray(view.to_world, np.float64)[:3, 3] - x
        r2 = (to_eye ** 2).sum(-1)
        cos_t = np.abs((n * to_eye).sum(-1)) / np.sqrt(np.maximum(r2, 1e-30))
        area = view.texel_solid_angle() * r2 / np.maximum(cos_t, 1e-6)
    return np.where(hit, area, 0.0)


def geometric_edges(aovs: dict, sine: float = EDGE_SINE) -> np.ndarray:
    """Pixels at a silhouette or a crease, (H, W) bool: a 4-neighbour sees no surface, or its surface point
    lies more than asin(``sine``) out of this pixel's tangent plane (|n · Δx| > sine · |Δx|). On one smooth
    surface Δx stays in the tangent plane up to curvature (|n · Δx| / |Δx| ≈ |Δx| / 2R)."""
    x = aovs["position"].astype(np.float64)
    n = aovs["normal"].astype(np.float64)
    hit = aovs["depth"] > 0
    edge = np.zeros(hit.shape, bool)
    h, w = hit.shape
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ys = slice(max(dy, 0), h + min(dy, 0))  # pixels whose neighbour (y + dy, x + dx) exists
        xs = slice(max(dx, 0), w + min(dx, 0))
        yq = slice(max(-dy, 0), h + min(-dy, 0))
        xq = slice(max(-dx, 0), w + min(-dx, 0))
        d = x[yq, xq] - x[ys, xs]
        off = np.abs((n[ys, xs] * d).sum(-1)) > sine * np.linalg.norm(d, axis=-1)
        edge[ys, xs] |= off | ~hit[yq, xq]
    edge[0, :] |= True  # the frame's border: its outer neighbours are unknown
    edge[-1, :] |= True
    edge[:, 0] |= True
    edge[:, -1] |= True
    return edge & hit


def caustic_mask(reference: dict, fraction: float = MASK_FRACTION, sigmas: float = MASK_SIGMAS) -> np.ndarray:
    """Pixels where the reference shows a caustic, off geometric edges (see the module table), (H, W) bool."""
    y = irradiance_y(reference["photon_map"])
    se = irradiance_y(reference["caustics_stderr"])
    lit = y[y > 0]
    if lit.size == 0:
        return np.zeros(y.shape, bool)
    return (y > fraction * np.percentile(y, 99)) & (y > sigmas * se) & (reference["depth"] > 0) \
        & ~geometric_edges(reference)


def relative_rmse(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """sqrt(mean_M (Y − Y_ref)²) / mean_M Y_ref for (H, W, 3) irradiances; NaN on an empty mask."""
    if not mask.any():
        return math.nan
    y, yr = irradiance_y(estimate)[mask], irradiance_y(reference)[mask]
    return float(np.sqrt(np.mean((y - yr) ** 2)) / np.mean(yr))


def reference_noise(reference: dict, mask: np.ndarray) -> float:
    """The reference's own relative standard error over ``mask``: errors below it are not resolved."""
    if not mask.any():
        return math.nan
    se = irradiance_y(reference["caustics_stderr"])[mask]
    return float(np.sqrt(np.mean(se ** 2)) / np.mean(irradiance_y(reference["photon_map"])[mask]))


def power(irradiance: np.ndarray, footprint: np.ndarray, region: np.ndarray | None = None) -> float:
    """Σ Y · A [W] over the pixels of ``region`` (all when None)."""
    p = irradiance_y(irradiance) * footprint
    return float(p.sum() if region is None else p[region].sum())


def energy_ratio(estimate: np.ndarray, reference: np.ndarray, footprint: np.ndarray,
                 region: np.ndarray | None = None) -> float:
    """power(estimate) / power(reference) over ``region``; NaN when the reference has none there."""
    ref = power(reference, footprint, region)
    return power(estimate, footprint, region) / ref if ref > 0 else math.nan


def reprojection(prev: dict, cur: dict, footprint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of ``cur``, the flat index of its nearest pixel in ``prev`` (by ``cur``'s motion
    AOV) and whether that tap is the same surface: inside the image, same triangle, and the same world
    point within two pixel widths (2 sqrt(A)). Returns (index (H, W) int64, valid (H, W) bool)."""
    h, w = cur["depth"].shape
    ys, xs = np.mgrid[0:h, 0:w]
    qx = np.floor(xs + 0.5 + cur["motion"][..., 0]).astype(np.int64)
    qy = np.floor(ys + 0.5 + cur["motion"][..., 1]).astype(np.int64)
    inside = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h) & (cur["depth"] > 0)
    q = np.where(inside, qy * w + qx, 0)
    same_tri = prev["tri_id"].reshape(-1)[q] == cur["tri_id"]
    moved = np.linalg.norm(prev["position"].reshape(-1, 3)[q].astype(np.float64) - cur["position"], axis=-1)
    valid = inside & same_tri & (moved <= 2.0 * np.sqrt(footprint))
    return q, valid


def flicker(prev: dict, cur: dict, footprint: np.ndarray, mask: np.ndarray, key: str = "caustics") -> float:
    """Mean relative frame-to-frame difference of ``key`` reprojected from ``prev`` to ``cur`` over the
    valid pixels of ``mask`` (see the module table); NaN when no pixel is valid."""
    q, valid = reprojection(prev, cur, footprint)
    valid &= mask
    if not valid.any():
        return math.nan
    y = irradiance_y(cur[key])[valid]
    y_prev = irradiance_y(prev[key]).reshape(-1)[q[valid]]
    total = y.sum()
    return float(np.abs(y - y_prev).sum() / total) if total > 0 else math.nan


def flip_ldr(final: np.ndarray, reference_final: np.ndarray) -> float:
    """Mean LDR-FLIP of ``final`` against ``reference_final`` (HDR radiance images), both tone mapped by
    :func:`cisp_warp.image_io.tonemap` with the reference's automatic exposure (so a brightness error
    counts); 67 pixels per degree, FLIP's default. Needs ``flip-evaluator`` (``pip install -e .[eval]``)."""
    import flip_evaluator as flip

    exposure = auto_exposure(reference_final)
    ref = tonemap(reference_final, exposure).astype(np.float32) / 255.0
    test = tonemap(final, exposure).astype(np.float32) / 255.0
    _, mean, _ = flip.evaluate(ref, test, "LDR", inputsRGB=True, applyMagma=False, computeMeanError=True)
    return float(mean)


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401
    except ImportError:
        return False
    return True
