"""The temporal prelude as an onnxruntime graph (exported by ``mcdenoise.export.prelude`` from
the torch path of :func:`runtime.temporal.reproject`): the same arithmetic the driver runs in
numpy, for a provider that keeps frames on its device. :class:`PreludeGraph` has the call
signature of ``reproject``, so :meth:`runtime.temporal.Protocol.follow` takes it as is."""
from __future__ import annotations

import numpy as np

from mcdenoise.runtime import data_path
from mcdenoise.runtime.temporal import reproject

#: Graph inputs and outputs, in order (see mcdenoise.export.prelude).
INPUTS = ("prev", "current", "alpha", "blend", "motion", "cur_depth", "cur_position", "cur_normal",
          "prev_depth", "prev_position", "prev_normal")
OUTPUTS = ("warped", "history")
#: The shipped prelude graph.
SHIPPED = data_path("models", "driver", "prelude.onnx")


class PreludeGraph:
    """``reproject(states, motion, cur, prev, blend=...)`` run by onnxruntime on ``providers``.
    Frames without world positions or normals (the graph tests both) go to the numpy path."""

    def __init__(self, path=SHIPPED, providers=None, threads: int = 0):
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.log_severity_level = 3
        if threads:
            so.intra_op_num_threads = threads
        self.session = ort.InferenceSession(str(path), so, providers=providers or ["CPUExecutionProvider"])

    def __call__(self, states, motion, cur: dict, prev: dict, blend=None, threads: int = 1):
        guides = ("depth", "position", "normal")
        if not all(g in cur and g in prev for g in guides):
            return reproject(states, motion, cur, prev, threads=threads, blend=blend)
        blend = list(blend) if blend is not None else [None] * len(states)
        ch = [s.shape[1] for s in states]
        current = [np.zeros_like(s) if b is None else b[0] for s, b in zip(states, blend)]
        alpha = np.concatenate([np.full(c, 0.0 if b is None else b[1], np.float32) for c, b in zip(ch, blend)])
        mask = np.concatenate([np.full(c, 0.0 if b is None else 1.0, np.float32) for c, b in zip(ch, blend)])
        feeds = {"prev": np.concatenate(states, axis=1), "current": np.concatenate(current, axis=1),
                 "alpha": alpha.reshape(1, -1, 1, 1), "blend": mask.reshape(1, -1, 1, 1), "motion": motion,
                 **{f"cur_{g}": cur[g] for g in guides}, **{f"prev_{g}": prev[g] for g in guides}}
        warped, history = self.session.run(list(OUTPUTS), {k: np.ascontiguousarray(v, np.float32) for k, v in feeds.items()})
        return list(np.split(warped, np.cumsum(ch)[:-1], axis=1)), history
