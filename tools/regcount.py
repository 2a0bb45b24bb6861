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
    python tools/regcount.py --kernels trace_photons --local  # and where its local loads/stores are (nvdisasm)

``--local`` compiles with line info (``wp.config.lineinfo``) and attributes every local load and store (STL/LDL:
spills, and values merged through local memory, such as an IEEE division's fast and slow paths inside a branch) to
the Python lines it was inlined from and to the innermost SASS loop it lies in (docs/perf_notes.md section 44).
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


def compile_module(module_name, block_dim: int, arch: int, out_dir: Path, lineinfo: bool = False) -> Path:
    """``module_name``: a module's name, or a Warp module (a kernel's own, ``module="unique"``)."""
    import warp as wp

    if isinstance(module_name, str):
        module = importlib.import_module(module_name)
        options = wp.get_module(module.__name__).options
    else:
        module = module_name
        options = module.options
    options["block_dim"] = block_dim
    kept = options["lineinfo"]
    options["lineinfo"] = lineinfo  # a compile option of the module (a cubin of its own), restored after
    try:
        paths = wp.compile_aot_module(module, arch=arch, module_dir=out_dir, use_ptx=False)
    finally:
        options["lineinfo"] = kept
    return next(p for p in paths if p.suffix == ".cubin")


def _cuda_tool(name: str):
    """(path, environment) of a CUDA binary tool: on PATH or from the ``nvidia-cuda-*`` wheels; (None, None) if none."""
    import os
    import shutil

    tool = shutil.which(name)
    env = dict(os.environ)
    if tool is None:
        try:
            import nvidia

            for base in nvidia.__path__:
                for cand in Path(base).glob(f"*/bin/{name}"):
                    tool = str(cand)
                    env["PATH"] = f"{cand.parent}{os.pathsep}{env.get('PATH', '')}"
        except ImportError:
            pass
    return (tool, env) if tool else (None, None)


def local_memory(cubin: Path) -> dict[str, list[dict]] | None:
    """{kernel (Warp's hash and suffix removed): one dict per local load or store (``op`` STL/LDL, ``address``,
    ``loop``: the start address of the innermost backward branch's range holding it, or None; ``source``: the Python
    ``file:line`` it comes from, innermost inlined function first)} from ``nvdisasm -gi`` of a cubin compiled with
    line info; None without nvdisasm."""
    import subprocess

    tool, env = _cuda_tool("nvdisasm")
    if tool is None:
        return None
    text = subprocess.run([tool, "-gi", "-c", str(cubin)], capture_output=True, text=True, env=env).stdout
    kernels: dict[str, list] = {}
    insts = None
    labels: dict[str, int] = {}
    pending_labels: list[str] = []
    chain: list[str] = []
    in_chain = False
    for line in text.splitlines():
        m = re.match(r"//-+ \.text\.(\S+) ", line)
        if m:
            kernel = re.sub(r"_[0-9a-f]{8}_cuda_kernel_forward$", "", m.group(1))
            insts = kernels.setdefault(kernel, []) if kernel != m.group(1) else None
            labels, pending_labels = {}, []
            continue
        if insts is None:
            continue
        m = re.match(r"^(\.L_x_\d+):", line)
        if m:
            pending_labels.append(m.group(1))
            continue
        m = re.match(r"\s*//## File (.*)", line)
        if m:
            if not in_chain:
                chain = []
            in_chain = True
            chain += [f"{Path(f).name}:{n}" for f, n in re.findall(r'"([^"]*)", line (\d+)', m.group(1))
                      if f.endswith(".py")]
            continue
        m = re.match(r"\s*/\*([0-9a-f]+)\*/\s+(.*)", line)
        if m:
            in_chain = False
            address = int(m.group(1), 16)
            for label in pending_labels:
                labels[label] = address
            pending_labels = []
            branch = re.search(r"\bBRA\b[^;]*?(\.L_x_\d+)", m.group(2))
            insts.append((address, m.group(2), list(dict.fromkeys(chain)), branch.group(1) if branch else None,
                          labels))
    out = {}
    for kernel, insts in kernels.items():
        loops = []  # (start, end) of each backward branch's range
        for address, _, _, target, labels in insts:
            if target in labels and labels[target] < address:
                loops.append((labels[target], address))
        out[kernel] = []
        for address, inst, source, _, _ in insts:
            op = re.sub(r"^@!?U?P\w+\s+", "", inst).split()[0].split(".")[0]
            if op in ("STL", "LDL"):
                inner = [b for b, e in loops if b <= address <= e]
                # innermost: the latest start; the kernel's own grid-stride loop spans everything and counts as none
                inner = [b for b in inner if (b, max(e for bb, e in loops if bb == b)) != min(loops)] if inner else []
                out[kernel].append({"op": op, "address": address, "loop": max(inner) if inner else None,
                                    "source": source})
    return out


def print_local(kernel: str, ops: list[dict], top: int = 12) -> None:
    """Print a kernel's local loads and stores: the total, those in loops, and the most frequent (loop, source)."""
    from collections import Counter

    in_loops = sum(1 for o in ops if o["loop"] is not None)
    print(f"{'':>18} {kernel}: {len(ops)} local loads/stores, {in_loops} of them in loops")
    counts = Counter((o["loop"], " <- ".join(o["source"][:4])) for o in ops)
    for (loop, source), n in counts.most_common(top):
        where = f"loop {loop:#x}" if loop is not None else "no loop"
        print(f"{'':>20} {n:4d}  {where:<14} {source}")


def write_sass(cubin: Path, out: Path) -> bool:
    """The SASS of ``cubin`` into ``out`` with ``cuobjdump -sass`` (on PATH or from the ``nvidia-cuda-cuobjdump``
    wheel, which needs ``nvdisasm`` beside it: the ``nvidia-cuda-nvdisasm`` wheel); False if there is none."""
    import subprocess

    tool, env = _cuda_tool("cuobjdump")
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
    ap.add_argument("--local", action="store_true",
                    help="also where each kernel's local loads and stores are (line info; nvdisasm, if installed)")
    ap.add_argument("--top", type=int, default=12, help="with --local: how many (loop, source) rows a kernel prints")
    ap.add_argument("--projected", action="store_true",
                    help="also the trace compiled per projection (kernels_cisp.projected_trace: perspective and "
                         "orthographic light views, perspective camera, no flow), each a module of its own")
    args = ap.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    wp.init()
    words = [w for w in args.kernels.split(",") if w]
    block_of = dict(PHOTON_MODULES + FRAME_MODULES + DENOISE_MODULES)
    names = []
    for m in [m for m in args.modules.split(",") if m]:
        names += [d for d, _ in DENOISE_MODULES] if m == "denoise" else [m]
    units = [(name, name, block_of.get(name, 128)) for name in names]
    if args.projected:
        from cisp_warp.photons import kernels_cisp as K

        for lo in (0, 1):
            kernel = K.projected_trace(False, lo, 0)
            units.append((("light_ortho" if lo else "light_persp"), kernel.module, 128))
    print(f"sm_{args.arch}, Warp {wp.__version__}: registers per thread / stack frame bytes")
    with tempfile.TemporaryDirectory() as tmp:
        for name, module, block in units:
            cubin = compile_module(module, block, args.arch, Path(tmp) / name, lineinfo=args.local)
            local = local_memory(cubin) if args.local else None
            if args.local and local is None:
                print("no nvdisasm: local memory not attributed")
            if args.sass:
                Path(args.sass).mkdir(parents=True, exist_ok=True)
                if not write_sass(cubin, Path(args.sass) / f"{name}.sass"):
                    print("no cuobjdump: SASS not written")
            for kernel, u in sorted(kernel_usage(cubin).items()):
                if words and not any(w in kernel for w in words):
                    continue
                print(f"{name.rsplit('.', 1)[-1]:>18} {kernel:<32} {u.get('registers', 0):4d} regs "
                      f"{u.get('frame_bytes', 0):5d} B frame  (block {block})")
                if local is not None and kernel in local:
                    print_local(kernel, local[kernel], args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
