"""Run a model's last stage in bands of rows, each band on a one-thread onnxruntime session.

WSKPN's reconstruction (Eq. 3-5 on the boxsum path) is about fifty per-pixel operations and
box filters.  onnxruntime runs each over the whole frame, so at 1280x720 every one is a trip
through memory (its 4-channel tensors are 15 MB), and its two threads meet at every one of
them.  Run on bands of :data:`BAND_ROWS` rows (plus the stage's halo above and below, so every
kept row sees the same window as in the whole frame), the tensors of a band stay in the
core's cache, and two threads each run their own bands on one-thread sessions.  Measured at
1280x720 on this project's 2-core machine, wskpn-3 with random inputs (one-off script, paired
runs): reconstruction alone 69-71 ms whole, 48-50 ms in 40-64-row bands on two threads;
prediction plus banded reconstruction 209-210 ms against 219-222 ms for the whole graph,
the copies into bands included.  The result is the same to the bit: every kept row is
computed from the same values by the same kernels.

A model declares a stage bandable in its contract (``"halo"``: rows of context each side,
written at export by a model that knows its stage is row-local); :mod:`runtime.graphcut`
cuts the graph before it.  Frames below :data:`MIN_PIXELS` run whole.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from mcdenoise.runtime import graphcut, workers

#: Rows per band: 40-64 were equally fast at 1280x720 (a band's tensors then fit a core's
#: 2 MB L2 cache); shorter bands pay more halo and more per-run overhead.
BAND_ROWS = 40
#: Frames with fewer pixels run the whole graph in one session: its tensors fit the caches
#: anyway.  wskpn-3, whole frame, banded vs whole (paired runs): 256x256 26.0 vs 24.9 ms,
#: 640x360 74.7 vs 74.4, 960x540 160.8 vs 164.6.
MIN_PIXELS = 1 << 18


class BandedStage:
    """The graph cut before its last stage: ``head`` runs on the caller's session options,
    the stage runs band by band on ``threads`` workers with one-thread sessions.

    Build with :meth:`build` (None when the model cannot be banded)."""

    def __init__(self, head, tail, cut: graphcut.Cut, stage: str, head_stage: str, halo: int,
                 out_channels: dict[str, int], threads: int):
        self.head, self.tail, self.cut = head, tail, cut
        self.stage, self.head_stage, self.halo = stage, head_stage, int(halo)
        self.threads = max(1, int(threads))
        self.head_inputs = [i.name for i in head.get_inputs()]
        self.head_outputs = [o.name for o in head.get_outputs()]
        self.tail_outputs = [o.name for o in tail.get_outputs()]
        self.out_channels = out_channels
        #: Per worker, reused band input buffers by (input, shape): a fresh array per band
        #: costs its page faults (1280x720: 10.8 ms of copies on two threads, 4.7 reused).
        self._buffers: list[dict] = [{} for _ in range(self.threads)]

    @classmethod
    def build(cls, model_bytes: bytes, contract, make_session: Callable, threads: int) -> "BandedStage | None":
        """The banded form of the contract's last stage when it declares a ``halo`` and
        exactly one stage runs before it; None otherwise.

        make_session(model bytes, intra-op threads or None for the caller's) -> session.
        Raises graphcut.GraphCutError when the graph cannot be cut there.
        """
        stages = list(contract.stages)
        if len(stages) != 2 or not isinstance(stages[-1].get("halo"), int) or stages[-1]["halo"] < 0:
            return None
        last = stages[-1]
        cut = graphcut.cut_before_stage(model_bytes, last["node_prefix"])
        head = make_session(cut.head, None)
        types = {o.name: (o.type, o.shape) for o in head.get_outputs()}
        tail = make_session(graphcut.tail_model(cut, types), 1)
        channels = {o["name"]: o["channels"] for o in contract.outputs}
        if any(o.name not in channels for o in tail.get_outputs()):
            return None
        return cls(head, tail, cut, last["name"], stages[0]["name"], last["halo"], channels, threads)

    def applies(self, h: int, w: int) -> bool:
        return h * w >= MIN_PIXELS and h > BAND_ROWS

    def run(self, feeds: dict[str, np.ndarray], rows: int | None = None
            ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Run the graph on ``feeds`` (the whole graph's inputs, (N, C, H, W) float32) with
        the stage in bands of ``rows`` rows: ({output name: array}, {head stage: ms, banded
        stage: ms}) by wall clock.  ``rows`` defaults to :data:`BAND_ROWS`."""
        rows = rows or BAND_ROWS
        t0 = time.perf_counter()
        outs = dict(zip(self.head_outputs, self.head.run(self.head_outputs,
                                                          {n: feeds[n] for n in self.head_inputs})))
        t1 = time.perf_counter()
        src = {n: outs[n] if n in outs else feeds[n] for n in self.cut.tail_inputs}
        first = next(iter(src.values()))
        n, _, h, w = first.shape
        if any(a.ndim != 4 or a.shape[0] != n or a.shape[2] != h for a in src.values()):
            raise ValueError(f"stage {self.stage!r}: inputs are not (N, C, H, W) with one H: "
                             f"{ {k: a.shape for k, a in src.items()} }")
        dst = {o: np.empty((n, self.out_channels[o], h, w), np.float32) for o in self.tail_outputs}
        bands = [(r0, min(h, r0 + rows)) for r0 in range(0, h, rows)]
        groups = [bands[i * len(bands) // self.threads:(i + 1) * len(bands) // self.threads]
                  for i in range(self.threads)]

        def work(i):
            buffers = self._buffers[i]
            for r0, r1 in groups[i]:
                a, b = max(0, r0 - self.halo), min(h, r1 + self.halo)
                band = {}
                for k, v in src.items():
                    buf = buffers.get((k, v.shape[:2], b - a, w))
                    if buf is None or buf.dtype != v.dtype:
                        if len(buffers) > 4 * len(src):      # sizes changed: drop the old ones
                            buffers.clear()
                        buf = buffers[(k, v.shape[:2], b - a, w)] = np.empty((*v.shape[:2], b - a, w), v.dtype)
                    np.copyto(buf, v[:, :, a:b])
                    band[k] = buf
                res = self.tail.run(self.tail_outputs, band)
                for name, r in zip(self.tail_outputs, res):
                    if r.shape[1] != dst[name].shape[1]:
                        raise ValueError(f"stage {self.stage!r} output {name!r} has {r.shape[1]} channels, "
                                         f"the contract says {dst[name].shape[1]}")
                    dst[name][:, :, r0:r1] = r[:, :, r0 - a:r1 - a]

        pool = workers.executor(self.threads)
        futures = [pool.submit(work, i) for i in range(1, self.threads) if groups[i]] if pool else []
        try:
            work(0)
        finally:
            for f in futures:
                f.result()
        t2 = time.perf_counter()
        outs.update(dst)
        return outs, {self.head_stage: 1e3 * (t1 - t0), self.stage: 1e3 * (t2 - t1)}
