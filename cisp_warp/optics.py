"""Exact dielectric optics: unpolarised Fresnel reflectance, reflection and refraction (Warp and numpy twins)."""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.func
def fresnel_dielectric(cos_i: float, eta: float) -> float:
    """Unpolarised Fresnel reflectance for light arriving at ``cos_i`` (>= 0) on a boundary with
    relative index ``eta = n_transmitted / n_incident``; 1 under total internal reflection."""
    c = wp.clamp(cos_i, 0.0, 1.0)
    sin2_t = (1.0 - c * c) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = wp.sqrt(1.0 - sin2_t)
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (rs * rs + rp * rp)


@wp.func
def reflect(d: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Mirror direction of unit ``d`` about unit normal ``n``."""
    return d - n * (2.0 * wp.dot(d, n))


@wp.func
def refract(d: wp.vec3, n: wp.vec3, eta: float) -> wp.vec3:
    """Refracted direction of unit ``d`` through a surface with unit normal ``n`` facing against ``d``
    (dot(d, n) <= 0) and ``eta = n_transmitted / n_incident``. Zero vector under total internal reflection."""
    cos_i = -wp.dot(d, n)
    k = 1.0 / eta
    sin2_t = k * k * (1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return wp.vec3(0.0)
    return wp.normalize(d * k + n * (k * cos_i - wp.sqrt(1.0 - sin2_t)))


def fresnel_dielectric_np(cos_i, eta):
    """numpy twin of :func:`fresnel_dielectric` (float64)."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    sin2_t = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))
