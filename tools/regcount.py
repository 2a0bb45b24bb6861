"""Registers per thread of the photon kernels on a GPU architecture, without a GPU.

Warp compiles each module ahead of time (``wp.compile_aot_module``) to a cubin for ``--arch`` (default 90, the
H100/H200) with its own NVRTC, at the block size the kernels are launched with, and this reads the cubin's
``.nv.info`` attributes: registers (EIATTR_REGCOUNT) and the stack frame (EIATTR_FRAME_SIZE, local memory a thread
needs: spills and arrays kept off registers). These are the numbers the device would load, since the driver runs the
same compiler's cubin.

    python tools/regcount.py                      # the photon kernels (cisp, sspm, reference, caustics_map, wavefront)
    python tools/regcount.py --kernels trace_sspm  # only kernels whose name contains one of these words
    python tools/regcount.py --modules cisp_warp.shade,cisp_warp.raster.kernels  # any module (blocks as launched)
    python tools/regcount.py --modules denoise    # the denoisers' kernels (DENOISE_MODULES)
    python tools/regcount.py --modules denoise --sass out/   # also each module's SASS (cuobjdump, if installed)
"""

from __future__ import annotations

import argparse
import importlib
import re
import struct
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # this checkout's cisp_warp, not whichever one is installed

EIATTR_FRAME_SIZE = 0x11
EIATTR_REGCOUNT = 0x2F
EIFMT_NVAL, EIFMT_BVAL, EIFMT_HVAL, EIFMT_SVAL = 1, 2, 3, 4

#: (module, threads per block it is launched with)
PHOTON_MODULES = (
    ("cisp_warp.photons.kernels_cisp", 128),
    ("cisp_warp.photons.kernels_world", 128),
    ("cisp_warp.photons.kernels_cmap", 128),
    ("cisp_warp.photons.kernels_wavefront", 128),
)
#: other modules of the frame (``--modules`` names them; plain ``wp.launch`` blocks of 256)
FRAME_MODULES = (
    ("cisp_warp.photons.common", 128),
    ("cisp_warp.raster.kernels", 256),
    ("cisp_warp.shade", 256),
)
#: the denoisers (``--modules denoise``), with the blocks their tiled kernels are launched with
DENOISE_MODULES = (
    ("cisp_warp.denoise.kernels_caustic", 256),
    ("cisp_warp.denoise.kernels_atrous", 512),
    ("cisp_warp.denoise.kernels_atrous_pixel", 256),
    ("cisp_warp.denoise.kernels_svgf", 256),
    ("cisp_warp.denoise.gather", 256),
)


def _sections(elf: bytes):
    """{name: bytes} of an ELF64 little-endian file, and its symbol names by index."""
    (shoff,) = struct.unpack_from("<Q", elf, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", elf, 0x3A)
    heads = [struct.unpack_from("<IIQQQQIIQQ", elf, shoff + i * shentsize) for i in range(shnum)]
    names_off = heads[shstrndx][4]

    def cstr(off: int) -> str:
        return elf[off:elf.index(b"\0", off)].decode()

    sections = {cstr(names_off + h[0]): (h, elf[h[4]:h[4] + h[5]]) for h in heads}
    symtab_head, symtab = sections[".symtab"]
    strtab = heads[symtab_head[6]][4]  # sh_link: the symbols' string table
    symbols = [cstr(strtab + struct.unpack_from("<I", symtab, i)[0]) for i in range(0, len(symtab), 24)]
    return {k: v[1] for k, v in sections.items()}, symbols


def resource_usage(cubin: Path) -> dict[str, dict[str, int]]:
    """{kernel symbol: {"registers": n, "frame_bytes": n}} from a cubin's .nv.info sections."""
    sections, symbols = _sections(cubin.read_bytes())
    usage: dict[str, dict[str, int]] = {}
    for name, data in sections.items():
        if not name.startswith(".nv.info"):
            continue
        i = 0
        while i + 4 <= len(data):
            fmt, attr, size = data[i], data[i + 1], struct.unpack_from("<H", data, i + 2)[0]
            if fmt == EIFMT_SVAL:
                payload = data[i + 4:i + 4 + size]
                if attr in (EIATTR_REGCOUNT, EIATTR_FRAME_SIZE) and size == 8:
                    sym, value = struct.unpack("<II", payload)
                    key = "registers" if attr == EIATTR_REGCOUNT else "frame_bytes"
                    usage.setdefault(symbols[sym], {})[key] = value
                i += 4 + size
            else:
                i += 4
    return usage


def kernel_usage(cubin: Path) -> dict[str, dict[str, int]]:
    """{kernel name (Warp's hash and suffix removed): usage} of the forward kernels in ``cubin``."""
    out = {}
    for symbol, u in resource_usage(cubin).items():
        kernel = re.sub(r"_[0-9a-f]{8}_cuda_kernel_forward$", "", symbol)
        if kernel != symbol:
            out[kernel] = u
    return out


def compile_module(module_name: str, block_dim: int, arch: int, out_dir: Path) -> Path:
    import warp as wp

    module = importlib.import_module(module_name)
    wp.get_module(module.__name__).options["block_dim"] = block_dim
    paths = wp.compile_aot_module(module, arch=arch, module_dir=out_dir, use_ptx=False)
    return next(p for p in paths if p.suffix == ".cubin")


def write_sass(cubin: Path, out: Path) -> bool:
    """The SASS of ``cubin`` into ``out`` with ``cuobjdump -sass`` (on PATH or from the ``nvidia-cuda-cuobjdump``
    wheel, which needs ``nvdisasm`` beside it: the ``nvidia-cuda-nvdisasm`` wheel); False if there is none."""
    import os
    import shutil
    import subprocess

    tool = shutil.which("cuobjdump")
    env = dict(os.environ)
    if tool is None:
        try:
            import nvidia

            for base in nvidia.__path__:
                for cand in Path(base).glob("*/bin/cuobjdump"):
                    tool = str(cand)
                    env["PATH"] = f"{cand.parent}{os.pathsep}{env.get('PATH', '')}"
        except ImportError:
            pass
    if tool is None:
        return False
    res = subprocess.run([tool, "-sass", str(cubin)], capture_output=True, text=True, env=env)
    out.write_text(res.stdout + res.stderr)
    return res.returncode == 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arch", type=int, default=90, help="SM architecture (90: H100/H200)")
    ap.add_argument("--modules", default=",".join(m for m, _ in PHOTON_MODULES),
                    help="comma-separated module names (blocks as in PHOTON_MODULES / FRAME_MODULES, else 128)")
    ap.add_argument("--kernels", default="", help="comma-separated words; only kernels whose name contains one")
    ap.add_argument("--sass", default="", help="folder: write each module's SASS there (MODULE.sass)")
    args = ap.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    wp.init()
    words = [w for w in args.kernels.split(",") if w]
    block_of = dict(PHOTON_MODULES + FRAME_MODULES + DENOISE_MODULES)
    names = []
    for m in [m for m in args.modules.split(",") if m]:
        names += [d for d, _ in DENOISE_MODULES] if m == "denoise" else [m]
    print(f"sm_{args.arch}, Warp {wp.__version__}: registers per thread / stack frame bytes")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            block = block_of.get(name, 128)
            cubin = compile_module(name, block, args.arch, Path(tmp) / name)
            if args.sass:
                Path(args.sass).mkdir(parents=True, exist_ok=True)
                if not write_sass(cubin, Path(args.sass) / f"{name}.sass"):
                    print("no cuobjdump: SASS not written")
            for kernel, u in sorted(kernel_usage(cubin).items()):
                if words and not any(w in kernel for w in words):
                    continue
                print(f"{name.rsplit('.', 1)[-1]:>18} {kernel:<32} {u.get('registers', 0):4d} regs "
                      f"{u.get('frame_bytes', 0):5d} B frame  (block {block})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
