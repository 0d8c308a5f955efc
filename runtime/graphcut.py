"""Cut an ONNX model in two at a stage boundary, without the ``onnx`` package.

The driver runs a stage on its own when that pays: WSKPN's reconstruction is a chain of
per-pixel operations and box filters over full-frame tensors, each a trip through memory at
1280x720, and in bands of rows on two one-thread sessions the same operations stay in cache
(:mod:`runtime.bands`).  onnxruntime runs whole graphs only, so the driver needs the graph
before the stage ("head") and the stage alone ("tail") as two models.

The runtime must not depend on ``onnx`` (numpy, onnxruntime and OpenEXR only), so this module
reads and writes the few protobuf fields it needs straight from the wire format and copies
every other field byte for byte:

* ModelProto: ``graph`` (7) is replaced, everything else (opsets, IR version, metadata) kept;
* GraphProto: ``node`` (1), ``initializer`` (5), ``input`` (11), ``output`` (12) and
  ``value_info`` (13) are split between the two graphs; other fields are kept in both;
* NodeProto: ``input`` (1), ``output`` (2), ``name`` (3) are read, a node is copied whole;
* TensorProto / ValueInfoProto: only ``name`` (8 / 1) is read.

The tail's inputs that the head computes are declared by name and type; the head's new
outputs by name only (onnxruntime infers their type, which :func:`tail_model` then needs).
Anything the cut cannot handle safely raises :class:`GraphCutError` (the caller then runs the
whole graph): nodes with subgraph attributes (their outer-scope inputs are not listed),
sparse initializers, a head node that reads a tail output, or an empty side.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

# Field numbers (onnx/onnx.proto).
_MODEL_GRAPH = 7
_GRAPH_NODE, _GRAPH_INIT, _GRAPH_SPARSE_INIT = 1, 5, 15
_GRAPH_INPUT, _GRAPH_OUTPUT, _GRAPH_VALUE_INFO = 11, 12, 13
_NODE_INPUT, _NODE_OUTPUT, _NODE_NAME, _NODE_ATTR = 1, 2, 3, 5
_ATTR_GRAPH, _ATTR_GRAPHS = 6, 11
_TENSOR_NAME, _VALUE_INFO_NAME = 8, 1
_VALUE_INFO_TYPE = 2
_TYPE_TENSOR, _TENSOR_TYPE_ELEM, _TENSOR_TYPE_SHAPE = 1, 1, 2
_SHAPE_DIM, _DIM_VALUE, _DIM_PARAM = 1, 1, 2
_VARINT, _I64, _LEN, _I32 = 0, 1, 2, 5

#: onnxruntime's type strings -> TensorProto.DataType, for the types a stage boundary carries.
ELEM_TYPES = {"tensor(float)": 1, "tensor(uint8)": 2, "tensor(int8)": 3, "tensor(int32)": 6,
              "tensor(int64)": 7, "tensor(bool)": 9, "tensor(float16)": 10, "tensor(double)": 11}


class GraphCutError(ValueError):
    """The model cannot be cut at that stage (the caller runs the whole graph instead)."""


class Field(NamedTuple):
    number: int
    raw: bytes          # the whole field as encoded (key and value), copied as is
    value: bytes | int  # payload of a length-delimited field, or the integer of a varint


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        if i >= len(buf):
            raise GraphCutError("truncated protobuf varint")
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, i
        shift += 7
        if shift > 63:
            raise GraphCutError("malformed protobuf varint")


def fields(buf: bytes) -> list[Field]:
    """The top-level fields of one encoded protobuf message, in order."""
    out, i = [], 0
    while i < len(buf):
        start = i
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == _VARINT:
            value, i = _varint(buf, i)
        elif wire == _LEN:
            n, i = _varint(buf, i)
            value = buf[i:i + n]
            if len(value) != n:
                raise GraphCutError("truncated protobuf field")
            i += n
        elif wire == _I64:
            value, i = buf[i:i + 8], i + 8
        elif wire == _I32:
            value, i = buf[i:i + 4], i + 4
        else:
            raise GraphCutError(f"unsupported protobuf wire type {wire}")
        if i > len(buf):
            raise GraphCutError("truncated protobuf field")
        out.append(Field(number, bytes(buf[start:i]), value))
    return out


def _encode_varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def _len_field(number: int, payload: bytes) -> bytes:
    return _encode_varint(number << 3 | _LEN) + _encode_varint(len(payload)) + payload


def _varint_field(number: int, v: int) -> bytes:
    return _encode_varint(number << 3 | _VARINT) + _encode_varint(v)


def _strings(msg: bytes, number: int) -> list[str]:
    return [f.value.decode() for f in fields(msg) if f.number == number]


def _name(msg: bytes, number: int) -> str:
    names = _strings(msg, number)
    return names[0] if names else ""


class _Node(NamedTuple):
    raw: bytes
    name: str
    inputs: list[str]
    outputs: list[str]


def _node(f: Field) -> _Node:
    parts = fields(f.value)
    for a in parts:
        if a.number == _NODE_ATTR and any(x.number in (_ATTR_GRAPH, _ATTR_GRAPHS) for x in fields(a.value)):
            raise GraphCutError("a node has a subgraph attribute (its outer-scope inputs are not listed)")
    pick = lambda n: [p.value.decode() for p in parts if p.number == n]  # noqa: E731
    names = pick(_NODE_NAME)
    return _Node(f.raw, names[0] if names else "", pick(_NODE_INPUT), pick(_NODE_OUTPUT))


def value_info(name: str, elem_type: int | None = None, shape=None) -> bytes:
    """An encoded ValueInfoProto: ``name`` alone (type left to onnxruntime's inference), or a
    tensor of ``elem_type`` (TensorProto.DataType) with ``shape`` (ints and dimension names;
    None for an unknown dimension)."""
    body = _len_field(_VALUE_INFO_NAME, name.encode())
    if elem_type is not None:
        tensor = _varint_field(_TENSOR_TYPE_ELEM, elem_type)
        if shape is not None:
            dims = b""
            for d in shape:
                if isinstance(d, int):
                    dims += _len_field(_SHAPE_DIM, _varint_field(_DIM_VALUE, d))
                elif isinstance(d, str):
                    dims += _len_field(_SHAPE_DIM, _len_field(_DIM_PARAM, d.encode()))
                else:
                    dims += _len_field(_SHAPE_DIM, b"")
            tensor += _len_field(_TENSOR_TYPE_SHAPE, dims)
        body += _len_field(_VALUE_INFO_TYPE, _len_field(_TYPE_TENSOR, tensor))
    return body


@dataclass(frozen=True)
class Cut:
    """A model cut before the nodes of one stage.

    head: encoded model of every other node; its outputs are the original graph outputs it
      computes, then ``boundary`` (declared by name only).
    boundary: tensors the head computes and the stage reads, in first-use order.
    tail_inputs: the stage's inputs in first-use order: original graph inputs and
      ``boundary`` names.
    """

    head: bytes
    boundary: list[str]
    tail_inputs: list[str]
    _model: list = field(repr=False)
    _graph_rest: list = field(repr=False)
    _tail_nodes: list = field(repr=False)
    _tail_inits: list = field(repr=False)
    _tail_outputs: list = field(repr=False)
    _graph_inputs: dict = field(repr=False)


def _model_bytes(model: list[Field], graph: bytes) -> bytes:
    return b"".join(_len_field(_MODEL_GRAPH, graph) if f.number == _MODEL_GRAPH else f.raw for f in model)


def cut_before_stage(model_bytes: bytes, node_prefix: str) -> Cut:
    """Cut ``model_bytes`` (an encoded ONNX ModelProto) before the nodes whose names start
    with ``node_prefix`` (a stage's ``/<stage>/``).  Those nodes must not feed any other
    node: the stage is the last one.  Raises GraphCutError."""
    model = fields(model_bytes)
    graphs = [f for f in model if f.number == _MODEL_GRAPH]
    if len(graphs) != 1:
        raise GraphCutError("not an ONNX model (no graph)")
    gfields = fields(graphs[0].value)
    if any(f.number == _GRAPH_SPARSE_INIT for f in gfields):
        raise GraphCutError("sparse initializers are not supported")
    nodes = [_node(f) for f in gfields if f.number == _GRAPH_NODE]
    tail = [n for n in nodes if n.name.startswith(node_prefix)]
    head = [n for n in nodes if not n.name.startswith(node_prefix)]
    if not tail or not head:
        raise GraphCutError(f"no nodes {'in' if not tail else 'before'} stage {node_prefix!r}")
    tail_made = {o for n in tail for o in n.outputs}
    head_made = {o for n in head for o in n.outputs}
    for n in head:
        bad = [i for i in n.inputs if i in tail_made]
        if bad:
            raise GraphCutError(f"node {n.name!r} outside stage {node_prefix!r} reads its output {bad[0]!r}")
    inits = {_name(f.value, _TENSOR_NAME): f.raw for f in gfields if f.number == _GRAPH_INIT}
    g_inputs = {_name(f.value, _VALUE_INFO_NAME): f.raw for f in gfields if f.number == _GRAPH_INPUT}
    g_outputs = [(_name(f.value, _VALUE_INFO_NAME), f.raw) for f in gfields if f.number == _GRAPH_OUTPUT]
    for name, _ in g_outputs:
        if name not in tail_made and name not in head_made:
            raise GraphCutError(f"graph output {name!r} is not computed by a node")

    tail_reads = list(dict.fromkeys(i for n in tail for i in n.inputs if i and i not in tail_made))
    boundary, tail_inputs, tail_inits = [], [], []
    for t in tail_reads:
        if t in inits:             # a constant (also when declared an input: a default)
            tail_inits.append(inits[t])
        elif t in g_inputs:
            tail_inputs.append(t)
        elif t in head_made:
            boundary.append(t)
            tail_inputs.append(t)
        else:
            raise GraphCutError(f"stage {node_prefix!r} reads {t!r}, which nothing defines")
    head_reads = {i for n in head for i in n.inputs}
    kept = (_GRAPH_NODE, _GRAPH_INIT, _GRAPH_INPUT, _GRAPH_OUTPUT, _GRAPH_VALUE_INFO)
    rest = [f for f in gfields if f.number not in kept]
    head_graph = b"".join([n.raw for n in head]
                          + [raw for name, raw in inits.items() if name in head_reads]
                          + [raw for name, raw in g_inputs.items() if name in head_reads]
                          + [raw for name, raw in g_outputs if name in head_made]
                          + [_len_field(_GRAPH_OUTPUT, value_info(b)) for b in boundary]
                          + [f.raw for f in rest])
    return Cut(head=_model_bytes(model, head_graph), boundary=boundary, tail_inputs=tail_inputs,
               _model=model, _graph_rest=rest, _tail_nodes=[n.raw for n in tail], _tail_inits=tail_inits,
               _tail_outputs=[raw for name, raw in g_outputs if name in tail_made], _graph_inputs=g_inputs)


def tail_model(cut: Cut, boundary_types: dict[str, tuple[str, list]]) -> bytes:
    """Encoded model of the stage alone.  ``boundary_types``: {boundary name: (onnxruntime
    type string, shape)} as the head session's ``get_outputs()`` reports them."""
    decl = []
    for name in cut.tail_inputs:
        if name in cut._graph_inputs:
            decl.append(cut._graph_inputs[name])
            continue
        type_str, shape = boundary_types[name]
        if type_str not in ELEM_TYPES:
            raise GraphCutError(f"stage input {name!r} has type {type_str}, which the cut does not declare")
        decl.append(_len_field(_GRAPH_INPUT, value_info(name, ELEM_TYPES[type_str], shape)))
    graph = b"".join(cut._tail_nodes + cut._tail_inits + decl + cut._tail_outputs
                     + [f.raw for f in cut._graph_rest])
    return _model_bytes(cut._model, graph)
