"""Image output: float32 AOVs as OpenEXR and .npy, the HDR image tone-mapped to an 8-bit sRGB PNG."""

from __future__ import annotations

import os

import numpy as np

from .errors import SceneError


def write_exr(path: str, image: np.ndarray) -> None:
    """Write a float32 image: (H, W) as channel Y, (H, W, 3) as RGB, (H, W, 2) as R, G (ZIP compression)."""
    import OpenEXR

    a = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if a.ndim == 2:
        channels = {"Y": a}
    elif a.ndim == 3 and a.shape[2] == 3:
        channels = {"RGB": a}
    elif a.ndim == 3 and a.shape[2] in (1, 2, 4):
        channels = {name: np.ascontiguousarray(a[..., k]) for k, name in enumerate("RGBA"[: a.shape[2]])}
    else:
        raise ValueError(f"cannot write an image of shape {a.shape} to '{path}'")
    OpenEXR.File(header, channels).write(path)


def read_exr(path: str) -> np.ndarray:
    """Read an EXR written by :func:`write_exr` back to (H, W) or (H, W, C) float32."""
    import OpenEXR

    ch = OpenEXR.File(path).channels()
    if "RGB" in ch:
        return np.asarray(ch["RGB"].pixels, dtype=np.float32)
    if "Y" in ch:
        return np.asarray(ch["Y"].pixels, dtype=np.float32)
    names = [c for c in "RGBA" if c in ch]
    return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in names], axis=-1)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 relative luminance of linear RGB."""
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


def auto_exposure(hdr: np.ndarray) -> float:
    """Exposure scale that maps the median luminance of lit pixels to middle grey (0.18).

    A display choice only: it never touches the radiometric AOVs.
    """
    lum = luminance(hdr)
    lit = lum[lum > 0.0]
    if lit.size == 0:
        return 1.0
    return 0.18 / float(np.median(lit))


def tonemap(hdr: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """HDR radiance -> 8-bit sRGB: exposure scale (auto when None), ACES filmic fit (Narkowicz 2015), sRGB OETF."""
    scale = auto_exposure(hdr) if exposure is None else exposure
    x = np.clip(np.nan_to_num(hdr, nan=0.0, posinf=0.0) * scale, 0.0, None)
    y = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    srgb = np.where(y <= 0.0031308, 12.92 * y, 1.055 * np.power(y, 1.0 / 2.4) - 0.055)
    return (np.clip(srgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: str, hdr: np.ndarray, exposure: float | None = None) -> None:
    from PIL import Image

    Image.fromarray(tonemap(hdr, exposure)).save(path)


def write_aovs(out_dir: str, aovs: dict[str, np.ndarray], exr: bool = True, npy: bool = True) -> list[str]:
    """Write every AOV as ``NAME.exr`` and ``NAME.npy`` (float32) into ``out_dir``; returns the paths."""
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise SceneError(f"cannot create output directory: {e.strerror}", file=out_dir) from e
    written = []
    for name, a in aovs.items():
        a = np.asarray(a)
        if a.dtype.kind == "f":
            a = a.astype(np.float32)
        if npy:
            p = os.path.join(out_dir, f"{name}.npy")
            np.save(p, a)
            written.append(p)
        if exr:
            p = os.path.join(out_dir, f"{name}.exr")
            write_exr(p, a.astype(np.float32))
            written.append(p)
    return written
