"""Image output: AOVs as one multi-channel OpenEXR (compositor channel names), the HDR image as EXR and as
an 8-bit sRGB PNG, optional .npy; every file written under a temporary name and renamed when complete.

The layered EXR (:func:`write_layers`): the beauty as ``R, G, B``, every other AOV as a layer
``NAME.R/G/B`` (colours, irradiances), ``NAME.X/Y/Z`` (positions, normals, motion), ``Z`` (depth) or a
bare ``NAME`` (scalars); integer ids as UINT (−1, none, becomes 4294967295). Colour layers are stored as
float16 (HALF) when every value fits (|v| < 60000; float16 keeps 3 significant digits, below what a
display or a compositing grade resolves), else float32; depth and positions always float32.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import SceneError


def atomic_path(path: str) -> str:
    """Temporary name beside ``path`` to write to before :func:`os.replace` puts the file in place."""
    d, name = os.path.split(path)
    return os.path.join(d, f".{name}.partial")


def check_out_dir(out_dir: str) -> None:
    """Create ``out_dir`` if needed and make sure files can be written there, before any rendering."""
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise SceneError(f"cannot create the output folder: {e.strerror}", file=out_dir) from None
    if not os.path.isdir(out_dir):
        raise SceneError("the output path exists and is not a folder", file=out_dir)
    probe = os.path.join(out_dir, f".cisp_write_test_{os.getpid()}")
    try:
        with open(probe, "wb") as f:
            f.write(b"0")
        os.remove(probe)
    except OSError as e:
        raise SceneError(f"the output folder is not writable: {e.strerror}", file=out_dir) from None


def write_exr(path: str, image: np.ndarray) -> None:
    """Write a float32 image: (H, W) as channel Y, (H, W, 3) as RGB, (H, W, 2) as R, G (ZIP compression)."""
    a = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    if a.ndim == 2:
        channels = {"Y": a}
    elif a.ndim == 3 and a.shape[2] == 3:
        channels = {"RGB": a}
    elif a.ndim == 3 and a.shape[2] in (1, 2, 4):
        channels = {name: np.ascontiguousarray(a[..., k]) for k, name in enumerate("RGBA"[: a.shape[2]])}
    else:
        raise ValueError(f"cannot write an image of shape {a.shape} to '{path}'")
    _write_channels(path, channels)


def _write_channels(path: str, channels: dict[str, np.ndarray]) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    tmp = atomic_path(path)
    try:
        OpenEXR.File(header, channels).write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


#: suffixes of a layer's channels by AOV kind; the beauty ("final") is the unprefixed R, G, B
VECTOR_AOVS = ("position", "normal", "water_position", "water_normal", "motion")
MAIN_AOVS = ("final", "caustics", "direct_irradiance", "sky_irradiance", "depth", "normal", "tri_id")
#: conventional layer names of the main AOVs
LAYER_NAMES = {"final": "", "caustics": "caustics", "direct_irradiance": "direct", "sky_irradiance": "sky",
               "depth": "Z", "normal": "N", "tri_id": "id", "photon_map": "photon_map"}
HALF_MAX = 60000.0


def exr_channels(aovs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Channel name -> (H, W) array (float16, float32 or uint32) for :func:`write_layers` (see the module doc)."""
    out = {}
    for name, a in aovs.items():
        a = np.asarray(a)
        layer = LAYER_NAMES.get(name, name)
        if a.dtype.kind in "iu":
            if a.ndim != 2:
                raise ValueError(f"integer AOV '{name}' must be (H, W)")
            out[layer] = np.ascontiguousarray(a.astype(np.int64).astype(np.uint32))
            continue
        a = a.astype(np.float32)
        exact = name in ("depth", "position", "water_depth", "water_position") or a.ndim == 2 and name != "roughness"
        if not exact and np.all(np.isfinite(a)) and (a.size == 0 or float(np.abs(a).max()) < HALF_MAX):
            a = a.astype(np.float16)
        if a.ndim == 2:
            out[layer] = np.ascontiguousarray(a)
            continue
        names = "XYZ" if name in VECTOR_AOVS else "RGBA"
        for k in range(a.shape[2]):
            out[f"{layer}.{names[k]}" if layer else names[k]] = np.ascontiguousarray(a[..., k])
    return out


def write_layers(path: str, aovs: dict[str, np.ndarray]) -> None:
    """One multi-channel EXR of ``aovs`` (channel names in the module docstring), written atomically."""
    _write_channels(path, exr_channels(aovs))


def read_layers(path: str) -> dict[str, np.ndarray]:
    """Every channel of an EXR: name -> (H, W) array in its stored type (float16, float32, uint32)."""
    import OpenEXR

    with OpenEXR.File(path, separate_channels=True) as f:
        return {name: np.asarray(c.pixels) for name, c in f.channels().items()}


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

    tmp = atomic_path(path)
    try:
        Image.fromarray(tonemap(hdr, exposure)).save(tmp, format="PNG")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


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
            tmp = atomic_path(p) + ".npy"
            np.save(tmp, a)
            os.replace(tmp, p)
            written.append(p)
        if exr:
            p = os.path.join(out_dir, f"{name}.exr")
            write_exr(p, a.astype(np.float32))
            written.append(p)
    return written
