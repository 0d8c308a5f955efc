"""``mcdenoise export RUN --out FILE.onnx``: a run folder -> a self-describing, checked ONNX file.

:func:`export_model` works on any spec + model (trained or freshly initialised), so tests and
benchmarks need no run folder; :func:`export_run` rebuilds the model from a run folder only
(:func:`training.runs.load_run`), and :func:`reexport` from an earlier export (its contract's
spec and its weights), so a graph change reaches shipped models whose run folder is gone.
Every export

1. traces ``model.deploy()`` with the TorchScript exporter (``dynamo=False``; fast, and the
   shared README's measurements favour its op choices) with dynamic N, H, W on every tensor;
   a TracerWarning (a shape baked in as a constant) is an error;
2. verifies every node name starts with ``/<stage>/`` of one of the spec's stages (the
   runtime splits profiler time by these prefixes);
3. writes the contract (:mod:`runtime.contract`) into ``metadata_props``, saves, and runs
   ``onnx.checker.check_model(path, full_check=True)``;
4. compares onnxruntime (float32) against the *training-form* torch model (eval mode,
   unfused) evaluated in float64, on inputs of a different size than the trace
   (:data:`CHECK_SIZE`, batch 2), for every output (:func:`parity_errors`).  The max relative
   error on non-dark values (:func:`parity_error`) must be <= :data:`PARITY_TOL`, or, where
   torch's own float32 result is further than that from float64, within
   :data:`FLOAT32_MARGIN` times torch float32's error: float32 cannot resolve a value that
   comes out of a cancellation (an untrained multi-resolution WSKPN's Eq. 7 turns ±30 terms
   into −0.01 here and there), and the export must not be blamed for that.  Both numbers are
   reported.

The file is written to a temporary name and moved into place only when all checks pass.
"""
from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mcdenoise.runtime.args import CommandError
from mcdenoise.runtime.contract import (FORMAT_VERSION, HISTORY, LAYOUT, SAMPLES_INPUT, SAMPLES_LAYOUT, Contract,
                              contract_metadata, node_prefix, parse_contract, state_input_name, state_output_name,
                              state_weight_name)
from mcdenoise.runtime.inputs import sample_group_channels
from mcdenoise.runtime.frames import PIXEL_LAYERS

DEFAULT_OPSET = 17
#: (H, W) of the traced example input, and of the parity check input (deliberately different,
#: not square, and a multiple of 4 neither in H nor in W).
EXPORT_SIZE = (64, 64)
CHECK_SIZE = (54, 78)
#: Samples per pixel of a per-sample model's traced input, and of its parity check input.
EXPORT_SPP, CHECK_SPP = 4, 3
#: Max relative error of the float32 graph vs torch float64, see :func:`parity_error`.
PARITY_TOL = 1e-4
#: ... or this many times torch float32's own error vs float64, if that is larger.  Two float32
#: evaluations that sum in different orders have the same bulk error but maxima (over the check's
#: ~25,000 elements) up to 3.5x apart: a fine-tuned anf-s failed at 2 with equal 99th
#: percentiles (docs/results/anf/parity_tail.txt). A wrong op errs by 1e-2 and more.
FLOAT32_MARGIN = 4.0
#: A value is "dark" when its magnitude is below this fraction of the tensor's mean magnitude;
#: there float32 rounding of sums of much larger values dominates any relative error, so its
#: error is measured relative to DARK_FRACTION·mean instead of to itself.
DARK_FRACTION = 1e-3
_LAYER_CHANNELS = {layer.name: len(layer.channels) for layer in PIXEL_LAYERS}


class ExportError(CommandError, RuntimeError):
    """An exported graph failed a check (stage prefixes, onnx checker, parity)."""


@dataclass
class ExportReport:
    """What :func:`export_model` wrote and measured."""

    path: Path
    opset: int
    nodes: int
    parity: dict[str, float] = field(default_factory=dict)
    torch_float32: dict[str, float] = field(default_factory=dict)
    check_size: tuple[int, int] = CHECK_SIZE
    seconds: float = 0.0

    @property
    def max_parity_error(self) -> float:
        return max(self.parity.values()) if self.parity else 0.0


def parity_error(test: np.ndarray, ref: np.ndarray, dark_fraction: float = DARK_FRACTION,
                 allow: float = 0.0) -> float:
    """Max over elements of max(|test − ref| − allow, 0) / max(|ref|, dark_fraction · mean|ref|).

    That is the max relative error on non-dark values (|ref| >= dark_fraction · mean|ref|), and
    on dark ones the absolute error relative to that floor; ``allow`` is an absolute error every
    element may have for free (:func:`parity_errors`: torch float32's own worst).  Inf/NaN
    anywhere gives inf.
    """
    test = np.asarray(test, np.float64)
    ref = np.asarray(ref, np.float64)
    if test.shape != ref.shape:
        raise ValueError(f"parity_error: shapes differ, {test.shape} vs {ref.shape}")
    if not (np.isfinite(test).all() and np.isfinite(ref).all()):
        return float("inf")
    floor = dark_fraction * float(np.mean(np.abs(ref)))
    denom = np.maximum(np.abs(ref), floor)
    denom = np.where(denom > 0, denom, 1.0)
    return float(np.max(np.maximum(np.abs(test - ref) - allow, 0.0) / denom))


def unstaged_nodes(graph, stages) -> list[str]:
    """Names of nodes of an ``onnx.GraphProto`` whose name lacks every ``/<stage>/`` prefix."""
    prefixes = tuple(node_prefix(s) for s in stages)
    return [f"{n.name or '<unnamed>'} ({n.op_type})" for n in graph.node if not n.name.startswith(prefixes)]


def tidy_graph(graph) -> None:
    """Remove the exporter's unscoped bookkeeping nodes from an ``onnx.GraphProto`` in place.

    * ``Constant`` nodes holding a tensor become initializers (no kernel runs for them; the
      TorchScript exporter emits some without a module scope, e.g. ReduceSum axes).
    * ``Identity`` nodes that copy an initializer are bypassed: the exporter inserts them when
      two parameters are bit-identical (e.g. two all-zero fused biases of an untrained model).
    """
    from onnx import numpy_helper

    inits = {i.name for i in graph.initializer}
    rename: dict[str, str] = {}
    keep = []
    for n in graph.node:
        if n.op_type == "Constant" and len(n.attribute) == 1 and n.attribute[0].name == "value":
            t = numpy_helper.from_array(numpy_helper.to_array(n.attribute[0].t), n.output[0])
            graph.initializer.append(t)
            inits.add(n.output[0])
            continue
        if n.op_type == "Identity" and n.input[0] in inits:
            rename[n.output[0]] = n.input[0]
            continue
        keep.append(n)
    outputs = {o.name for o in graph.output}
    if outputs & set(rename):
        raise ExportError(f"graph output(s) {sorted(outputs & set(rename))} are copies of parameters")
    del graph.node[:]
    for n in keep:
        for j, name in enumerate(n.input):
            if name in rename:
                n.input[j] = rename[name]
        graph.node.append(n)


def _stage_entry(model, stage: str) -> dict:
    """A contract stage: its name and node prefix."""
    return {"name": stage, "node_prefix": node_prefix(stage)}


def build_contract(spec, model, code_hash: str, export_info: dict | None = None) -> Contract:
    """The :class:`runtime.contract.Contract` of ``model`` built from ``spec``."""
    from mcdenoise.training.specs import spec_hash

    layers = set(spec.inputs.layers)
    state_in = {state_input_name(s.name): s for s in spec.state}
    weights = {state_weight_name(s.name) for s in spec.state if s.alpha}
    inputs = []
    for name in model.input_names:
        if name in layers:
            inputs.append({"name": name, "layer": name, "channels": _LAYER_CHANNELS[name], "layout": LAYOUT,
                           "transfer": "linear"})
        elif name in state_in:
            inputs.append({"name": name, "layer": None, "channels": state_in[name].channels,
                           "layout": LAYOUT, "transfer": "linear"})
        elif name == HISTORY:
            inputs.append({"name": name, "layer": None, "channels": 1, "layout": LAYOUT, "transfer": "linear"})
        elif name in weights:
            inputs.append({"name": name, "layer": None, "kind": "weight", "channels": 1, "layout": LAYOUT,
                           "transfer": "linear"})
        elif name == SAMPLES_INPUT:
            groups = [{"group": g, "channels": sample_group_channels(g), "transfer": t}
                      for g, t in spec.inputs.sample_groups]
            inputs.append({"name": name, "layer": None, "kind": "samples", "groups": groups,
                           "channels": sum(g["channels"] for g in groups), "layout": SAMPLES_LAYOUT,
                           "transfer": "linear"})
        elif name in {st.name for st in spec.setting}:
            continue                                   # a setting: KEY_SETTINGS, not an image input
        else:
            raise ValueError(f"model input {name!r} is neither a layer of the spec, a state input nor {HISTORY!r}")
    outputs = [{"name": model.output_names[0], "channels": 3, "layout": LAYOUT, "transfer": "linear"}]
    outputs += [{"name": state_output_name(s.name), "channels": s.channels, "layout": LAYOUT, "transfer": "linear"}
                for s in spec.state]
    return Contract(
        version=FORMAT_VERSION, spec_name=spec.name, model_type=spec.type, spec_toml=spec.raw,
        spec_hash=spec_hash(spec), code_hash=code_hash, inputs=tuple(inputs), outputs=tuple(outputs),
        stages=tuple(_stage_entry(model, s) for s in spec.stages),
        state=tuple({"name": s.name, "channels": s.channels, "input": state_input_name(s.name),
                     "output": state_output_name(s.name),
                     **({"weight_input": state_weight_name(s.name), "alpha": s.alpha, "history_spp": s.history_spp}
                        if s.alpha else {})} for s in spec.state),
        history=HISTORY if spec.state else "",
        accumulate=tuple({"layer": a.layer, "input": a.layer, "channels": _LAYER_CHANNELS[a.layer], "alpha": a.alpha,
                          **({"history_spp": a.history_spp} if a.history_spp else {})}
                         for a in spec.accumulate),
        settings=tuple({"name": st.name, "input": st.name, "default": st.default, "min": st.min, "max": st.max,
                        "step": st.step} for st in spec.setting),
        paper=dict(spec.paper), export=dict(export_info or {}))


def _torch_outputs(model, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
    import torch

    with torch.no_grad():
        outs = model(*[torch.from_numpy(feeds[n]) for n in model.input_names])
    return [o.numpy() for o in outs]


def parity_errors(model, run_graph, feeds: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """{output name: (graph error, torch float32 error)}, both :func:`parity_error` against
    ``model`` evaluated in float64 (a copy; ``model`` itself is untouched).  The graph's error
    counts only what exceeds torch float32's largest absolute error in that output: a signed
    output has elements near 0 where that much rounding is a large relative error, and which
    element lands there decided the test (ANF's affinity features at 7 spp on an AMD EPYC host:
    one element of 8,320 failed while the graph's largest absolute error was below torch's).

    run_graph: feeds (float32 arrays by input name) -> list of outputs in ``model.output_names``
    order, e.g. an onnxruntime session's ``run``.
    """
    import copy

    ref32 = _torch_outputs(model, feeds)
    ref64 = _torch_outputs(copy.deepcopy(model).double().eval(),
                           {k: v.astype(np.float64) if v.dtype == np.float32 else v for k, v in feeds.items()})
    got = run_graph(feeds)
    return {n: (parity_error(g, r64, allow=float(np.max(np.abs(np.asarray(r32, np.float64) - r64), initial=0.0))),
                parity_error(r32, r64))
            for n, g, r32, r64 in zip(model.output_names, got, ref32, ref64)}


def parity_ok(errors: dict[str, tuple[float, float]], tol: float = PARITY_TOL) -> bool:
    """Every output's graph error <= max(tol, FLOAT32_MARGIN · torch float32 error)."""
    return all(g <= max(tol, FLOAT32_MARGIN * t) for g, t in errors.values())




def export_model(spec, model, out_path: str | os.PathLike, opset: int = DEFAULT_OPSET, *,
                 code_hash: str | None = None, export_size: tuple[int, int] = EXPORT_SIZE,
                 check_size: tuple[int, int] = CHECK_SIZE, seed: int = 0,
                 tol: float = PARITY_TOL, info: dict | None = None) -> ExportReport:
    """Export ``model`` (built from ``spec``; trained or not) to ``out_path`` and check it
    (see the module docstring).  ``code_hash`` defaults to the current source tree's.  The
    model is evaluated in eval mode and handed back in the mode it came in.

    Raises ExportError when a check fails (nothing is left at ``out_path`` then).
    """
    import onnx
    import onnxruntime as ort
    import torch

    from mcdenoise.training.models import example_inputs
    from mcdenoise.training.runs import code_hash as current_code_hash

    if opset < 17:
        raise ValueError(f"opset must be >= 17 (AveragePool/ReduceMax semantics relied on), got {opset}")
    t0 = time.perf_counter()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".tmp")
    was_training = model.training
    model.eval()
    deployed = model.deploy() if hasattr(model, "deploy") else model
    feeds = example_inputs(deployed, 1, *export_size, seed=seed, spp=EXPORT_SPP)
    args = tuple(torch.from_numpy(feeds[n]) for n in deployed.input_names)
    settings = set(getattr(deployed, "settings", {}))
    weights = set(getattr(deployed, "state_weights", {}))       # (N, 1, 1, 1): only N varies
    axes = {n: {0: "N"} if n in weights else {0: "N", 2: "H", 3: "W"}
            for n in (*deployed.input_names, *deployed.output_names) if n not in settings}
    if SAMPLES_INPUT in axes:
        axes[SAMPLES_INPUT] = {0: "N", 1: "S", 3: "H", 4: "W"}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("error", torch.jit.TracerWarning)
            torch.onnx.export(deployed, args, str(tmp), dynamo=False, opset_version=opset,
                              input_names=list(deployed.input_names),
                              output_names=list(deployed.output_names),
                              dynamic_axes=axes, do_constant_folding=True)

        proto = onnx.load(str(tmp))
        tidy_graph(proto.graph)
        scripted = getattr(deployed, "scripted_stage", None)
        if scripted:
            # TorchScript functions (ANF's tap loop) export without a module scope: the model
            # names the one stage that calls them.
            for n in proto.graph.node:
                if not n.name.startswith(tuple(node_prefix(st) for st in spec.stages)):
                    n.name = node_prefix(scripted) + (n.name or n.op_type)
        # Shape inference loses the channel count through a Loop (ANF's taps): the spec knows it.
        channels = {model.output_names[0]: 3, **{state_output_name(st.name): st.channels for st in spec.state}}
        for o in proto.graph.output:
            dim = o.type.tensor_type.shape.dim
            if len(dim) == 4 and not dim[1].HasField("dim_value"):
                dim[1].dim_value = channels[o.name]
        bad = unstaged_nodes(proto.graph, spec.stages)
        if bad:
            raise ExportError(f"{spec.name}: {len(bad)} graph node(s) outside every stage "
                              f"{list(spec.stages)}, e.g. {bad[:5]}; move their ops into a stage module")

        check_feeds = example_inputs(model, 2, *check_size, seed=seed + 1, spp=CHECK_SPP)
        so = ort.SessionOptions()
        so.log_severity_level = 3
        sess = ort.InferenceSession(proto.SerializeToString(), so, providers=["CPUExecutionProvider"])
        errors = parity_errors(model, lambda f: sess.run(list(model.output_names), f), check_feeds)
        parity = {n: e[0] for n, e in errors.items()}
        if not parity_ok(errors, tol):
            raise ExportError(
                f"{spec.name}: onnxruntime differs from torch at {check_size[1]}x{check_size[0]}: max relative "
                f"error vs float64 {', '.join(f'{n} {g:.3g} (torch float32 {t:.3g})' for n, (g, t) in errors.items())}"
                f" > max({tol:g}, {FLOAT32_MARGIN:g}x torch float32) (dark: < {DARK_FRACTION:g}·mean)")

        info = {"opset": opset, "torch": torch.__version__, "onnx": onnx.__version__,
                "exporter": "torchscript", "export_size": list(export_size),
                "parity_size": list(check_size), "parity_max_rel_error": max(parity.values()),
                "parity_torch_float32_error": max(e[1] for e in errors.values()),
                **{k: v for k, v in (info or {}).items() if k == "protocol_from"}}
        contract = build_contract(spec, model, code_hash or current_code_hash(), info)
        meta = contract_metadata(contract)
        del proto.metadata_props[:]
        for k, v in meta.items():
            proto.metadata_props.add(key=k, value=v)
        proto.producer_name = "mcdenoise"
        proto.doc_string = f"mcdenoise {spec.name} ({spec.type}): {spec.description}"
        onnx.save(proto, str(tmp))
        onnx.checker.check_model(str(tmp), full_check=True)
        parse_contract({p.key: p.value for p in onnx.load(str(tmp), load_external_data=False).metadata_props})
        os.replace(tmp, out_path)
    finally:
        model.train(was_training)
        if tmp.exists():
            tmp.unlink()
    return ExportReport(path=out_path, opset=opset, nodes=len(proto.graph.node), parity=parity,
                        torch_float32={n: e[1] for n, e in errors.items()}, check_size=tuple(check_size), seconds=time.perf_counter() - t0)


def export_run(run_dir: str | os.PathLike, out_path: str | os.PathLike, opset: int = DEFAULT_OPSET) -> ExportReport:
    """Export the model of a run folder (spec + checkpoint, nothing else) to ``out_path``.

    The contract's code hash is the run's ``code_hash.txt`` (the code that trained it) when
    present, else the current tree's.
    """
    from mcdenoise.training import runs

    spec, model, _ = runs.load_run(run_dir)
    ch_file = Path(run_dir) / runs.CODE_HASH_FILE
    ch = ch_file.read_text().strip() if ch_file.exists() else None
    return export_model(spec, model, out_path, opset, code_hash=ch)


def load_exported(path: str | os.PathLike, spec=None):
    """(spec, model, contract) of an earlier export: the spec embedded in its contract (or
    ``spec``), built, with every parameter and buffer read from the initializer of the same name.

    Raises ExportError when a tensor of the model is missing or has another shape (an export
    whose constant folding merged it away, or a spec that changed its layers): that file can
    only be re-made from its run folder."""
    import onnx
    import torch
    from onnx import numpy_helper

    from mcdenoise.training.specs import build_model, parse_spec

    proto = onnx.load(str(path))
    contract = parse_contract({p.key: p.value for p in proto.metadata_props})
    spec = spec or parse_spec(contract.spec_toml, f"{path} (embedded spec)")
    model = build_model(spec)
    weights = {i.name: i for i in proto.graph.initializer}
    state = {}
    for name, tensor in model.state_dict().items():
        if name not in weights:
            raise ExportError(f"{path}: no initializer {name!r} for the model's tensor of that name (the "
                              f"export folded it into another): its weights are only in its run folder")
        value = numpy_helper.to_array(weights[name])
        if tuple(value.shape) != tuple(tensor.shape):
            raise ExportError(f"{path}: initializer {name!r} is {list(value.shape)}, the model's tensor "
                              f"{list(tensor.shape)}")
        state[name] = torch.from_numpy(value.copy()).to(tensor.dtype)
    model.load_state_dict(state)
    return spec, model, contract


def reexport(src: str | os.PathLike, out_path: str | os.PathLike, opset: int = DEFAULT_OPSET) -> ExportReport:
    """Export the model of an earlier export ``src`` again with the current graph code (the
    weights and the code hash that trained them carried over; see :func:`load_exported`)."""
    try:
        spec, model, contract = load_exported(src)
    except ExportError as e:
        raise ExportError(f"{e}; re-export it from its run folder (mcdenoise export RUN)") from None
    return export_model(spec, model, out_path, opset, code_hash=contract.code_hash)


def adopt_protocol(src: str | os.PathLike, out_path: str | os.PathLike, spec_path: str | os.PathLike) -> Contract:
    """Write the export ``src`` to ``out_path`` with the history weights of the spec at
    ``spec_path``: its ``[[accumulate]]`` entries (which of the graph's input layers the driver
    accumulates, and how) and its ``[[state]]`` ``alpha`` / ``history_spp``, rules of the
    driver. The spec must equal the file's embedded spec in everything else (params, inputs,
    stages, state, training; its name and comments aside), so the contract never describes a
    graph the file does not hold: an accumulated layer is fed under its own input name, so
    accumulating one more of the model's layers (albedo: docs/results/albedo-history) leaves
    the graph as it is. Where the graph's inputs stay the same (accumulations) the
    graph and weights are kept byte-equal; a state weight the model is now fed is a new graph
    input, so the model is exported again with the file's weights (:func:`load_exported`).
    The export info records the weights it was trained with.

    Raises ExportError naming what differs."""
    import onnx

    from mcdenoise.training.specs import build_model, load_spec, parse_spec

    proto = onnx.load(str(src))
    old = parse_contract({p.key: p.value for p in proto.metadata_props})
    was, new = parse_spec(old.spec_toml, f"{src} (embedded spec)"), load_spec(spec_path)

    def rest(spec) -> dict:
        d = spec.to_dict()
        for k in ("name", "description", "accumulate"):
            d.pop(k)
        d["state"] = [(s["name"], s["channels"]) for s in d["state"]]
        return d

    a, b = rest(was), rest(new)
    if a != b:
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        raise ExportError(f"{spec_path}: differs from {src}'s spec in {keys}, not only in its history "
                          "rules; export the model again from its run folder instead")

    def weights(spec) -> list:
        return ([{"layer": a.layer, "alpha": a.alpha, "history_spp": a.history_spp} for a in spec.accumulate]
                + [{"state": s.name, "alpha": s.alpha, "history_spp": s.history_spp} for s in spec.state if s.alpha])

    info = {**old.export, "protocol_from": {"spec": Path(spec_path).name, "weights": weights(new),
                                            "trained_with": old.export.get("protocol_from", {}).get(
                                                "trained_with", weights(was) or "its graph's fixed weights"),
                                            "trained_as": old.export.get("protocol_from", {}).get("trained_as", was.name)}}
    if new.input_names != was.input_names:
        try:
            _, model, _ = load_exported(src, new)
        except ExportError as e:
            raise ExportError(f"{e}; export the model again from its run folder instead") from None
        export_model(new, model, out_path, code_hash=old.code_hash, info=info)
        return parse_contract({p.key: p.value for p in onnx.load(str(out_path), load_external_data=False).metadata_props})
    contract = build_contract(new, build_model(new), old.code_hash, info)
    del proto.metadata_props[:]
    for k, v in contract_metadata(contract).items():
        proto.metadata_props.add(key=k, value=v)
    out_path = Path(out_path)
    tmp = out_path.with_name(out_path.name + ".tmp")
    onnx.save(proto, str(tmp))
    os.replace(tmp, out_path)
    return contract


def add_arguments(p) -> None:
    p.add_argument("run", metavar="RUN", help="run folder written by 'mcdenoise train', or an earlier "
                   "export (FILE.onnx) to export again with the current graph code and its weights")
    p.add_argument("--out", required=True, metavar="FILE.onnx", help="ONNX file to write")
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET,
                   help=f"ONNX opset, >= 17 (default {DEFAULT_OPSET})")
    p.add_argument("--protocol-from", default=None, metavar="SPEC",
                   help="with an earlier export as RUN: take only the history weights of SPEC (a spec otherwise "
                   "equal to the file's): metadata only for an accumulation; a state's fed weight is a new "
                   "graph input, so the model is exported again with the file's weights")


def main(args) -> int:
    if args.protocol_from:
        if not args.run.endswith(".onnx"):
            raise CommandError("--protocol-from takes an earlier export (FILE.onnx) as RUN")
        c = adopt_protocol(args.run, args.out, args.protocol_from)
        weights = ", ".join(f"{w.get('layer') or w.get('state')} alpha {w['alpha']:g} history_spp {w['history_spp']:g}"
                            for w in c.export["protocol_from"]["weights"])
        print(f"wrote {args.out}: {args.run} with the accumulation of {args.protocol_from} ({weights})")
        return 0
    rep = (reexport if Path(args.run).is_file() and args.run.endswith(".onnx") else export_run)(
        args.run, args.out, args.opset)
    print(f"wrote {rep.path} (opset {rep.opset}, {rep.nodes} nodes, {rep.seconds:.1f} s); "
          f"onnxruntime vs torch (float64) at {rep.check_size[1]}x{rep.check_size[0]}: max relative error "
          f"{rep.max_parity_error:.2e} (torch float32: {max(rep.torch_float32.values()):.2e}; "
          f"tolerance {PARITY_TOL:g})")
    return 0
