"""Peak memory of one method denoising a few frames, each method in a fresh process.

A process's peak resident set (Linux: ``VmHWM`` in ``/proc/self/status``) is the number that
sees onnxruntime's and Open Image Denoise's own allocations (``tracemalloc`` sees Python's
only), and only a fresh process gives one method's peak alone. (``getrusage``'s ``ru_maxrss``
is the fallback elsewhere; on Linux it keeps the peak of the process that forked the child
across ``exec``, so a child of a big test process reported that process's size.)  The frames are built first and the method
loaded; ``base_mb`` is the peak then, ``peak_mb`` the peak after denoising, and ``added_mb``
their difference: what denoising adds on top of the frames it is given (the driver's buffers,
its kept state, the graph's working memory).

``python -m mcdenoise.training.memory METHOD WxH [--frames N] [--spp S] [--threads T]`` prints
the result as one JSON line; :func:`peak_memory` runs it.  The measuring side only: the
runtime itself never starts a process.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys


def _maxrss_mb() -> float:
    """This process's peak resident set so far, in MiB."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0          # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # KiB on Linux


def measure(method: str, w: int, h: int, frames: int = 3, spp: int = 0, threads: int = 0) -> dict:
    """In this process: {"base_mb", "peak_mb", "added_mb"} of ``method`` (an .onnx path or a
    built-in method name, :func:`training.methods.load_method`) on ``frames`` synthetic frames
    of w x h (with ``spp`` per-sample features when > 0).  Meaningful only in a fresh process
    (the peak is the process's)."""
    from mcdenoise.training.harness import synthetic_frame
    from mcdenoise.training.methods import load_method

    seq = [synthetic_frame(w, h, t, 0, spp) for t in range(frames)]
    m = load_method(method, threads=threads)
    base = _maxrss_mb()
    for fr in seq:
        m(fr)
    peak = _maxrss_mb()
    return {"base_mb": round(base, 1), "peak_mb": round(peak, 1), "added_mb": round(peak - base, 1)}


def peak_memory(method: str, w: int, h: int, frames: int = 3, spp: int = 0, threads: int = 0,
                timeout_s: float = 600.0) -> dict:
    """:func:`measure` in a fresh Python process; raises RuntimeError with the child's last
    error line when it fails."""
    cmd = [sys.executable, "-m", "mcdenoise.training.memory", method, f"{w}x{h}", "--frames", str(frames),
           "--spp", str(spp), "--threads", str(threads)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"peak memory of {method} at {w}x{h}: {last}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    from mcdenoise.runtime.args import parse_size

    p = argparse.ArgumentParser(prog="python -m mcdenoise.training.memory", description=__doc__.split("\n\n")[0])
    p.add_argument("method", help="an .onnx file or a built-in method (noisy, oidn-high, oidn-fast, svgf)")
    p.add_argument("size", type=parse_size, metavar="WxH")
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--spp", type=int, default=0, help="per-sample features per pixel (per-sample models)")
    p.add_argument("--threads", type=int, default=0)
    a = p.parse_args(argv)
    print(json.dumps(measure(a.method, *a.size, frames=a.frames, spp=a.spp, threads=a.threads)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
