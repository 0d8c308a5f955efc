"""Per-stage timing: driver stages by wall clock, graph stages from onnxruntime's profiler.

The exported graph names its nodes ``/<stage>/...`` (the model's stage submodules).  With
profiling on, onnxruntime records every kernel's duration; :func:`graph_stage_times` sums
them per stage and per run.  onnxruntime's optimiser fuses nodes and inserts layout
reorders; a fused node keeps a name derived from its scoped output, and an unscoped
inserted node is charged to the stage of the node that ran just before it.

Stage names are defined once: graph stages come from the model's contract, driver stages
are :data:`DRIVER_STAGES`.
"""
from __future__ import annotations

import bisect
import json
import time
from contextlib import contextmanager

import numpy as np

#: Stages the driver runs itself, in the order they happen around the graph.
PREPROCESS, REPROJECT, POSTPROCESS, STATE_UPDATE = "preprocess", "reproject", "postprocess", "state update"
DRIVER_STAGES_BEFORE = (PREPROCESS, REPROJECT)
DRIVER_STAGES_AFTER = (POSTPROCESS, STATE_UPDATE)
#: Whole-frame wall time row, and the graph's wall time (what onnxruntime's run() took).
TOTAL, GRAPH = "total", "graph (wall)"


def cpu_name() -> str:
    """The CPU's model name and core count (for timing tables), or a generic label."""
    import os
    import platform

    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return f"{line.split(':', 1)[1].strip()} ({os.cpu_count()} cores)"
    except OSError:
        pass
    return platform.processor() or "CPU"


class FrameTimer:
    """Collects stage durations (ms) of one frame."""

    def __init__(self):
        self.ms: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.ms[name] = self.ms.get(name, 0.0) + 1e3 * (time.perf_counter() - t0)


def _profile_events(profile_path: str):
    with open(profile_path) as fh:
        events = json.load(fh)
    runs = sorted((e for e in events if e.get("name") == "model_run"), key=lambda e: e["ts"])
    nodes = sorted((e for e in events if e.get("cat") == "Node" and e.get("name", "").endswith("_kernel_time")),
                   key=lambda e: e["ts"])
    return runs, nodes, [e["ts"] for e in nodes]


def _attributed(nodes, keys, start: float, end: float, stages: list[str]):
    """(node event, stage) for the kernels that ran within [start, end], in order: a node named
    ``/<stage>/...`` belongs to that stage, any other to the stage of the node before it.
    A kernel that runs inside another's span (the body of a ``Loop``, ANF's taps) is left out:
    the enclosing node's time already holds it.  ``keys``: the nodes' start times (sorted)."""
    current = stages[0] if stages else None
    busy_until = -1.0
    for e in nodes[bisect.bisect_left(keys, start):]:
        if e["ts"] > end:
            break
        if e["ts"] + e["dur"] <= busy_until:
            continue
        busy_until = e["ts"] + e["dur"]
        name = e["name"]
        for s in stages:
            if name.startswith(f"/{s}/"):
                current = s
                break
        yield e, current


def graph_stage_times(profile_path: str, stages: list[str]) -> list[dict[str, float]]:
    """Per-run {stage: ms} from an onnxruntime profile JSON file (one dict per ``run()``)."""
    runs, nodes, keys = _profile_events(profile_path)
    out = []
    for r in runs:
        per = {s: 0.0 for s in stages}
        for e, stage in _attributed(nodes, keys, r["ts"], r["ts"] + r["dur"], stages):
            if stage is not None:
                per[stage] += e["dur"] / 1e3
        out.append(per)
    return out


def node_stages(profile_path: str, stages: list[str]) -> list[tuple[str, str, str | None]]:
    """(kernel name, op type, stage) of every kernel of the profile's first run, as
    :func:`graph_stage_times` charges them (what a test checks after graph changes: a fusion
    can rename a node into the next stage's scope)."""
    runs, nodes, keys = _profile_events(profile_path)
    if not runs:
        return []
    r = runs[0]
    return [(e["name"][:-len("_kernel_time")], e.get("args", {}).get("op_name", ""), stage)
            for e, stage in _attributed(nodes, keys, r["ts"], r["ts"] + r["dur"], stages)]


def paper_key(stage: str) -> str | None:
    """Key of a spec's ``[paper]`` table for a stage row.  The papers' totals time the network
    alone (prediction + reconstruction), so they sit beside the graph's wall time, not beside
    our whole-frame total that also counts the driver's stages."""
    if stage == TOTAL:
        return None
    if stage == GRAPH:
        return "total_ms"
    return stage.replace(" ", "_") + "_ms"


def medians(rows: list[dict[str, float]]) -> dict[str, float]:
    """Median per key over frames (keys missing in a row count as absent, not 0)."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    return {k: float(np.median([r[k] for r in rows if k in r])) for k in keys}


def format_table(ours: dict[str, float], stages: list[str], paper: dict | None, resolution: str,
                 title: str, n_frames: int, device: str) -> str:
    """A Table-3-shaped text table: stage | ours (median ms) | paper (ms on its GPU)."""
    paper = paper or {}
    pdev = paper.get("device", "")
    pres = paper.get("resolution", "")
    lines = [title,
             f"median over {n_frames} frame{'' if n_frames == 1 else 's'} at {resolution} on {device}; paper: {pdev} at {pres}".rstrip(),
             f"{'stage':<20}{'ours ms':>12}{'paper ms':>12}", "-" * 44]
    for s in stages + [GRAPH, TOTAL]:
        if s not in ours:
            continue
        key = paper_key(s)
        p = paper.get(key) if key else None
        pstr = f"{p:>12.2f}" if isinstance(p, (int, float)) else f"{'-':>12}"
        if s in (GRAPH, TOTAL):
            lines.append("-" * 44)
        lines.append(f"{s:<20}{ours[s]:>12.2f}{pstr}")
    return "\n".join(lines)
