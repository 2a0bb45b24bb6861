"""Per-kernel table from bench_frame JSONs, side by side: python3 ksum.py [--key=graph_kernels] A.json B.json ..."""
import json
import sys


def rows(o, key):
    """Every bench_frame row (a dict with ``photons`` and ``key``) in a report."""
    if isinstance(o, dict):
        if key in o and "photons" in o:
            yield o
        for v in o.values():
            yield from rows(v, key)
    elif isinstance(o, list):
        for v in o:
            yield from rows(v, key)


def cell(ms, launches, width=17):
    return f"{ms:{width}.3f} ({launches:4.0f})"


def main(args):
    key = "kernels"
    tabs = []
    for f in args:
        if f.startswith("--key="):
            key = f[6:]
            continue
        with open(f) as fh:
            report = json.load(fh)
        tabs += [(f.split("/")[-1], row[key], row.get("graph_ms")) for row in rows(report, key)]
    names = sorted({k for _, t, _ in tabs for k in t}, key=lambda k: -max(t.get(k, (0, 0))[0] for _, t, _ in tabs))
    print("kernel".ljust(40) + "".join(n[:22].rjust(24) for n, _, _ in tabs))
    print("graph".ljust(40) + "".join(f"{g or float('nan'):24.3f}" for _, _, g in tabs))
    print("sum".ljust(40) + "".join(cell(sum(v[0] for v in t.values()), sum(v[1] for v in t.values())) for _, t, _ in tabs))
    for k in names:
        print(k[:40].ljust(40) + "".join(cell(*t.get(k, (0, 0))) for _, t, _ in tabs))


if __name__ == "__main__":
    main(sys.argv[1:])
