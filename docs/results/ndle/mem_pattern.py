"""ndle-s's graph alone at 1280x720 x 8 spp on one thread, three runs in one session, with
onnxruntime's memory pattern on (its default) or off: the process's peak resident set above
the input after each run, and each run's time. What made the driver turn the pattern off for
per-sample models (models/ndle-s.md, runtime/denoiser.py). Run each mode in a fresh process:

    python docs/results/ndle/mem_pattern.py default
    python docs/results/ndle/mem_pattern.py nopattern
"""
import sys
import time

import numpy as np
import onnxruntime as ort

from mcdenoise.training.memory import _maxrss_mb

mode = sys.argv[1]
so = ort.SessionOptions()
so.log_severity_level = 3
so.intra_op_num_threads = 1
so.enable_mem_pattern = mode != "nopattern"
s = ort.InferenceSession("models/ndle-s.onnx", so, providers=["CPUExecutionProvider"])
inp = s.get_inputs()[0]
x = np.random.default_rng(0).random((1, 8, inp.shape[2], 720, 1280), dtype=np.float32)
base = _maxrss_mb()
for k in range(3):
    t = time.time()
    s.run(None, {inp.name: x})
    print(f"{mode} run {k}: added {_maxrss_mb() - base:.0f} MB, {time.time() - t:.1f} s", flush=True)
