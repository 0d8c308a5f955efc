"""mcdenoise.runtime.graphcut: cutting a model before its last stage without the onnx package.

The head and the stage run one after the other must give the whole graph's outputs to the
bit, for every shipped model; what the cut cannot handle is an error, not a wrong graph.
"""
import os

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from mcdenoise.runtime import graphcut
from mcdenoise.runtime.contract import parse_contract
from mcdenoise.runtime.methods import shipped_models


def _session(model: bytes):
    so = ort.SessionOptions()
    so.log_severity_level = 3
    return ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])


def _feeds(sess, h=23, w=31, seed=0):
    rng = np.random.default_rng(seed)
    feeds = {}
    for i in sess.get_inputs():
        c = i.shape[1]
        a = rng.random((1, c, h, w), dtype=np.float32)
        feeds[i.name] = a * 2 - 1 if i.name == "normal" else a
    return feeds


@pytest.mark.parametrize("path", shipped_models(), ids=os.path.basename)
def test_head_then_last_stage_equals_the_whole_graph(path):
    with open(path, "rb") as fh:
        data = fh.read()
    whole = _session(data)
    contract = parse_contract(whole.get_modelmeta().custom_metadata_map)
    last = contract.stages[-1]
    cut = graphcut.cut_before_stage(data, last["node_prefix"])
    head = _session(cut.head)
    types = {o.name: (o.type, o.shape) for o in head.get_outputs()}
    tail = _session(graphcut.tail_model(cut, types))
    # The pieces are well-formed ONNX, every node in exactly one of them.
    n_head = len(onnx.load_from_string(cut.head).graph.node)
    tail_proto = onnx.load_from_string(graphcut.tail_model(cut, types))
    assert n_head + len(tail_proto.graph.node) == len(onnx.load_from_string(data).graph.node)
    assert all(n.name.startswith(last["node_prefix"]) for n in tail_proto.graph.node)
    assert {p.key for p in tail_proto.metadata_props} == {p.key for p in onnx.load_from_string(data).metadata_props}

    feeds = _feeds(whole)
    want = dict(zip([o.name for o in whole.get_outputs()], whole.run(None, feeds)))
    got = dict(zip([o.name for o in head.get_outputs()], head.run(None, {i.name: feeds[i.name] for i in head.get_inputs()})))
    assert cut.boundary and all(b in got for b in cut.boundary)
    stage_in = {n: got[n] if n in got else feeds[n] for n in cut.tail_inputs}
    got.update(zip([o.name for o in tail.get_outputs()], tail.run(None, stage_in)))
    for name, ref in want.items():
        np.testing.assert_array_equal(got[name], ref)


def _model(nodes, inputs, outputs, initializers=()):
    g = helper.make_graph(nodes, "g", inputs, outputs, initializer=list(initializers))
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m.SerializeToString()


X = helper.make_tensor_value_info("x", TensorProto.FLOAT, ["N", 3])
Y = helper.make_tensor_value_info("y", TensorProto.FLOAT, ["N", 3])


def test_a_small_model_cut_keeps_constants_and_graph_inputs_where_they_are_read():
    two = helper.make_tensor("two", TensorProto.FLOAT, [], [2.0])
    nodes = [helper.make_node("Mul", ["x", "two"], ["a"], name="/first/Mul"),
             helper.make_node("Relu", ["a"], ["b"], name="/first/Relu"),
             helper.make_node("Add", ["b", "x"], ["c"], name="/second/Add"),
             helper.make_node("Mul", ["c", "two"], ["y"], name="/second/Mul")]
    data = _model(nodes, [X], [Y], [two])
    cut = graphcut.cut_before_stage(data, "/second/")
    assert cut.boundary == ["b"] and cut.tail_inputs == ["b", "x"]
    head = _session(cut.head)
    assert [o.name for o in head.get_outputs()] == ["b"]
    tail = _session(graphcut.tail_model(cut, {"b": ("tensor(float)", ["N", 3])}))
    assert [i.name for i in tail.get_inputs()] == ["b", "x"]
    x = np.array([[-1.0, 0.5, 2.0]], np.float32)
    (b,) = head.run(None, {"x": x})
    (y,) = tail.run(None, {"b": b, "x": x})
    np.testing.assert_array_equal(y, (np.maximum(x * 2, 0) + x) * 2)


def test_what_cannot_be_cut_is_an_error():
    nodes = [helper.make_node("Relu", ["x"], ["a"], name="/first/Relu"),
             helper.make_node("Neg", ["a"], ["b"], name="/second/Neg"),
             helper.make_node("Add", ["a", "b"], ["y"], name="/first/Add")]
    data = _model(nodes, [X], [Y])
    with pytest.raises(graphcut.GraphCutError, match="reads its output"):
        graphcut.cut_before_stage(data, "/second/")         # not the last stage
    with pytest.raises(graphcut.GraphCutError, match="no nodes in stage"):
        graphcut.cut_before_stage(data, "/third/")
    with pytest.raises(graphcut.GraphCutError, match="no nodes before"):
        graphcut.cut_before_stage(_model(nodes[:1], [X], [helper.make_tensor_value_info("a", TensorProto.FLOAT, None)]),
                                  "/first/")
    with pytest.raises(graphcut.GraphCutError):
        graphcut.cut_before_stage(data[:len(data) // 2], "/second/")   # truncated file
    with pytest.raises(graphcut.GraphCutError, match="no graph"):
        graphcut.cut_before_stage(b"\x08\x08", "/second/")           # ir_version only
    # A node with a subgraph reads outer-scope values it does not list: refused.
    branch = helper.make_graph([helper.make_node("Identity", ["a"], ["z"])], "b", [],
                               [helper.make_tensor_value_info("z", TensorProto.FLOAT, None)])
    cond = helper.make_tensor_value_info("cond", TensorProto.BOOL, [])
    nodes = [helper.make_node("Relu", ["x"], ["a"], name="/first/Relu"),
             helper.make_node("If", ["cond"], ["y"], name="/second/If", then_branch=branch, else_branch=branch)]
    with pytest.raises(graphcut.GraphCutError, match="subgraph"):
        graphcut.cut_before_stage(_model(nodes, [X, cond], [Y]), "/second/")
    with pytest.raises(graphcut.GraphCutError, match="type"):
        cut = graphcut.cut_before_stage(_model(
            [helper.make_node("Shape", ["x"], ["s"], name="/first/Shape"),
             helper.make_node("Reshape", ["x", "s"], ["y"], name="/second/Reshape")], [X], [Y]), "/second/")
        graphcut.tail_model(cut, {"s": ("tensor(string)", [2])})


def test_value_info_encoding_reads_back_in_onnx():
    v = onnx.ValueInfoProto.FromString(graphcut.value_info("t", 1, ["N", 12, None, 7]))
    assert v.name == "t" and v.type.tensor_type.elem_type == TensorProto.FLOAT
    dims = v.type.tensor_type.shape.dim
    assert [d.dim_param for d in dims] == ["N", "", "", ""] and [d.dim_value for d in dims] == [0, 12, 0, 7]
    assert not dims[2].HasField("dim_value") and not dims[2].HasField("dim_param")
    bare = onnx.ValueInfoProto.FromString(graphcut.value_info("u"))
    assert bare.name == "u" and not bare.HasField("type")
    # Long names and large values need multi-byte varints.
    long = "n" * 300
    v = onnx.ValueInfoProto.FromString(graphcut.value_info(long, 7, [1 << 40]))
    assert v.name == long and v.type.tensor_type.shape.dim[0].dim_value == 1 << 40
