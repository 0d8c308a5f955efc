"""Median onnxruntime run() time of each ONNX file given, on one 1280x720 frame of synthetic WSKPN
inputs (colour, albedo, normal, depth), 2 intra-op threads, 2 untimed runs then 7 timed, the files
in the order given (list a file twice to see the drift). Graph only: no driver.

    python docs/results/int8/time_graphs.py FILE.onnx [FILE.onnx ...]
"""
import sys
import time

import numpy as np
import onnxruntime as ort

H, W = 720, 1280
rng = np.random.default_rng(0)
feed = {"color": rng.gamma(1, 0.5, (1, 3, H, W)).astype(np.float32),
        "albedo": rng.uniform(0, 1, (1, 3, H, W)).astype(np.float32),
        "normal": rng.uniform(-1, 1, (1, 3, H, W)).astype(np.float32),
        "depth": rng.uniform(1, 5, (1, 1, H, W)).astype(np.float32)}
for f in sys.argv[1:]:
    o = ort.SessionOptions()
    o.intra_op_num_threads = 2
    s = ort.InferenceSession(f, o, providers=["CPUExecutionProvider"])
    for _ in range(2):
        s.run(None, feed)
    ts = []
    for _ in range(7):
        t = time.perf_counter()
        s.run(None, feed)
        ts.append(time.perf_counter() - t)
    print(f"{f}: median {1000 * np.median(ts):.1f} ms", flush=True)
