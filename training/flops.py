"""FLOP / FMA and parameter counts of an ONNX graph at a concrete resolution.

    from mcdenoise.training.flops import count_flops
    c = count_flops("models/wskpn-3.onnx", 1280, 720)
    c.flops, c.fmas, c.params, c.per_stage["prediction"]["flops"]

The graph's dynamic dimensions are bound (N = 1, H, W from the first 4-D input's named
dims) and ONNX shape inference (with data propagation) gives every tensor a concrete shape;
tensors whose size depends on values it cannot propagate (NBG's grid sizes) get theirs from
one onnxruntime run on zero inputs.  Each node is then counted from its input and output shapes.  Needs the ``onnx`` package
(``pip install onnx``; the [train] extra has it), imported only when counting, so the runtime
driver itself stays numpy + onnxruntime.

Counting rules (``out`` = elements of the node's first output, ``in`` = elements of its
first input; a FLOP is one float add, multiply, compare, divide or transcendental; an FMA
is one multiply-add and counts as 2 FLOPs):

* ``Conv``: FMAs = N * Cout * Hout * Wout * (Cin / groups) * kh * kw (any number of spatial
  axes); + ``out`` FLOPs for the bias if present.  ``ConvTranspose``: FMAs =
  N * Cin * Hin * Win * (Cout / groups) * kh * kw, + bias as for Conv.
* ``MatMul``: FMAs = (batch elements of the output) * M * N * K.  ``Gemm``: M * N * K FMAs,
  + M * N FLOPs for C, + M * N for alpha/beta when they are not 1.  ``Einsum``: FMAs = the
  product of every index's size (one multiply-add per point of the index space).
* Elementwise ops (:data:`ELEMENTWISE`: arithmetic, comparisons, activations, ``Exp``, ``Pow``,
  ``Clip``, ``Where``...): 1 FLOP per output element; transcendentals count as 1 too.
* ``BatchNormalization`` (inference): 2 per element (scale and shift after folding).
  ``InstanceNormalization`` / ``LayerNormalization``: 5 per element (mean, variance, normalise,
  scale, shift; an approximation).  ``Softmax`` / ``LogSoftmax``: 5 per element (max,
  subtract, exp, sum, divide).
* Pooling (``AveragePool``, ``MaxPool``, ``LpPool``): ``out`` * window size (kh * kw: the
  window's adds or compares; the average's divide is counted in the window).  Global pooling:
  ``in``.
* Reductions (``ReduceSum``, ``ReduceMax``, ``ReduceMean``...), ``CumSum``: ``in`` (one op per
  input element).
* ``Resize``: nearest 0; linear / cubic 2 * 2^k - 1 per output element for k resized axes (a
  2^k-tap weighted sum).  ``GridSample``: bilinear 7 per output element, nearest 0.
* ``ScatterND`` / ``ScatterElements``: 0 without a reduction, else 1 per update element.
* Data movement and shape ops (:data:`FREE`: Slice, Concat, Reshape, Transpose, Gather, Pad,
  Cast, Shape...): 0.
* Anything else is *not counted*: listed in :attr:`FlopCount.uncounted`, never silently 0.
* Control flow (``Loop``, ``If``, ``Scan``; ANF's taps are a ``Loop`` over kernel_size² taps
  with an ``If`` that skips the centre): the nodes inside are counted by the rules above, once
  per execution, from one profiled onnxruntime run of the bound graph on zero inputs with the
  run-time settings at their defaults (or ``settings``). That is how many times each body runs
  and which branch each ``If`` takes, with the shapes it ran at; the cost goes to the stage of
  the top-level node that holds the body. Where a body's value decides a branch, zero inputs
  decide it (ANF's branches depend only on the tap index). A profiled run at 720p costs
  minutes (anf-s: 100 s here), so above :data:`PROFILE_PIXELS` the run is made at the two
  smallest sizes of the frame's aspect (W/d x H/d, d dividing both) and a node's count is
  carried to the full size only where it is the same at both (a scalar's) or grows exactly with
  the pixel count; as a cost bilinear in H and W is a quadratic in d, that holds at every size.
  Anything else is counted at the full size.

Parameters: elements of the floating-point initializers that feed a weight input of
``Conv``, ``ConvTranspose``, ``Gemm``, ``MatMul``, ``Einsum``, the normalisations or ``PRelu``
(scalar and shape constants are not parameters); :attr:`FlopCount.constants` counts every
other float initializer element.

Stages: a node belongs to stage ``s`` when its name starts with ``/<s>/`` (the exporter's
scopes, as in :func:`runtime.timing.graph_stage_times`); other nodes go to :data:`OTHER`.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

#: Stage of nodes whose name carries no ``/<stage>/`` prefix.
OTHER = "other"

ELEMENTWISE = frozenset({
    "Add", "Sub", "Mul", "Div", "Pow", "Exp", "Log", "Sqrt", "Reciprocal", "Neg", "Abs", "Sign",
    "Relu", "LeakyRelu", "PRelu", "Elu", "Selu", "Celu", "Gelu", "Sigmoid", "HardSigmoid",
    "HardSwish", "Tanh", "Softplus", "Softsign", "Mish", "Erf", "Sin", "Cos", "Tan", "Atan",
    "Floor", "Ceil", "Round", "Clip", "Min", "Max", "Mean", "Sum", "Where", "Equal", "Less",
    "LessOrEqual", "Greater", "GreaterOrEqual", "Not", "And", "Or", "Xor", "IsNaN", "IsInf",
    "Mod", "ThresholdedRelu", "Shrink",
})
FREE = frozenset({
    "Slice", "Concat", "Reshape", "Transpose", "Gather", "GatherElements", "GatherND", "Pad",
    "Cast", "CastLike", "Shape", "Size", "Identity", "Unsqueeze", "Squeeze", "Flatten", "Expand",
    "Split", "Constant", "ConstantOfShape", "Range", "Tile",
    "DepthToSpace", "SpaceToDepth", "Dropout", "NonZero", "TopK", "ArgMax", "ArgMin", "Trilu",
    "EyeLike", "OneHot",
})
REDUCE = frozenset({"ReduceSum", "ReduceMax", "ReduceMin", "ReduceMean", "ReduceProd",
                    "ReduceL1", "ReduceL2", "ReduceLogSumExp", "ReduceSumSquare", "CumSum"})
POOL = frozenset({"AveragePool", "MaxPool", "LpPool"})
GLOBAL_POOL = frozenset({"GlobalAveragePool", "GlobalMaxPool", "GlobalLpPool"})
#: op -> input positions that hold weights (for the parameter count).
WEIGHT_INPUTS = {"Conv": (1, 2), "ConvTranspose": (1, 2), "Gemm": (0, 1, 2), "MatMul": (0, 1),
                 "Einsum": None, "BatchNormalization": (1, 2, 3, 4),
                 "InstanceNormalization": (1, 2), "LayerNormalization": (1, 2), "PRelu": (1,)}
_FLOAT_TYPES = {1, 10, 11, 16}  # FLOAT, FLOAT16, DOUBLE, BFLOAT16


@dataclass
class FlopCount:
    """Counts for one graph at one resolution (see the module docstring for the rules)."""

    width: int
    height: int
    flops: int = 0
    fmas: int = 0
    params: int = 0
    constants: int = 0
    per_stage: dict = field(default_factory=dict)   # stage -> {"flops", "fmas", "nodes"}
    per_op: dict = field(default_factory=dict)      # op type -> {"flops", "fmas", "nodes"}
    per_node: list = field(default_factory=list)    # (node name, op type, stage, flops, fmas)
    uncounted: dict = field(default_factory=dict)   # op type -> node count

    @property
    def gflops(self) -> float:
        return self.flops / 1e9


def _load(model):
    import onnx

    if isinstance(model, (str, os.PathLike)):
        return onnx.load(os.fspath(model))
    return model


def _bind_inputs(model, width: int, height: int, batch: int = 1):
    """A copy of ``model`` with every dynamic input dim bound: the last two dims of 4-D
    inputs to (H, W), any other named or unknown dim to ``batch``."""
    import onnx

    m = onnx.ModelProto()
    m.CopyFrom(model)
    init = {i.name for i in m.graph.initializer}
    for inp in m.graph.input:
        if inp.name in init:
            continue
        dims = inp.type.tensor_type.shape.dim
        rank = len(dims)
        for k, d in enumerate(dims):
            if d.HasField("dim_value") and d.dim_value > 0:
                continue
            if rank >= 3 and k == rank - 2:
                d.dim_value = height
            elif rank >= 3 and k == rank - 1:
                d.dim_value = width
            else:
                d.dim_value = batch
    return m


def _shapes(model) -> dict[str, tuple]:
    import onnx

    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=False, data_prop=True)
    shapes: dict[str, tuple] = {}
    for vi in list(inferred.graph.input) + list(inferred.graph.value_info) + list(inferred.graph.output):
        t = vi.type.tensor_type
        if not t.HasField("shape"):
            continue
        dims = []
        for d in t.shape.dim:
            if d.HasField("dim_value"):
                dims.append(int(d.dim_value))
            else:
                dims = None
                break
        if dims is not None:
            shapes[vi.name] = tuple(dims)
    for i in model.graph.initializer:
        shapes[i.name] = tuple(int(d) for d in i.dims)
    missing = [o for n in model.graph.node for o in n.output if o and o not in shapes]
    if missing:
        shapes.update(_run_shapes(model, missing))
    return shapes


def _zero_feeds(model, settings: dict | None = None) -> dict:
    """Zeros for every graph input of the bound ``model`` (not its initializers), of its shape and
    type; the int64 scalar ``settings`` (input name -> value) instead where given."""
    import onnx

    feeds = {}
    init = {i.name for i in model.graph.initializer}
    for inp in model.graph.input:
        if inp.name in init:
            continue
        t = inp.type.tensor_type
        dt = onnx.helper.tensor_dtype_to_np_dtype(t.elem_type)
        feeds[inp.name] = (np.array(settings[inp.name], dtype=dt) if settings and inp.name in settings
                           else np.zeros([d.dim_value for d in t.shape.dim], dtype=dt))
    return feeds


def _run_shapes(model, names: list[str]) -> dict[str, tuple]:
    """Shapes static inference cannot give (sizes computed from data, e.g. NBG's grid sizes
    from H and W): run the bound graph once on zero inputs with each tensor's ``Shape`` as an
    output. Only the shapes are outputs, so onnxruntime frees every tensor as usual: with the
    tensors themselves as outputs, ndle-s at 1280x720 held 15.7 GB at once."""
    import onnx
    import onnxruntime as ort

    m = onnx.ModelProto()
    m.CopyFrom(model)
    shape_names = [f"__mcdenoise_shape_{i}" for i in range(len(names))]
    for name, out in zip(names, shape_names):
        m.graph.node.append(onnx.helper.make_node("Shape", [name], [out], name=out))
        m.graph.output.append(onnx.helper.make_tensor_value_info(out, onnx.TensorProto.INT64, [None]))
    so = ort.SessionOptions()
    so.log_severity_level = 3
    # Basic optimisations (constant folding, fusions) are safe: a fusion leaves a tensor that
    # has another consumer, and each shape asked for has its Shape node. Unoptimised, ndle-s at
    # 1280x720 peaked at 13 GB (1.7 GB so); neither the arena nor the memory pattern, which
    # keep every size they ever saw.
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
    so.enable_cpu_mem_arena = False
    so.enable_mem_pattern = False
    sess = ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"])
    outs = sess.run(shape_names, _zero_feeds(m))
    return {n: tuple(int(d) for d in o) for n, o in zip(names, outs)}


def _attrs(node) -> dict:
    import onnx

    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def _n(shape) -> int:
    return int(np.prod(shape, dtype=np.int64)) if shape is not None else 0


def node_cost(node, shapes: dict[str, tuple]) -> tuple[int, int] | None:
    """(FLOPs, FMAs) of one node, or None when its op is not counted.  Raises ValueError when
    a shape the count needs is unknown."""
    op = node.op_type

    def shape(name):
        if name not in shapes:
            raise ValueError(f"node {node.name!r} ({op}): shape of {name!r} unknown after inference")
        return shapes[name]

    if op in FREE:
        return 0, 0
    if op in ("ScatterND", "ScatterElements"):
        red = _attrs(node).get("reduction", b"none")
        red = red.decode() if isinstance(red, bytes) else red
        return (0, 0) if red == "none" else (_n(shape(node.input[2])), 0)
    out = shape(node.output[0])
    n_out = _n(out)
    a = _attrs(node)
    has_bias = len(node.input) > 2 and node.input[2] != ""
    if op == "Conv":
        w = shape(node.input[1])                  # (Cout, Cin/groups, k...)
        fmas = n_out * _n(w[1:])
        return 2 * fmas + (n_out if has_bias else 0), fmas
    if op == "ConvTranspose":
        x = shape(node.input[0])
        w = shape(node.input[1])                  # (Cin, Cout/groups, k...)
        fmas = _n(x) * _n(w[1:])
        return 2 * fmas + (n_out if has_bias else 0), fmas
    if op == "MatMul":
        x = shape(node.input[0])
        k = x[-1] if len(x) >= 1 else 1
        fmas = n_out * k
        return 2 * fmas, fmas
    if op == "Gemm":
        x = shape(node.input[0])
        k = x[0] if a.get("transA", 0) else x[-1]
        fmas = n_out * k
        extra = n_out if has_bias else 0
        if a.get("alpha", 1.0) != 1.0:
            extra += n_out
        if has_bias and a.get("beta", 1.0) != 1.0:
            extra += n_out
        return 2 * fmas + extra, fmas
    if op == "Einsum":
        eq = a["equation"]
        eq = eq.decode() if isinstance(eq, bytes) else eq
        lhs = eq.replace(" ", "").split("->")[0].split(",")
        size: dict[str, int] = {}
        for term, name in zip(lhs, node.input):
            s = shape(name)
            if "..." in term:
                raise ValueError(f"node {node.name!r}: Einsum with '...' is not counted")
            for ch, d in zip(term, s):
                size[ch] = max(size.get(ch, 1), d)
        fmas = int(np.prod(list(size.values()), dtype=np.int64))
        return 2 * fmas, fmas
    if op in ELEMENTWISE:
        return n_out, 0
    if op == "BatchNormalization":
        return 2 * n_out, 0
    if op in ("InstanceNormalization", "LayerNormalization", "Softmax", "LogSoftmax"):
        return 5 * n_out, 0
    if op in POOL:
        return n_out * _n(a["kernel_shape"]), 0
    if op in GLOBAL_POOL or op in REDUCE:
        return _n(shape(node.input[0])), 0
    if op == "Resize":
        mode = a.get("mode", b"nearest")
        mode = mode.decode() if isinstance(mode, bytes) else mode
        if mode == "nearest":
            return 0, 0
        x = shape(node.input[0])
        k = sum(1 for i, o in zip(x, out) if i != o)
        return n_out * (2 * 2 ** k - 1), 0
    if op == "GridSample":
        mode = a.get("mode", b"bilinear")
        mode = mode.decode() if isinstance(mode, bytes) else mode
        return (0, 0) if mode == "nearest" else (7 * n_out, 0)
    return None


def stage_of(node_name: str, stages) -> str:
    """The stage whose ``/<stage>/`` prefix starts ``node_name``, else :data:`OTHER`."""
    for s in stages:
        if node_name.startswith(f"/{s}/"):
            return s
    return OTHER


def _stages_from_names(model) -> list[str]:
    try:
        from mcdenoise.runtime.contract import parse_contract

        return parse_contract({p.key: p.value for p in model.metadata_props}).stage_names
    except ValueError:
        return sorted({n.name.split("/")[1] for n in model.graph.node
                       if n.name.startswith("/") and n.name.count("/") >= 2})


#: Ops whose cost is that of the subgraphs they run.
CONTROL_FLOW = frozenset({"If", "Loop", "Scan"})


def _subgraphs(node):
    import onnx

    for a in node.attribute:
        if a.type == onnx.AttributeProto.GRAPH:
            yield a.g
        elif a.type == onnx.AttributeProto.GRAPHS:
            yield from a.graphs


def _subgraph_nodes(model, stages) -> dict[str, tuple]:
    """Every node inside a control-flow node's subgraphs, at any depth: name -> (NodeProto,
    stage of the top-level node that holds it).  ValueError on an unnamed one or a name used
    twice (the profile names executed nodes by name only)."""
    found: dict[str, tuple] = {}
    top = {n.name for n in model.graph.node}

    def walk(graph, stage):
        for n in graph.node:
            if not n.name or n.name in found or n.name in top:
                raise ValueError(f"count_flops: a node inside a subgraph is {'unnamed' if not n.name else 'named twice: ' + n.name!r} "
                                 f"({n.op_type}); its executions cannot be told apart in the profile")
            found[n.name] = (n, stage)
            for g in _subgraphs(n):
                walk(g, stage)

    for node in model.graph.node:
        for g in _subgraphs(node):
            walk(g, stage_of(node.name, stages))
    return found


_SHAPES = r'\[((?:\{"\w+":\[[\d,]*\]\},?)*)\]'
_NAME = re.compile(r'"name" :"([^"]*)_kernel_time"')
_INPUTS = re.compile(r'"input_type_shape" : ' + _SHAPES)
_OUTPUTS = re.compile(r'"output_type_shape" : ' + _SHAPES)
_DIMS = re.compile(r'\{"\w+":\[([\d,]*)\]\}')


def _executed(model, settings: dict) -> list[tuple[str, list, list]]:
    """(node name, input shapes, output shapes) of every kernel one onnxruntime run of ``model``
    executes, subgraph bodies included (a profiled run, optimisations off so the nodes are the
    graph's own), on zero inputs with the int64 scalar ``settings`` by input name."""
    import tempfile

    import onnxruntime as ort

    feeds = _zero_feeds(model, settings)
    with tempfile.TemporaryDirectory() as tmp:
        so = ort.SessionOptions()
        so.log_severity_level = 3
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        so.enable_profiling = True
        so.profile_file_prefix = os.path.join(tmp, "flops")
        sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
        sess.run(None, feeds)
        # One event a line; a regex reads the three fields needed (json.load of the 45 MB an
        # anf-s run writes took 3.4 s, for the thread statistics of every event).
        out = []
        with open(sess.end_profiling()) as fh:
            for line in fh:
                name = _NAME.search(line)
                if name and '"cat" : "Node"' in line:
                    out.append((name[1], *([tuple(int(d) for d in dims.split(",") if d) for dims in _DIMS.findall(m[1])]
                                           if (m := rx.search(line)) else [] for rx in (_INPUTS, _OUTPUTS))))
    return out


def _default_settings(model) -> dict:
    try:
        from mcdenoise.runtime.contract import parse_contract

        contract = parse_contract({p.key: p.value for p in model.metadata_props})
    except ValueError:
        return {}
    return {st["input"]: st["default"] for st in contract.settings}


def _add(res: FlopCount, name: str, op: str, stage: str, fl: int, fm: int, nodes: int = 1) -> None:
    res.flops += fl
    res.fmas += fm
    for d, key in ((res.per_stage, stage), (res.per_op, op)):
        e = d.setdefault(key, {"flops": 0, "fmas": 0, "nodes": 0})
        e["flops"] += fl
        e["fmas"] += fm
        e["nodes"] += nodes
    res.per_node.append((name, op, stage, fl, fm))


#: Frames up to this many pixels have their control flow profiled at their own size.
PROFILE_PIXELS = 64 * 64
#: The smallest size the scaled profile runs at (see the module docstring).
PROFILE_MIN_PIXELS = 32 * 32


def _profiled_costs(model, width: int, height: int, batch: int, stages, settings: dict):
    """({subgraph node name: [flops, fmas] over its executions}, {op: uncounted executions}) of one
    profiled run of ``model`` bound to ``width`` x ``height``."""
    bound = _bind_inputs(model, width, height, batch)
    inner = _subgraph_nodes(bound, stages)
    totals: dict[str, list] = {}
    uncounted: dict[str, int] = {}
    for name, ins, outs in _executed(bound, settings):
        if name not in inner:
            continue
        node, _ = inner[name]
        if node.op_type in CONTROL_FLOW:
            continue                  # its own body's nodes are in the profile
        shapes = dict(zip([i for i in node.input if i], ins))
        shapes.update(zip([o for o in node.output if o], outs))
        cost = node_cost(node, shapes)
        if cost is None:
            uncounted[node.op_type] = uncounted.get(node.op_type, 0) + 1
            continue
        t = totals.setdefault(name, [0, 0])
        t[0] += cost[0]
        t[1] += cost[1]
    return totals, uncounted


def _scaled_costs(model, width: int, height: int, batch: int, stages, settings: dict):
    """:func:`_profiled_costs` at ``width`` x ``height``, from two smaller runs where they give it
    exactly (the module docstring), else from a run at that size."""
    g = math.gcd(width, height)
    divs = [d for d in range(g, 1, -1) if g % d == 0 and (width // d) * (height // d) >= PROFILE_MIN_PIXELS]
    if width * height > PROFILE_PIXELS and len(divs) >= 2:
        (a, ua), (b, ub) = (_profiled_costs(model, width // d, height // d, batch, stages, settings) for d in divs[:2])
        pa, pb, p = ((width // d) * (height // d) for d in (*divs[:2], 1))
        out = {}
        for name in a if a.keys() == b.keys() and ua == ub else ():
            pair = []
            for xa, xb in zip(a[name], b[name]):
                if xa == xb:
                    pair.append(xa)
                elif xb * pa == xa * pb and xa * p % pa == 0:
                    pair.append(xa * p // pa)
                else:
                    break
            if len(pair) < 2:
                break
            out[name] = pair
        else:
            if a.keys() == b.keys() and ua == ub:
                return out, ua
    return _profiled_costs(model, width, height, batch, stages, settings)


def _count_subgraphs(res: FlopCount, model, stages, settings: dict, batch: int) -> None:
    """Add the executed subgraph nodes of ``model`` (see the module docstring) to ``res``."""
    inner = _subgraph_nodes(model, stages)
    totals, uncounted = _scaled_costs(model, res.width, res.height, batch, stages, settings)
    for op, n in uncounted.items():
        res.uncounted[op] = res.uncounted.get(op, 0) + n
    for name, (fl, fm) in totals.items():
        node, stage = inner[name]
        _add(res, name, node.op_type, stage, fl, fm)


def count_flops(model, width: int, height: int, stages=None, batch: int = 1,
                settings: dict | None = None) -> FlopCount:
    """Count FLOPs, FMAs and parameters of ``model`` (path or ``onnx.ModelProto``) for one
    frame of ``width`` x ``height`` (batch ``batch``).  ``stages``: stage names for the
    per-stage split (default: the mcdenoise contract's stages, else the graph's top-level
    ``/<scope>/`` names).  ``settings``: values of int64 scalar setting inputs by input name for
    a graph with control flow (default: the contract's defaults), e.g. ANF's kernel_size.
    Raises ValueError when shape inference leaves a counted node's shape unknown."""
    model = _load(model)
    if stages is None:
        stages = _stages_from_names(model)
    bound = _bind_inputs(model, width, height, batch)
    shapes = _shapes(bound)
    res = FlopCount(width=width, height=height)
    for s in list(stages) + [OTHER]:
        res.per_stage[s] = {"flops": 0, "fmas": 0, "nodes": 0}
    for node in bound.graph.node:
        if node.op_type in CONTROL_FLOW:
            continue
        cost = node_cost(node, shapes)
        if cost is None:
            res.uncounted[node.op_type] = res.uncounted.get(node.op_type, 0) + 1
            continue
        _add(res, node.name, node.op_type, stage_of(node.name, stages), *cost)
    if any(n.op_type in CONTROL_FLOW for n in bound.graph.node):
        _count_subgraphs(res, model, stages, {**_default_settings(bound), **(settings or {})}, batch)
    if not res.per_stage[OTHER]["nodes"]:
        del res.per_stage[OTHER]
    weight_names: set[str] = set()
    for node in bound.graph.node:
        slots = WEIGHT_INPUTS.get(node.op_type, ())
        if slots is None:
            slots = range(len(node.input))
        for k in slots:
            if k < len(node.input):
                weight_names.add(node.input[k])
    for init in bound.graph.initializer:
        if init.data_type not in _FLOAT_TYPES:
            continue
        n = _n(tuple(init.dims))
        if init.name in weight_names:
            res.params += n
        else:
            res.constants += n
    return res


# ------------------------------------------------------------------------------------------
# This CPU's peak
# ------------------------------------------------------------------------------------------

def _cpuinfo() -> dict[str, str]:
    info: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if ":" in line:
                    k, v = line.split(":", 1)
                    info.setdefault(k.strip(), v.strip())
    except OSError:
        pass
    return info


def cpu_peak(threads: int | None = None) -> dict:
    """This CPU's fp32 peak from /proc/cpuinfo: cores x GHz x FLOPs/cycle/core.

    Assumptions (returned in ``"assumptions"``): FLOPs/cycle per core for the widest vector
    ISA in the flags, with two FMA units per core: AVX-512F 2 x 16 lanes x 2 = 64, AVX2 + FMA
    2 x 8 x 2 = 32, AVX without FMA 16 (one 8-wide add + one 8-wide multiply), else SSE 8.
    Some Xeons have one 512-bit FMA unit (then AVX-512 peak is half).  The clock is the
    ``@ x.xxGHz`` of the model name, else /proc/cpuinfo's ``cpu MHz`` (the current or, in a VM,
    nominal clock; turbo is not known).  Cores: ``threads`` if given, else the CPUs this
    process may run on, each counted as a full core (a VM's vCPU may be a hyperthread).
    Returns {"gflops", "cores", "ghz", "flops_per_cycle", "isa", "assumptions"}; gflops is None
    when the clock is unknown.
    """
    import re

    info = _cpuinfo()
    flags = set(info.get("flags", "").split())
    if "avx512f" in flags:
        isa, fpc = "AVX-512F (2 FMA units assumed)", 64
    elif "avx2" in flags and "fma" in flags:
        isa, fpc = "AVX2 + FMA (2 FMA units assumed)", 32
    elif "avx" in flags:
        isa, fpc = "AVX (1 add + 1 mul per cycle)", 16
    else:
        isa, fpc = "SSE (1 add + 1 mul per cycle)", 8
    ghz = None
    m = re.search(r"@\s*([0-9.]+)\s*GHz", info.get("model name", ""))
    if m:
        ghz, clock_src = float(m.group(1)), "model name"
    elif info.get("cpu MHz"):
        ghz, clock_src = float(info["cpu MHz"]) / 1e3, "/proc/cpuinfo cpu MHz"
    else:
        clock_src = "unknown"
    if threads:
        cores = int(threads)
    else:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:
            cores = os.cpu_count() or 1
    gflops = cores * ghz * fpc if ghz else None
    return {"gflops": gflops, "cores": cores, "ghz": ghz, "flops_per_cycle": fpc, "isa": isa,
            "assumptions": f"fp32, {cores} cores x {ghz if ghz else '?'} GHz ({clock_src}) x {fpc} "
                           f"FLOPs/cycle ({isa}); no turbo, every vCPU counted as a full core"}


def format_count(c: FlopCount) -> str:
    """A short text summary (for logs)."""
    st = ", ".join(f"{s} {v['flops'] / 1e9:.3f}" for s, v in c.per_stage.items())
    un = f"; not counted: {c.uncounted}" if c.uncounted else ""
    return (f"{c.flops / 1e9:.3f} GFLOP ({c.fmas / 1e9:.3f} GFMA) at {c.width}x{c.height}, "
            f"{c.params} parameters; per stage GFLOP: {st}{un}")


def main(argv: list[str] | None = None) -> int:
    """``python -m mcdenoise.training.flops FILE.onnx... [--size WxH]``: print each file's
    FLOPs, FMAs and parameters at one frame size (default 1280x720), the numbers the README
    and the result pages quote for a spec (export a run folder first: ``mcdenoise export``)."""
    import argparse
    import sys
    p = argparse.ArgumentParser(prog="python -m mcdenoise.training.flops",
                                description="FLOPs and parameters of ONNX models at one frame size")
    p.add_argument("models", nargs="+", metavar="FILE.onnx")
    p.add_argument("--size", default="1280x720", help="frame size WxH (default 1280x720)")
    a = p.parse_args(argv)
    try:
        w, h = (int(v) for v in a.size.lower().split("x"))
    except ValueError:
        p.error(f"--size {a.size!r}: give WxH, e.g. 1280x720")
    rc = 0
    for m in a.models:
        try:
            print(f"{m}: {format_count(count_flops(m, w, h))}")
        except (OSError, ValueError) as e:     # a missing or unreadable file: say which, go on
            print(f"{m}: cannot count: {e}", file=sys.stderr)
            rc = 1
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
