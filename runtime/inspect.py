"""``mcdenoise inspect FILE...``: print the layers, statistics and metadata of frame files; and the
channel table the README and docs/render.md print (:func:`channel_table_markdown`). Apart from
the deployable core (runtime/frames.py holds the schema these read)."""
from __future__ import annotations

import json
import os

import numpy as np

from mcdenoise.runtime.frames import (PIXEL_LAYERS, SAMPLE_FEATURES, SAMPLE_FEATURES_DOC, SAMPLE_GROUPS, _channel_names,
                                      _open, read_meta)


def add_arguments(p):
    p.add_argument("files", nargs="+", help="frame EXR files")


def main(args) -> int:
    for path in args.files:
        print(describe(path))
    return 0


def describe(path: str | os.PathLike) -> str:
    """Human-readable summary of a frame file (``mcdenoise inspect``)."""
    path = os.fspath(path)
    f = _open(path)
    names = _channel_names(f)
    meta = read_meta(path)
    chans = f.channels()
    lines = [f"{path}"]
    first = chans[names[0]].pixels if names else None
    if first is not None:
        lines.append(f"  resolution: {first.shape[1]}x{first.shape[0]}, {len(names)} channels")
    groups: dict[str, list[str]] = {}
    n_samples = 0
    for n in names:
        head = n.split(".")[0]
        if head.startswith("sample") and head[6:].isdigit():
            n_samples = max(n_samples, int(head[6:]) + 1)
            continue
        groups.setdefault(head, []).append(n)
    lines.append("  pixel layers:")
    for g, chs in groups.items():
        arr = np.stack([chans[c].pixels.astype(np.float64) for c in chs])
        fin = np.isfinite(arr)
        lines.append(f"    {g:<10} {','.join(c.split('.', 1)[-1] for c in chs):<8} "
                     f"{str(chans[chs[0]].pixels.dtype):<8} min {np.min(arr[fin]) if fin.any() else float('nan'):.4g} "
                     f"mean {np.mean(arr[fin]) if fin.any() else float('nan'):.4g} "
                     f"max {np.max(arr[fin]) if fin.any() else float('nan'):.4g}"
                     + (f"  non-finite {int((~fin).sum())}" if not fin.all() else ""))
    if n_samples:
        lines.append(f"  per-sample layers: {n_samples} samples x {len(SAMPLE_FEATURES)} features "
                     f"(sample<i>.{{{', '.join(SAMPLE_GROUPS)}}})")
    if meta:
        lines.append("  metadata:")
        for k in sorted(meta):
            v = json.dumps(meta[k])
            lines.append(f"    {k}: {v if len(v) < 100 else v[:97] + '...'}")
    return "\n".join(lines)


def channel_table_markdown() -> str:
    """The channel documentation as a markdown table (the README's table is generated here)."""
    rows = ["| EXR channels | meaning | units / range | frame | on a miss |", "|---|---|---|---|---|"]
    for l in PIXEL_LAYERS:
        rows.append(f"| `{l.name}.{{{','.join(l.channels)}}}` | {l.meaning} | {l.units} | {l.frame} | {l.miss} |")
    groups: dict[str, list] = {}
    for name, *doc in SAMPLE_FEATURES_DOC:
        g = name.split(".")[0]
        if g in groups:
            groups[g][0].append(name.split(".", 1)[1])
        else:
            groups[g] = [[name.split(".", 1)[1]] if "." in name else [], *doc]
    for g, (chs, meaning, units, frame, miss) in groups.items():
        cs = f".{{{','.join(chs)}}}" if chs else ""
        rows.append(f"| `sample<i>.{g}{cs}` | {meaning} | {units} | {frame} | {miss} |")
    return "\n".join(rows)
