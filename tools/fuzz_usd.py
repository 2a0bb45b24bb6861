"""Mutation fuzzer of cisp_warp's input handling: every bad stage must end in one clear sentence.

Each case takes a seed stage (the shipped scenes, ``tools/make_pool_scene.py`` variants, small
hand-made stages), mutates it once (text level on ``.usda``, bytes of a ``.usdc``, attribute level
through ``pxr``, resources: references/payloads/sublayers to FIFOs, devices, folders; giant n-gons;
or ``cisp-render``'s own numbers), and renders it with ``cisp_warp.cli.main`` at 32×32 on the CPU with
a few photons and a random method, in a forked worker with a deadline and a memory cap
(``resource.setrlimit(RLIMIT_AS)``). The outcome of each case is one of:

=====================  ===================================================================  =========
outcome                meaning                                                              a failure
=====================  ===================================================================  =========
``rendered``           exit 0, every AOV finite
``scene_error``        exit 2 with one ``cisp-render: error:`` sentence naming the file
                       (or, for a bad command-line number, the flag)
``error_no_file``      an error message that names neither the file nor the flag           yes
``nan_aov``            exit 0 but an AOV (``*.npy``) holds NaN or Inf                       yes
``traceback``          a Python exception escaped ``main``                                  yes
``crash``              the worker died of a signal (abort, segfault, out of memory in C++)  yes
``hang``               the worker ran past ``--deadline`` seconds                           yes
``nonsense``           exit 0 but detectably wrong: no ``final.png``, an image of another   yes
                       size than asked, or ``--out``'s existing file changed
=====================  ===================================================================  =========

A table of outcomes (and of failures per mutation family) is printed at the end; ``--out`` gets
``cases.json`` with every case (seed stage, mutation, method, argv, outcome, message) and the stage
files of every failing case, so ``--only ID --seed S`` reproduces one case in the foreground.

    python3 tools/fuzz_usd.py --cases 5000 --seed 1 --jobs 2 --out /tmp/fuzz
    python3 tools/fuzz_usd.py --cases 30 --seed 1 --smoke      # seconds; what tests/test_fuzz_usd.py runs

Exit status 0 when no case failed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import math
import os
import random
import re
import resource
import shutil
import signal
import stat
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

OUTCOMES = ("rendered", "scene_error", "error_no_file", "nan_aov", "traceback", "crash", "hang", "nonsense")
FAILURES = ("error_no_file", "nan_aov", "traceback", "crash", "hang", "nonsense")
METHODS = ("cisp", "sspm", "caustics_map", "reference")
SENTINEL = "keep_me.txt"  #: a file placed in every case's --out first: no run may change or delete it

# Values that break numbers: zero, signs, float32 and float64 limits, NaN/Inf, integers past 32 bits.
NASTY_NUMBERS = ["0", "-0", "1", "-1", "-1e-30", "1e-30", "1e-300", "1e-45", "3.5e38", "-3.5e38", "1e38",
                 "1e300", "-1e300", "nan", "inf", "-inf", "2147483648", "-2147483649", "4294967296",
                 "9223372036854775808", "1e6", "65536", "4096", "0.5", "360", "180", "128", "1024", "7"]
USD_TYPES = ["float", "double", "int", "half", "bool", "string", "token", "float2", "float3", "double3", "int2",
             "int3", "color3f", "point3f", "normal3f", "float[]", "double[]", "int[]", "string[]", "token[]",
             "float2[]", "float3[]", "point3f[]", "normal3f[]", "color3f[]", "int2[]", "matrix4d", "quatf",
             "asset", "bool[]"]
PRIM_TYPES = ["Mesh", "Xform", "Scope", "Sphere", "Cube", "Points", "Camera", "DistantLight", "SphereLight",
              "RectLight", "DomeLight", "DiskLight", "Material", "Shader", "GeomSubset", "RenderSettings",
              "PointInstancer", "BasisCurves", "NotAType"]
SPECIAL_FILES = ["fifo", "dir", "/dev/zero", "/dev/null", "/dev/urandom", "missing", "self", "big", "binary"]
_NUMBER = re.compile(rb"(?<![\w.#@])-?\d+(?:\.\d+)?(?:[eE][+-]?\d+)?(?![\w.])")
_TYPE_DECL = re.compile(rb"^(\s*(?:uniform |custom |varying )*)([a-zA-Z0-9]+(?:\[\])?) ([\w:]+)( = |\.)",
                        re.M)
_DEF = re.compile(rb'\bdef ([A-Za-z]+) "')
_STRING = re.compile(rb'"([^"\n]{0,40})"')
_ARRAY = re.compile(rb"= \[([^\[\]\n]{1,4000})\]")


# ---------------------------------------------------------------------------------------- seed stages


def _small_stages() -> dict[str, str]:
    """Hand-made stages, each valid: the malformed corpus' base plus variants with water, spot, Z up."""
    spec = importlib.util.spec_from_file_location("make_corpus", ROOT / "tests" / "malformed" / "make_corpus.py")
    mc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mc)
    water_mesh = """
    def Mesh "Water"
    {
        int[] faceVertexCounts = [4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6, 4, 5, 8, 7]
        point3f[] points = [(-1, 0.5, -1), (0, 0.5, -1), (1, 0.5, -1), (-1, 0.5, 0), (0, 0.5, 0), (1, 0.5, 0), (-1, 0.5, 1), (0, 0.5, 1), (1, 0.5, 1)]
        custom double cisp:water:amplitude = 1
        custom double cisp:water:choppiness = 0.5
        custom double cisp:water:depth = 1.2
        custom double cisp:water:fetch = 8
        custom double cisp:water:patch_size = 4
        custom int cisp:water:resolution = 16
        custom int cisp:water:seed = 7
        custom double cisp:water:small_wave_cutoff = 0.15
        custom string cisp:water:spectrum = "phillips"
        custom double cisp:water:wind_direction = 0.3
        custom double cisp:water:wind_speed = 2
        rel material:binding = </World/Looks/Water>
    }
"""
    spot = """
    def SphereLight "Spot" (
        prepend apiSchemas = ["ShapingAPI"]
    )
    {
        float inputs:intensity = 20
        float inputs:exposure = 0
        color3f inputs:color = (1, 0.9, 0.8)
        bool treatAsPoint = 1
        float inputs:shaping:cone:angle = 30
        float inputs:shaping:cone:softness = 0.2
        double3 xformOp:translate = (0, 3, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
"""
    hexagon = """
    def Mesh "Hexagon"
    {
        int[] faceVertexCounts = [6, 5]
        int[] faceVertexIndices = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10]
        point3f[] points = [(0, 0.1, 0), (0.5, 0.1, 0.1), (0.6, 0.1, 0.5), (0.3, 0.1, 0.2), (0.1, 0.1, 0.6), (-0.3, 0.1, 0.3), (-1, 0.2, -1), (-0.5, 0.2, -1), (-0.5, 0.2, -0.5), (-0.8, 0.2, -0.7), (-1, 0.2, -0.5)]
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)]
        uniform token subdivisionScheme = "none"
        color3f[] primvars:displayColor = [(0.8, 0.2, 0.1), (0.1, 0.7, 0.2)] (
            interpolation = "uniform"
        )
    }
"""
    return {
        "small_base.usda": mc.stage_text(extra_root=mc.render_settings("(64, 48)")),
        "small_water.usda": mc.stage_text(extra_world=mc.WATER_MATERIAL.format(ior="1.33") + water_mesh),
        "small_spot.usda": mc.stage_text(sun=False, extra_world=spot + hexagon, up="Z", mpu="0.01"),
    }


def build_seeds(folder: Path, smoke: bool) -> list[Path]:
    """Write every seed stage into ``folder``; returns their paths (each loads cleanly)."""
    from pxr import Sdf

    folder.mkdir(parents=True, exist_ok=True)
    seeds = []
    for name, text in _small_stages().items():
        (folder / name).write_text(text)
        seeds.append(folder / name)
    for name in ("cornell_flooded.usda", "pool.usda"):
        shutil.copy(ROOT / "scenes_usd" / name, folder / name)
        seeds.append(folder / name)
    for image in (ROOT / "scenes_usd").glob("*.exr"):  # the shipped stages' sky images, next to them
        shutil.copy(image, folder / image.name)
    if not smoke:
        import subprocess

        variants = {"pool_night.usda": ["--night", "--water-spacing", "0.5"],
                    "pool_baked.usda": ["--bake", "2", "--water-spacing", "0.5", "--seed", "3"],
                    "pool_choppy.usda": ["--choppiness", "2", "--wind-speed", "9", "--depth", "0.5",
                                         "--water-spacing", "0.25"]}
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        for name, extra in variants.items():
            out = folder / name
            subprocess.run([sys.executable, str(ROOT / "tools" / "make_pool_scene.py"), "--out", str(out)] + extra,
                           check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            seeds.append(out)
    for src in (folder / "small_base.usda", folder / "small_water.usda", folder / "pool.usda"):
        dst = src.with_name(src.stem + "_crate.usdc")
        Sdf.Layer.FindOrOpen(str(src)).Export(str(dst))
        seeds.append(dst)
    return seeds


# ------------------------------------------------------------------------------------------ mutations


def _special_file(rng: random.Random, case_dir: Path, stage_name: str) -> tuple[str, str]:
    """(asset path text, kind) of a resource that is not a readable USD layer."""
    kind = rng.choice(SPECIAL_FILES)
    if kind == "fifo":
        p = case_dir / "pipe.usda"
        os.mkfifo(p)
        return "./pipe.usda", kind
    if kind == "dir":
        (case_dir / "folder.usda").mkdir()
        return "./folder.usda", kind
    if kind == "missing":
        return "./gone.usda", kind
    if kind == "self":
        return "./" + stage_name, kind
    if kind == "big":
        p = case_dir / "big.usda"
        with open(p, "wb") as f:
            f.write(b"#usda 1.0\n")
            f.truncate(300 << 20)  # 300 MB of NUL bytes (sparse)
        return "./big.usda", kind
    if kind == "binary":
        (case_dir / "bin.usdc").write_bytes(b"PXR-USDC" + bytes(rng.randrange(256) for _ in range(512)))
        return "./bin.usdc", kind
    return kind, kind  # a device path


def _ngon(rng: random.Random) -> tuple[str, str]:
    """A Mesh prim of one polygon with many corners: convex (a fan) or a star (ear clipping)."""
    n = rng.choice([500, 5000, 20000, 60000, 100000])
    star = rng.random() < 0.5
    pts = []
    for k in range(n):
        a = 2.0 * math.pi * k / n
        r = (1.0 if k % 2 == 0 else 0.6) if star else 1.0
        pts.append(f"({r * math.cos(a):.6g}, 0.05, {r * math.sin(a):.6g})")
    text = f"""
    def Mesh "NGon"
    {{
        int[] faceVertexCounts = [{n}]
        int[] faceVertexIndices = [{", ".join(map(str, range(n)))}]
        point3f[] points = [{", ".join(pts)}]
    }}
"""
    return text, f"ngon n={n} {'star' if star else 'convex'}"


def _insert_into_world(data: bytes, text: str) -> bytes:
    m = re.search(rb'def Xform "World"[^{]*\{', data)
    if not m:
        return data + text.encode()
    return data[: m.end()] + text.encode() + data[m.end():]


def mutate_text(rng: random.Random, data: bytes, case_dir: Path, stage_name: str) -> tuple[bytes, str]:
    """One text-level mutation of a .usda file's bytes; returns (new bytes, description)."""
    op = rng.choice(["number", "number", "number", "type", "line_delete", "line_dup", "truncate", "bytes",
                     "string", "prim_type", "resource", "ngon", "array", "water", "metadata"])
    if op == "number":
        ms = list(_NUMBER.finditer(data))
        if ms:
            m = rng.choice(ms)
            v = rng.choice(NASTY_NUMBERS)
            return data[: m.start()] + v.encode() + data[m.end():], f"number@{m.start()} {m.group().decode()}->{v}"
    if op == "type":
        ms = list(_TYPE_DECL.finditer(data))
        if ms:
            m = rng.choice(ms)
            t = rng.choice(USD_TYPES)
            return (data[: m.start(2)] + t.encode() + data[m.end(2):],
                    f"type {m.group(3).decode()}: {m.group(2).decode()}->{t}")
    if op in ("line_delete", "line_dup"):
        lines = data.split(b"\n")
        k = rng.randrange(len(lines))
        if op == "line_delete":
            desc = f"delete line {k + 1}: {lines[k][:60]!r}"
            del lines[k]
        else:
            desc = f"duplicate line {k + 1}: {lines[k][:60]!r}"
            lines.insert(k, lines[k])
        return b"\n".join(lines), desc
    if op == "truncate":
        k = rng.randrange(len(data))
        return data[:k], f"truncate at {k}"
    if op == "bytes":
        k = rng.randrange(len(data))
        junk = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        return data[:k] + junk + data[k:], f"insert {len(junk)} random bytes at {k}"
    if op == "string":
        ms = list(_STRING.finditer(data))
        if ms:
            m = rng.choice(ms)
            v = rng.choice(["", "X", "Z", "640x360", "1e30", "nan", "leftHanded", "faceVarying", "orthographic",
                            "invisible", "guide", "\xff\xfe", "a" * 300, "uniform", "constant", "3"])
            return data[: m.start(1)] + v.encode("utf-8", "surrogateescape") + data[m.end(1):], \
                f"string {m.group(1)[:30].decode(errors='replace')!r}->{v[:20]!r}"
    if op == "prim_type":
        ms = list(_DEF.finditer(data))
        if ms:
            m = rng.choice(ms)
            t = rng.choice(PRIM_TYPES)
            return data[: m.start(1)] + t.encode() + data[m.end(1):], f"prim type {m.group(1).decode()}->{t}"
    if op == "resource":
        asset, kind = _special_file(rng, case_dir, stage_name)
        how = rng.choice(["references", "payload", "subLayers"])
        if how == "subLayers":
            header_end = data.find(b"(\n")
            if data.startswith(b"#usda") and header_end >= 0:
                data = data[: header_end + 2] + f"    subLayers = [@{asset}@]\n".encode() + data[header_end + 2:]
            return data, f"subLayers -> {kind}"
        prim = f'\n    def Xform "Extra" (\n        {how} = @{asset}@\n    )\n    {{\n    }}\n'
        return _insert_into_world(data, prim), f"{how} -> {kind}"
    if op == "ngon":
        text, desc = _ngon(rng)
        return _insert_into_world(data, text), desc
    if op == "array":
        ms = list(_ARRAY.finditer(data))
        if ms:
            m = rng.choice(ms)
            choice = rng.choice(["empty", "half", "tuples", "strings", "nested"])
            body = m.group(1)
            new = {"empty": b"", "half": body[: len(body) // 2].rsplit(b",", 1)[0],
                   "tuples": b"(1, 2, 3), (4, 5, 6)", "strings": b'"a", "b"', "nested": b"[1, 2], [3]"}[choice]
            return data[: m.start(1)] + new + data[m.end(1):], f"array@{m.start()} -> {choice}"
    if op == "water":
        ms = list(re.finditer(rb"cisp:water:(\w+) = ([^\s(]+)", data))
        if ms:
            m = rng.choice(ms)
            v = rng.choice(NASTY_NUMBERS + ['"jonswap"', '"nope"', "8192", "4096", "2048", "3", "1e30"])
            return data[: m.start(2)] + v.encode() + data[m.end(2):], f"cisp:water:{m.group(1).decode()} -> {v}"
    if op == "metadata":
        key = rng.choice([b"metersPerUnit", b"timeCodesPerSecond", b"startTimeCode", b"upAxis"])
        v = rng.choice(NASTY_NUMBERS + ['"X"', '"Z"', '"y"'])
        m = re.search(key + rb" = [^\n]+", data)
        if m:
            return data[: m.start()] + key + b" = " + v.encode() + data[m.end():], f"{key.decode()} -> {v}"
        header_end = data.find(b"(\n")
        if data.startswith(b"#usda") and header_end >= 0:
            return data[: header_end + 2] + b"    " + key + b" = " + v.encode() + b"\n" + data[header_end + 2:], \
                f"add {key.decode()} = {v}"
    k = rng.randrange(len(data))
    return data[:k] + b"\x00" + data[k + 1:], f"NUL at {k}"


def mutate_bytes(rng: random.Random, data: bytes) -> tuple[bytes, str]:
    """One byte-level mutation of a .usdc crate file."""
    b = bytearray(data)
    op = rng.choice(["flip", "flip", "truncate", "zero", "dup", "ff"])
    if op == "flip":
        ks = [rng.randrange(len(b)) for _ in range(rng.randint(1, 8))]
        for k in ks:
            b[k] ^= 1 << rng.randrange(8)
        return bytes(b), f"flip bits at {ks}"
    if op == "truncate":
        k = rng.randrange(len(b))
        return bytes(b[:k]), f"truncate at {k}"
    k = rng.randrange(len(b))
    n = rng.randint(1, 64)
    if op == "zero":
        b[k: k + n] = bytes(len(b[k: k + n]))
        return bytes(b), f"zero {n} bytes at {k}"
    if op == "ff":
        b[k: k + n] = b"\xff" * len(b[k: k + n])
        return bytes(b), f"0xff {n} bytes at {k}"
    j = rng.randrange(len(b))
    return bytes(b[:k] + b[j: j + n] + b[k:]), f"copy {n} bytes from {j} to {k}"


def _nasty_value(rng: random.Random, type_name):
    """A value of USD type ``type_name`` (an Sdf.ValueTypeName), mostly at the edge of its range."""
    from pxr import Gf, Sdf, Vt

    x = lambda: float(rng.choice(NASTY_NUMBERS + ["0.3", "2", "-5", "10"]))  # noqa: E731
    t = type_name.scalarType
    n = rng.choice([0, 1, 2, 3, 4, 7, 100])
    name = str(t)
    if name in ("float", "double", "half"):
        s = x
    elif name in ("int", "uint", "int64", "uchar"):
        s = lambda: int(rng.choice([0, -1, 3, 4, 7, 2**31 - 1, -(2**31), 64, 4096]))  # noqa: E731
        if name == "uint":
            s = lambda: int(rng.choice([0, 3, 4, 7, 2**32 - 1, 64, 4096]))  # noqa: E731
    elif name == "bool":
        s = lambda: rng.random() < 0.5  # noqa: E731
    elif name in ("string", "token"):
        s = lambda: rng.choice(["", "640x360", "leftHanded", "faceVarying", "orthographic", "3", "nan"])  # noqa: E731
    elif name == "asset":
        s = lambda: Sdf.AssetPath(rng.choice(["/dev/zero", "./gone.png", ""]))  # noqa: E731
    elif name.startswith(("float2", "double2", "half2")):
        s = lambda: Gf.Vec2d(x(), x())  # noqa: E731
    elif name.startswith("int2"):
        s = lambda: Gf.Vec2i(rng.choice([0, -1, 32, 2**31 - 1]), rng.choice([0, 1, 32, 100000]))  # noqa: E731
    elif name.startswith("int3"):
        s = lambda: Gf.Vec3i(rng.choice([0, 3, -1]), 4, 5)  # noqa: E731
    elif name.startswith(("float3", "double3", "point3", "normal3", "color3", "vector3", "half3")):
        s = lambda: Gf.Vec3d(x(), x(), x())  # noqa: E731
    elif name.startswith("matrix4d"):
        s = lambda: Gf.Matrix4d(x())  # noqa: E731
    elif name.startswith("quat"):
        s = lambda: Gf.Quatd(x(), x(), x(), x())  # noqa: E731
    else:
        return None
    if type_name.isArray:
        if n == 100:
            one = s()
            return [one] * n
        return [s() for _ in range(n)]
    return s()


def mutate_attribute(rng: random.Random, seed: Path, out: Path) -> str:
    """One attribute-level mutation through pxr: a value at the edge of its range, a wrong type, a time
    sample, an xform op, a deactivated or invisible prim. Writes the stage to ``out``."""
    from pxr import Sdf, Usd, UsdGeom

    stage = Usd.Stage.Open(str(seed))
    prims = [p for p in stage.Traverse() if p.GetTypeName() not in ("Scope", "")]
    prim = rng.choice(prims)
    op = rng.choice(["value", "value", "retype", "retype", "sample", "xform", "active", "visibility", "new"])
    attrs = [a for a in prim.GetAttributes() if a.HasAuthoredValue() or a.GetName() in (
        "points", "normals", "faceVertexCounts", "faceVertexIndices", "clippingRange", "focalLength",
        "inputs:intensity", "inputs:exposure", "inputs:color", "inputs:ior", "resolution")]
    desc = ""
    if op == "xform":
        xf = UsdGeom.Xformable(prim) if prim.IsA(UsdGeom.Xformable) else None
        if xf:
            kind = rng.choice(["scale", "translate", "transform", "rotate"])
            v = float(rng.choice(["1e30", "1e20", "3.5e38", "0", "1e-30", "-1", "1e300", "nan"]))
            if kind == "scale":
                xf.AddScaleOp(UsdGeom.XformOp.PrecisionDouble, opSuffix="fuzz").Set((v, v, v))
            elif kind == "translate":
                xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble, opSuffix="fuzz").Set((v, 0.0, 0.0))
            elif kind == "rotate":
                xf.AddRotateXYZOp(UsdGeom.XformOp.PrecisionDouble, opSuffix="fuzz").Set((v, 0.0, 0.0))
            else:
                from pxr import Gf

                xf.AddTransformOp(opSuffix="fuzz").Set(Gf.Matrix4d(v))
            desc = f"xform {kind} {v} on {prim.GetPath()}"
    elif op == "active":
        prim.SetActive(False)
        desc = f"deactivate {prim.GetPath()}"
    elif op == "visibility":
        img = UsdGeom.Imageable(prim)
        if img:
            img.CreateVisibilityAttr().Set("invisible")
            img.CreatePurposeAttr().Set(rng.choice(["guide", "proxy", "render"]))
            desc = f"visibility/purpose on {prim.GetPath()}"
    elif op in ("value", "sample") and attrs:
        attr = rng.choice(attrs)
        v = _nasty_value(rng, attr.GetTypeName())
        if v is not None:
            try:
                if op == "sample":
                    attr.Set(v, Usd.TimeCode(rng.choice([0.0, 1.0, -5.0])))
                else:
                    attr.Set(v)
                desc = f"{op} {attr.GetPath()} = {str(v)[:60]}"
            except Exception as exc:  # noqa: BLE001 - pxr refuses some values: that case is just skipped
                desc = f"({op} refused by pxr: {type(exc).__name__})"
    elif op in ("retype", "new"):
        if op == "retype" and attrs:
            attr = rng.choice(attrs)
            name = attr.GetName()
            prim.RemoveProperty(name)
        else:
            name = rng.choice(["points", "faceVertexCounts", "normals", "primvars:displayColor", "clippingRange",
                               "inputs:intensity", "inputs:shaping:cone:angle", "cisp:water:resolution",
                               "cisp:water:wind_speed", "resolution", "focalLength", "inputs:ior"])
            if prim.GetAttribute(name):
                prim.RemoveProperty(name)
        tname = rng.choice(USD_TYPES).replace("[]", "[]")
        vt = Sdf.ValueTypeNames.Find(tname)
        if vt:
            new = prim.CreateAttribute(name, vt)
            v = _nasty_value(rng, vt)
            if v is not None:
                try:
                    new.Set(v)
                except Exception:  # noqa: BLE001
                    pass
            desc = f"{op} {prim.GetPath()}.{name} as {tname} = {str(v)[:60]}"
    if not desc:
        desc = f"(no-op on {prim.GetPath()})"
    stage.GetRootLayer().Export(str(out))
    return desc


def mutate_cli(rng: random.Random) -> tuple[list[str], str, str]:
    """(extra argv, description, the flag it exercises) of one bad or edge cisp-render number."""
    flag, values = rng.choice([
        ("--exposure", ["nan", "inf", "-inf", "1e6", "-1e6", "128", "1e300", "3", "-2"]),
        ("--frames", ["0:2000000000", "0:1", "-5:-3", "1e3:2", "0:100001", "nan:3", "0:2", "5:5", "3:1"]),
        ("--width", ["0", "-1", "100000", "1", "2147483647"]),
        ("--height", ["0", "-1", "100000", "1"]),
        ("--photons", ["0", "1", "1e12", "10000000000000", "nan", "1.5", "inf"]),
        ("--time", ["nan", "inf", "1e300", "-1e300", "3"]),
        ("--rsm-size", ["0", "1", "100000"]),
        ("--supersample", ["0", "-1", "3", "64", "100000"]),
        ("--seed", ["-1", "99999999999999999999", "3"]),
        ("--max-bounces", ["0", "1000000", "-1"]),
        ("--reference-photons", ["1e15", "0", "1"]),
        ("--cmap-history", ["0", "1000000000"]),
    ])
    v = rng.choice(values)
    return [f"{flag}={v}"], f"cli {flag}={v}", flag


# ------------------------------------------------------------------------------------------- one case


def plan_case(seed: int, index: int, seeds: list[Path]) -> dict:
    """The mutation plan of case ``index`` of run ``seed`` (deterministic; independent of --jobs)."""
    rng = random.Random(seed * 1_000_003 + index)
    src = rng.choice(seeds)
    if src.suffix == ".usdc":
        family = rng.choice(["bytes", "bytes", "attribute"])
    else:
        family = rng.choice(["text", "text", "text", "attribute", "attribute", "cli"])
    return {"id": index, "seed_stage": src.name, "family": family, "method": rng.choice(METHODS),
            "rng": rng.randrange(2**63)}


def prepare_case(case: dict, seeds_dir: Path, case_dir: Path) -> tuple[Path, list[str]]:
    """Write the mutated stage of ``case`` into ``case_dir``; returns (stage path, extra argv)."""
    rng = random.Random(case["rng"])
    src = seeds_dir / case["seed_stage"]
    for asset in seeds_dir.iterdir():  # images the stages name relative to themselves (sky domes)
        if asset.suffix.lower() not in (".usda", ".usdc", ".usd"):
            os.symlink(asset, case_dir / asset.name)
    family = case["family"]
    extra: list[str] = []
    if family == "text":
        stage = case_dir / ("stage" + src.suffix)
        data, desc = mutate_text(rng, src.read_bytes(), case_dir, stage.name)
        stage.write_bytes(data)
    elif family == "bytes":
        stage = case_dir / "stage.usdc"
        data, desc = mutate_bytes(rng, src.read_bytes())
        stage.write_bytes(data)
    elif family == "attribute":
        stage = case_dir / ("stage" + rng.choice([".usda", ".usdc"]))
        desc = mutate_attribute(rng, src, stage)
    else:
        stage = case_dir / src.name
        shutil.copy(src, stage)
        extra, desc, case["flag"] = mutate_cli(rng)
    case["mutation"] = desc
    return stage, extra


def base_argv(stage: Path, out: Path, method: str) -> list[str]:
    return [str(stage), "--out", str(out), "--device", "cpu", "--width", "32", "--height", "32",
            "--rsm-size", "32", "--photons", "2k", "--reference-photons", "8k", "--method", method,
            "--supersample", "1", "--aovs", "all", "--npy"]


def run_case_in_child(case: dict, seeds_dir: Path, case_dir: Path, result_path: Path) -> None:
    """Body of a worker: prepare the stage, run cisp-render's main, write the raw result as JSON."""
    import numpy as np

    from cisp_warp import cli

    res = {"stage_ok": False}
    try:
        stage, extra = prepare_case(case, seeds_dir, case_dir)
        res["stage_ok"] = True
        res["mutation"] = case.get("mutation")
        res["flag"] = case.get("flag")
        out = case_dir / "out"
        out.mkdir()
        (out / SENTINEL).write_text("written before the run\n")
        argv = base_argv(stage, out, case["method"]) + extra
        res["argv"] = argv
        res["stage"] = stage.name
        res["stage_size"] = stage.stat().st_size if stage.is_file() else 0
        _write(result_path, res)  # the plan survives a crash or hang of the run itself
        err = io.StringIO()
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            try:
                res["rc"] = cli.main(argv)
            except SystemExit as exc:  # argparse
                res["rc"] = exc.code if isinstance(exc.code, int) else 2
            except BaseException:  # noqa: BLE001 - exactly what the fuzzer looks for
                res["traceback"] = traceback.format_exc()[-3000:]
        res["stderr"] = err.getvalue()[-20000:]
        nonfinite, shapes = [], set()
        for f in sorted(out.glob("*.npy")):
            a = np.load(f)
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                nonfinite.append(f.name)
            if a.ndim >= 2:
                shapes.add(a.shape[:2])
        res["nonfinite"] = nonfinite
        res["shapes"] = sorted(shapes)
        res["final_png"] = (out / "final.png").exists() or any(out.glob("final.*.png"))
        res["sentinel_ok"] = (out / SENTINEL).is_file() and (out / SENTINEL).read_text() == "written before the run\n"
        res["out_files"] = sorted(p.name for p in out.iterdir())
    except BaseException:  # noqa: BLE001
        res["prepare_error" if not res["stage_ok"] else "traceback"] = traceback.format_exc()[-3000:]
    _write(result_path, res)


def _write(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, default=str))
    os.replace(tmp, path)


def classify(case: dict, res: dict | None, status: str) -> tuple[str, str]:
    """(outcome, message) from a worker's result and how it ended ('ok', 'hang', 'signal N', 'exit N')."""
    if status == "hang":
        return "hang", f"no answer within the deadline ({(res or {}).get('mutation')})"
    if res is None or "rc" not in res and "traceback" not in res:
        if res and res.get("prepare_error"):
            return "fuzzer_error", res["prepare_error"].strip().splitlines()[-1]
        return "crash", f"worker ended with {status} ({(res or {}).get('mutation')})"
    if "traceback" in res:
        return "traceback", res["traceback"].strip().splitlines()[-1]
    rc = res["rc"]
    stderr = res.get("stderr", "")
    errors = [line for line in stderr.splitlines() if line.startswith("cisp-render: error:") or "error:" in line]
    if rc != 0:
        message = errors[-1] if errors else stderr.strip()[-300:]
        named = res.get("stage", "\0") in message or (res.get("flag") and res["flag"] in message)
        if not res.get("sentinel_ok"):
            return "nonsense", f"a failing run changed --out: {res.get('out_files')}"
        return ("scene_error" if named else "error_no_file"), message
    if res.get("nonfinite"):
        return "nan_aov", f"non-finite AOVs: {', '.join(res['nonfinite'][:6])}"
    if not res.get("final_png"):
        return "nonsense", "exit 0 without final.png"
    if not res.get("sentinel_ok"):
        return "nonsense", "the run changed or deleted a file already in --out"
    want = (32, 32)
    for a in res.get("argv", []):
        if a.startswith(("--width=", "--height=")):
            want = None  # the CLI mutation changed the size
    if want and any(tuple(s) != want for s in res.get("shapes", [])):
        return "nonsense", f"asked for 32x32, AOVs of {res.get('shapes')}"
    return "rendered", ""


# ------------------------------------------------------------------------------------------ the driver


def _warm_up(seeds: list[Path], scratch: Path, smoke: bool) -> None:
    """Compile every kernel once in the parent (forked workers inherit the loaded modules)."""
    from cisp_warp import cli

    for method in METHODS:
        for name in ("small_water.usda",) if smoke else ("small_water.usda", "pool.usda"):
            src = next(s for s in seeds if s.name == name)
            out = scratch / f"warm_{method}_{name}"
            with redirect_stderr(io.StringIO()), redirect_stdout(io.StringIO()):
                rc = cli.main(base_argv(src, out, method))
            if rc != 0:
                raise SystemExit(f"fuzz_usd: the unmutated seed {src.name} does not render with {method}")
            shutil.rmtree(out, ignore_errors=True)


def _die_with_parent() -> None:
    """Linux: the worker is killed when the fuzzer dies, so no case outlives an interrupted run."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _vm_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def run(args) -> int:
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    import numpy  # noqa: F401  (loaded before forking)

    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix="fuzz_usd_", dir=args.tmp))
    seeds_dir = scratch / "seeds"
    seeds = build_seeds(seeds_dir, args.smoke)
    _warm_up(seeds, scratch, args.smoke)
    mem_cap = _vm_bytes() + args.memory_mb * 2**20
    ids = [args.only] if args.only is not None else list(range(args.cases))
    cases = [plan_case(args.seed, i, seeds) for i in ids]
    pending = list(cases)
    running: dict[int, tuple[dict, float, Path]] = {}
    results: list[dict] = []
    t_start = time.monotonic()
    last_report = t_start

    def finish(pid: int, status: str) -> None:
        case, t0, case_dir = running.pop(pid)
        res = None
        rp = case_dir / "result.json"
        if rp.exists():
            try:
                res = json.loads(rp.read_text())
            except ValueError:
                res = None
        outcome, message = classify(case, res, status)
        case.update(outcome=outcome, message=message[:1000], seconds=round(time.monotonic() - t0, 2),
                    mutation=(res or {}).get("mutation", case.get("mutation")), argv=(res or {}).get("argv"))
        results.append(case)
        if outcome in FAILURES or outcome == "fuzzer_error" or args.keep:
            keep = work / "failures" / f"{case['id']:06d}"
            if keep.exists():
                shutil.rmtree(keep)
            shutil.copytree(case_dir, keep, ignore=shutil.ignore_patterns("out", "pipe.usda", "big.usda"),
                            symlinks=True)
        for p in case_dir.glob("*"):  # FIFOs and folders are removed with the rest
            pass
        shutil.rmtree(case_dir, ignore_errors=True)
        if args.verbose or outcome in FAILURES:
            print(f"[{case['id']}] {outcome}: {case['seed_stage']} {case['method']} {case['mutation']} :: "
                  f"{message[:200]}", flush=True)

    def stop(signum, frame):  # an interrupted run takes its workers (and their process groups) with it
        for pid in list(running):
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        raise SystemExit(f"fuzz_usd: stopped by signal {signum} after {len(results)} cases")

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    while pending or running:
        while pending and len(running) < args.jobs:
            case = pending.pop(0)
            case_dir = scratch / f"case_{case['id']:06d}"
            case_dir.mkdir()
            pid = os.fork()
            if pid == 0:  # worker
                code = 0
                try:
                    _die_with_parent()
                    os.setpgid(0, 0)
                    resource.setrlimit(resource.RLIMIT_AS, (mem_cap, mem_cap))
                    fd = os.open(case_dir / "worker.log", os.O_WRONLY | os.O_CREAT, 0o644)
                    os.dup2(fd, 1)
                    os.dup2(fd, 2)
                    run_case_in_child(case, seeds_dir, case_dir, case_dir / "result.json")
                except BaseException:  # noqa: BLE001
                    code = 3
                os._exit(code)
            running[pid] = (case, time.monotonic(), case_dir)
        time.sleep(0.005)
        for pid in list(running):
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                if os.WIFSIGNALED(status):
                    finish(pid, f"signal {signal.Signals(os.WTERMSIG(status)).name}")
                else:
                    finish(pid, f"exit {os.WEXITSTATUS(status)}")
            elif time.monotonic() - running[pid][1] > args.deadline:
                try:
                    os.killpg(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                os.waitpid(pid, 0)
                finish(pid, "hang")
        if not args.quiet and time.monotonic() - last_report > 60:
            last_report = time.monotonic()
            counts = Counter(r["outcome"] for r in results)
            print(f"... {len(results)}/{len(cases)} cases in {last_report - t_start:.0f} s: "
                  + ", ".join(f"{k} {v}" for k, v in counts.most_common()), flush=True)

    elapsed = time.monotonic() - t_start
    shutil.rmtree(scratch, ignore_errors=True)
    results.sort(key=lambda r: r["id"])
    report = {"command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]), "seed": args.seed,
              "cases": len(results), "seconds": round(elapsed, 1), "jobs": args.jobs,
              "deadline_s": args.deadline, "memory_mb": args.memory_mb, "results": results}
    (work / "cases.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    print(table(results, elapsed))
    return 1 if any(r["outcome"] in FAILURES or r["outcome"] == "fuzzer_error" for r in results) else 0


def table(results: list[dict], elapsed: float) -> str:
    counts = Counter(r["outcome"] for r in results)
    lines = [f"| outcome over {len(results)} mutated stages (32x32, cpu, every method; {elapsed:.0f} s) | count |",
             "| --- | --- |"]
    names = {"rendered": "rendered, finite", "scene_error": "clean SceneError (names the file or flag)",
             "error_no_file": "error without the file or the prim", "nonsense": "rendered nonsense (detected)",
             "nan_aov": "NaN or Inf in an AOV", "traceback": "Python traceback", "crash": "worker crashed (signal)",
             "hang": "hang", "fuzzer_error": "fuzzer could not build the case"}
    for k in OUTCOMES + ("fuzzer_error",):
        if k in counts or k in OUTCOMES:
            lines.append(f"| {names[k]} | {counts.get(k, 0)} |")
    fam = defaultdict(Counter)
    for r in results:
        fam[r["family"]][r["outcome"]] += 1
    lines.append("")
    lines.append("| family | cases | " + " | ".join(OUTCOMES) + " |")
    lines.append("| --- | --- |" + " --- |" * len(OUTCOMES))
    for f in sorted(fam):
        lines.append(f"| {f} | {sum(fam[f].values())} | " + " | ".join(str(fam[f].get(o, 0)) for o in OUTCOMES) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="fuzz_usd.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=200, help="number of mutated stages (default 200)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the run: (seed, case id) reproduce a case")
    ap.add_argument("--jobs", type=int, default=1, help="workers at once (default 1)")
    ap.add_argument("--out", default="fuzz_out", help="folder for cases.json and the failing cases' stages")
    ap.add_argument("--deadline", type=float, default=60.0, help="seconds a case may take before it is a hang")
    ap.add_argument("--memory-mb", type=int, default=3072, help="memory a worker may add to the parent's [MiB]")
    ap.add_argument("--only", type=int, default=None, help="run only this case id (with the same --seed)")
    ap.add_argument("--smoke", action="store_true", help="seeds without the pool generator's variants (fast)")
    ap.add_argument("--keep", action="store_true", help="keep every case's stage, not only the failing ones")
    ap.add_argument("--tmp", default="/dev/shm" if os.path.isdir("/dev/shm") else None,
                    help="scratch folder (default: /dev/shm where it exists, else the system's)")
    ap.add_argument("--verbose", action="store_true", help="print every case")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    if not (1 <= args.cases <= 10**7 and 1 <= args.jobs <= 64 and args.deadline > 0 and args.memory_mb > 0):
        ap.error("--cases in [1, 1e7], --jobs in [1, 64], --deadline and --memory-mb positive")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
