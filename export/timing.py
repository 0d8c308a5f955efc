"""Export-side timing: kernel-application paths and whole graphs, onnxruntime vs torch eager.

    python -m export.timing                          # everything below, 2 threads
    python -m export.timing --what kernels --sizes 256x256
    python -m export.timing --what models --specs wskpn-3 --repeats 9
    python -m export.timing --what models --specs anf-s --sizes 256x256 --spp 1 2 4 8

``kernels``: WSKPN's reconstruction (six fused kernels 3..13 on a 3-channel image) with the
"unfold" reference path vs the "boxsum" path, each exported alone.  ``models``: the deployed
graph of each spec (random initialisation, deterministic seed), plus the per-stage split of
the onnxruntime time from its profiler (node names ``/<stage>/``); a per-sample model at each
``--spp`` (its embedding should grow linearly in S, nothing after the average should move).  Reported: the median of
``--repeats`` runs after ``--warmup`` runs, in milliseconds; nothing is asserted.
This is the command behind the timings quoted for the kernel path choice.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import warnings

import numpy as np

from mcdenoise.runtime.args import parse_size


def _median_ms(fn, warmup: int, repeats: int) -> float:
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(ts)


def _session(path: str, threads: int, profile: bool = False):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    if profile:
        so.enable_profiling = True
        so.profile_file_prefix = os.path.join(tempfile.mkdtemp(prefix="mcdenoise-timing-"), "ort")
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])


def stage_split_ms(path: str, feeds: dict, stages, threads: int, runs: int = 3) -> dict[str, float]:
    """Median per-stage onnxruntime kernel time (ms) over ``runs`` profiled runs after one
    warm-up, split by :func:`runtime.timing.graph_stage_times` (the runtime's own rule)."""
    from mcdenoise.runtime.timing import graph_stage_times

    sess = _session(path, threads, profile=True)
    for _ in range(runs + 1):
        sess.run(None, feeds)
    per_run = graph_stage_times(sess.end_profiling(), list(stages))[1:]
    return {k: statistics.median(r[k] for r in per_run) for k in per_run[0]} if per_run else {}


def time_kernels(size: tuple[int, int], threads: int, warmup: int, repeats: int,
                 kernel_sizes=(3, 5, 7, 9, 11, 13)) -> dict[str, float]:
    """ms of WSKPN kernel application + fusion (:func:`training.models.wskpn.fuse_kernels`) at
    ``size`` (W, H): {"<path> ort": ms, "<path> torch": ms}."""
    import torch

    from mcdenoise.training.models.wskpn import fuse_kernels

    w, h = size
    m = len(kernel_sizes)
    rng = np.random.default_rng(0)
    feeds = {"x": rng.exponential(1.0, (1, 3, h, w)).astype(np.float32),
             "importance": rng.normal(0, 2, (1, m, h, w)).astype(np.float32),
             "logits": rng.normal(0, 1, (1, m, h, w)).astype(np.float32)}
    out = {}
    for path in ("boxsum", "unfold"):
        class Op(torch.nn.Module):
            def forward(self, x, importance, logits, _path=path):
                return fuse_kernels(x, importance, logits, kernel_sizes, _path)

        op = Op()
        with tempfile.TemporaryDirectory() as d:
            f = os.path.join(d, f"{path}.onnx")
            small = {k: v[..., :32, :32] for k, v in feeds.items()}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                torch.onnx.export(op, tuple(torch.from_numpy(v) for v in small.values()), f, dynamo=False,
                                  opset_version=17, input_names=list(feeds), output_names=["out"],
                                  dynamic_axes={k: {0: "N", 2: "H", 3: "W"} for k in [*feeds, "out"]})
            sess = _session(f, threads)
            reps = repeats if path == "boxsum" or w * h <= 256 * 256 else max(3, repeats // 3)
            out[f"{path} ort"] = _median_ms(lambda: sess.run(None, feeds), warmup, reps)
        args = [torch.from_numpy(v) for v in feeds.values()]
        with torch.no_grad():
            out[f"{path} torch"] = _median_ms(lambda: op(*args), warmup, reps)
    return out


def time_model(spec_name: str, size: tuple[int, int], threads: int, warmup: int, repeats: int,
               stages: bool = True, spp: int = 4) -> dict[str, float]:
    """ms of the deployed graph of ``spec_name`` at ``size`` (W, H): {"ort": ms, "torch": ms,
    "ort <stage>": ms...}.  Exported with :func:`export.onnx_export.export_model` (all checks)."""
    import torch

    from mcdenoise.export.onnx_export import export_model
    from mcdenoise.training.models import example_inputs
    from mcdenoise.training.specs import build_model, load_spec

    spec = load_spec(spec_name)
    torch.manual_seed(0)
    model = build_model(spec).eval()
    w, h = size
    res = {}
    with tempfile.TemporaryDirectory() as d:
        f = os.path.join(d, "model.onnx")
        export_model(spec, model, f)
        feeds = example_inputs(model, 1, h, w, seed=0, spp=spp)
        sess = _session(f, threads)
        res["ort"] = _median_ms(lambda: sess.run(None, feeds), warmup, repeats)
        if stages:
            for k, v in stage_split_ms(f, feeds, spec.stages, threads).items():
                res[f"ort {k}"] = v
    deployed = model.deploy()
    args = [torch.from_numpy(feeds[n]) for n in deployed.input_names]
    with torch.no_grad():
        res["torch"] = _median_ms(lambda: deployed(*args), warmup, repeats)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m export.timing", description=__doc__.split("\n\n")[0])
    p.add_argument("--what", choices=("kernels", "models", "all"), default="all")
    p.add_argument("--sizes", nargs="+", type=parse_size, default=[(256, 256), (1280, 720)], metavar="WxH")
    p.add_argument("--specs", nargs="+", default=None, help="specs to time (default: all)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--spp", type=int, nargs="+", default=[4], help="samples per pixel of per-sample models")
    a = p.parse_args(argv)
    import torch

    torch.set_num_threads(a.threads)
    import onnxruntime

    print(f"torch {torch.__version__}, onnxruntime {onnxruntime.__version__}, {a.threads} threads, "
          f"median of {a.repeats} runs after {a.warmup} warm-up (unfold at >256²: fewer runs)")
    if a.what in ("kernels", "all"):
        for size in a.sizes:
            r = time_kernels(size, a.threads, a.warmup, a.repeats)
            print(f"kernels {size[0]}x{size[1]}: " + ", ".join(f"{k} {v:.1f} ms" for k, v in r.items()), flush=True)
    if a.what in ("models", "all"):
        from mcdenoise.training.specs import list_specs

        from mcdenoise.training.specs import load_spec

        for name in a.specs or list_specs():
            for size in a.sizes:
                for spp in a.spp if load_spec(name).inputs.samples else [None]:
                    r = time_model(name, size, a.threads, a.warmup, a.repeats, spp=spp or 4)
                    print(f"{name} {size[0]}x{size[1]}{f' {spp} spp' if spp else ''}: "
                          + ", ".join(f"{k} {v:.1f} ms" for k, v in r.items()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
