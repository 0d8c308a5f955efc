"""Graph time at 1280x720 of untrained wskpn-3-aa variants with a cheaper prediction network
(issue 15: wskpn-3 under a third of Open Image Denoise fast's time; issue 17's AMX ratio).

Each variant is models_spec/wskpn-3-aa.toml with [params] overridden, built untrained (time does
not depend on the weights), exported with mcdenoise's exporter to OUT/<name>.onnx, then every
graph is timed in onnxruntime (2 intra-op threads, the same synthetic 720p frame), in ROUNDS
interleaved rounds of 5 runs after 2 untimed, so machine drift hits all alike; the median per
graph over all rounds is printed with onnxruntime's per-stage profile (prediction, reconstruction).

    python docs/results/cheap-wskpn/time_variants.py OUT [ROUNDS [VARIANT...]]

VARIANT names pick a subset (the first one named is the ratio's base).
"""
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from mcdenoise.export.onnx_export import export_model
from mcdenoise.training.curves import spec_variant
from mcdenoise.training.specs import SPEC_DIR, build_model, parse_spec
from mcdenoise.runtime.timing import graph_stage_times

#: name -> [params] overrides of wskpn-3-aa (blocks 3, widths [16], conv 5)
VARIANTS = {
    "k5-w16-b3 (shipped)": {},
    "k3-w16-b3": {"conv": 3},
    "k3-w12-b3": {"conv": 3, "widths": [12]},
    "k3-w8-b3": {"conv": 3, "widths": [8]},
    "k3-w16-b4": {"conv": 3, "blocks": 4},
    "k3-w12-b4": {"conv": 3, "widths": [12], "blocks": 4},
    "k3-w8-b4": {"conv": 3, "widths": [8], "blocks": 4},
    "k5-w12-b3": {"widths": [12]},
    "k5-w8-b3": {"widths": [8]},
    # fewer kernel sizes (each is a pool over four channels and four elementwise passes)
    "k3-w16-b4-s5": {"conv": 3, "blocks": 4, "kernel_sizes": [3, 5, 7, 9, 13]},
    "k3-w16-b4-s4": {"conv": 3, "blocks": 4, "kernel_sizes": [3, 5, 9, 13]},
    "k3-w16-b4-s3": {"conv": 3, "blocks": 4, "kernel_sizes": [3, 7, 13]},
}
H, W = 720, 1280


def spec_text(over: dict) -> str:
    """wskpn-3-aa's spec with ``over`` set in [params] (the curves command's own rewrite)."""
    text = (SPEC_DIR / "wskpn-3-aa.toml").read_text()
    for k, v in over.items():
        text = spec_variant(text, k, json.dumps(v))
    return text


def profiled_stages(path: Path, feed: dict) -> dict[str, float]:
    """Median over 3 profiled runs of each stage's kernel time (ms)."""
    o = ort.SessionOptions()
    o.intra_op_num_threads = 2
    o.enable_profiling = True
    o.profile_file_prefix = str(Path(tempfile.mkdtemp()) / "p")
    s = ort.InferenceSession(str(path), o, providers=["CPUExecutionProvider"])
    for _ in range(4):
        s.run(None, feed)
    runs = graph_stage_times(s.end_profiling(), ["prediction", "reconstruction"])[1:]
    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def main(out: Path, rounds: int, names: list[str]):
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        sys.exit(f"unknown variant(s) {unknown}; known: {list(VARIANTS)}")
    for name in names or list(VARIANTS):
        over = VARIANTS[name]
        spec = parse_spec(spec_text(over), f"<wskpn-3-aa {name}>")
        torch.manual_seed(0)
        model = build_model(spec)
        path = out / (name.split(" ")[0] + ".onnx")
        export_model(spec, model, path)
        files[name] = path
    rng = np.random.default_rng(0)
    sess0 = ort.InferenceSession(str(next(iter(files.values()))), providers=["CPUExecutionProvider"])
    feed = {}
    for i in sess0.get_inputs():
        shape = [1 if d == "N" else H if d == "H" else W if d == "W" else d for d in i.shape]
        feed[i.name] = rng.uniform(0.05, 1, shape).astype(np.float32)
    sessions = {}
    for name, path in files.items():
        o = ort.SessionOptions()
        o.intra_op_num_threads = 2
        s = ort.InferenceSession(str(path), o, providers=["CPUExecutionProvider"])
        f = {i.name: feed[i.name] for i in s.get_inputs()}
        for _ in range(2):
            s.run(None, f)
        sessions[name] = (s, f)
    times = {n: [] for n in files}
    for _ in range(rounds):
        for name, (s, f) in sessions.items():
            for _ in range(5):
                t = time.perf_counter()
                s.run(None, f)
                times[name].append(time.perf_counter() - t)
    base = np.median(times[next(iter(files))])
    print(f"| variant | params | graph ms 1280x720 (median of {5 * rounds}) | x shipped | prediction ms | reconstruction ms |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, path in files.items():
        stages = profiled_stages(path, sessions[name][1])
        n_params = sum(p.numel() for p in build_model(parse_spec(spec_text(VARIANTS[name]))).deploy().parameters())
        med = np.median(times[name])
        print(f"| {name} | {n_params:,} | {1000 * med:.1f} | {med / base:.2f} | "
              f"{stages.get('prediction', float('nan')):.1f} | {stages.get('reconstruction', float('nan')):.1f} |", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 3, sys.argv[3:])
