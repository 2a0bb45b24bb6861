"""Per-kernel table from bench_frame JSONs: python3 ksum.py A.json B.json ... (key: kernels or graph_kernels)."""
import json, sys
key = "kernels"
tabs = []
for f in sys.argv[1:]:
    if f.startswith("--key="):
        key = f[6:]; continue
    rep = json.load(open(f))
    def rows(o):
        if isinstance(o, dict):
            if key in o and "photons" in o:
                yield o
            for v in o.values():
                yield from rows(v)
        elif isinstance(o, list):
            for v in o:
                yield from rows(v)
    for row in rows(rep):
        tabs.append((f.split("/")[-1], row[key], row.get("graph_ms")))
names = sorted({k for _, t, _ in tabs for k in t}, key=lambda k: -max(t.get(k, (0, 0))[0] for _, t, _ in tabs))
print("kernel".ljust(40) + "".join(n[:22].rjust(24) for n, _, _ in tabs))
print("graph".ljust(40) + "".join(f"{g or float('nan'):24.3f}" for _, _, g in tabs))
print("sum".ljust(40) + "".join(f"{sum(v[0] for v in t.values()):17.3f} ({sum(v[1] for v in t.values()):4.0f})" for _, t, _ in tabs))
for k in names:
    print(k[:40].ljust(40) + "".join(f"{t.get(k, (0, 0))[0]:17.3f} ({t.get(k, (0, 0))[1]:4.0f})" for _, t, _ in tabs))
