"""Issue 17 (the AMX host's ratio) and issue 15 (wskpn-3 against Open Image Denoise fast): does an
8-bit prediction network pay on the CPU? Writes an int8 copy of a shipped WSKPN file.

    python docs/results/int8/make_int8.py models/wskpn-3-aa.onnx /tmp/int8/wskpn-3-aa [--pad]

Writes OUT.fp32-pad.onnx (with --pad) and OUT.int8.onnx:
* --pad: the ImportanceNet's convolutions padded to multiples of 16 channels with zero weights
  (its input's 10 channels get 6 zero planes, the last convolution's 12 outputs 4 dropped
  ones). onnxruntime's blocked (NCHWc) convolution needs the input channels a multiple of the
  vector width (8 on AVX2) or below it; with 10 the first convolution falls back to im2col, and
  its int8 convolution was slow with 12 output channels (docs/results/int8/README.md). The padded
  fp32 graph must equal the original (checked here).
* int8: onnxruntime.quantization.quantize_static, QDQ, per-channel int8 weights, uint8
  activations, only the Conv nodes (the kernel fusion stays fp32), calibrated on the graph inputs
  the driver feeds on CALIB (default data/nbg-train: training scenes, never the test sets) at
  1, 2, 4 and 8 spp. The file keeps the source's metadata, so the driver runs it as the same spec.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
import onnx
from onnx import helper, numpy_helper

PAD = 16


def _conv_nodes(model):
    return [n for n in model.graph.node if n.op_type == "Conv" and n.name.startswith("/prediction/")]


def pad_channels(model) -> onnx.ModelProto:
    """A copy of ``model`` whose ImportanceNet convolutions have input and output channel counts
    rounded up to multiples of :data:`PAD` with zero weights; same outputs."""
    m = onnx.ModelProto()
    m.CopyFrom(model)
    inits = {i.name: i for i in m.graph.initializer}
    convs = _conv_nodes(m)
    first, last = convs[0], convs[-1]
    for n in convs:
        w = numpy_helper.to_array(inits[n.input[1]])
        cout, cin = w.shape[:2]
        pin = -cin % PAD if n is first else 0
        pout = -cout % PAD if n is last else 0
        if not (pin or pout):
            continue
        w2 = np.zeros((cout + pout, cin + pin, *w.shape[2:]), w.dtype)
        w2[:cout, :cin] = w
        inits[n.input[1]].CopyFrom(numpy_helper.from_array(w2, n.input[1]))
        if len(n.input) > 2 and pout:
            b = numpy_helper.to_array(inits[n.input[2]])
            inits[n.input[2]].CopyFrom(numpy_helper.from_array(np.concatenate([b, np.zeros(pout, b.dtype)]), n.input[2]))
        if pin:      # zero planes after the input: Pad on the channel axis
            pads = numpy_helper.from_array(np.array([0, 0, 0, 0, 0, pin, 0, 0], np.int64), n.name + "_pads")
            m.graph.initializer.append(pads)
            padded = n.input[0] + "_padded"
            idx = list(m.graph.node).index(n)
            m.graph.node.insert(idx, helper.make_node("Pad", [n.input[0], pads.name], [padded], name=n.name + "_pad"))
            n.input[0] = padded
        if pout:     # drop the zero outputs again
            full = n.output[0] + "_full"
            out = n.output[0]
            n.output[0] = full
            for name, arr in ((n.name + "_s0", [0]), (n.name + "_s1", [cout]), (n.name + "_ax", [1])):
                m.graph.initializer.append(numpy_helper.from_array(np.array(arr, np.int64), name))
            idx = list(m.graph.node).index(n)
            m.graph.node.insert(idx + 1, helper.make_node("Slice", [full, n.name + "_s0", n.name + "_s1", n.name + "_ax"],
                                                          [out], name=n.name + "_slice"))
    return m


def calibration_feeds(path: str, data: str, sequences: int, frames: int) -> list[dict]:
    """The graph inputs the driver feeds ``path`` over the first ``sequences`` x ``frames`` of
    ``data``, at 1, 2, 4 and 8 spp (each sequence from a reset)."""
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.testsets import at_spp, read_sequences

    den = Denoiser.load(path, threads=1)
    fed = []
    run = den.session.run

    def record(names, feeds, *a, **k):
        fed.append({k2: np.array(v) for k2, v in feeds.items()})
        return run(names, feeds, *a, **k)

    den.session.run = record
    for seq in read_sequences(data, limit=(sequences, frames)):
        for spp in (1, 2, 4, 8):
            den.reset()
            for fr in seq:
                den(at_spp(fr, spp))
    return fed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model")
    p.add_argument("out", help="output prefix")
    p.add_argument("--pad", action="store_true")
    p.add_argument("--calib", default="data/nbg-train")
    p.add_argument("--sequences", type=int, default=6)
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--only-hidden", action="store_true",
                   help="quantize only the convolutions between hidden layers: not the first (its input's channels "
                        "span different ranges: depth to ~100, colour and albedo [0, 1], under one per-tensor scale) "
                        "nor the last (its output is the kernels' logits, which go through exp)")
    a = p.parse_args(argv)
    import onnxruntime as ort
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    src = onnx.load(a.model)
    base = a.model
    if a.pad:
        padded = pad_channels(src)
        base = a.out + ".fp32-pad.onnx"
        onnx.save(padded, base)
        rng = np.random.default_rng(0)
        feeds = {i.name: rng.uniform(0, 1, (1, *(d.dim_value or 96 for d in i.type.tensor_type.shape.dim[1:]))).astype(np.float32)
                 for i in src.graph.input}
        y0 = ort.InferenceSession(a.model).run(None, feeds)[0]
        y1 = ort.InferenceSession(base).run(None, feeds)[0]
        err = float(np.max(np.abs(y0 - y1)) / max(1e-12, float(np.max(np.abs(y0)))))
        print(f"padded fp32 graph: max |difference| / max |output| = {err:.2e}")
        if err > 1e-5:
            print("the padded graph differs from the original", file=sys.stderr)
            return 1
    fed = calibration_feeds(a.model, a.calib, a.sequences, a.frames)
    print(f"calibration: {len(fed)} frames of {a.calib}")

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter(fed)

        def get_next(self):
            return next(self.it, None)

    out = a.out + ".int8.onnx"
    convs = _conv_nodes(onnx.load(base))
    quantize_static(base, out, Reader(), quant_format=QuantFormat.QDQ, op_types_to_quantize=["Conv"],
                    per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                    nodes_to_exclude=[convs[0].name, convs[-1].name] if a.only_hidden else [])
    q = onnx.load(out)
    del q.metadata_props[:]
    q.metadata_props.extend(src.metadata_props)
    onnx.save(q, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
