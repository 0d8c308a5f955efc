"""mcdenoise bench: a quick run on the tiny dataset, the Pareto front, FLOP counts."""
from __future__ import annotations

import csv

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from mcdenoise.runtime.cli import main as cli_main
from mcdenoise.training.flops import count_flops, cpu_peak
from mcdenoise.training.methods import shipped_models
from mcdenoise.training import bench, harness, scoring


def _rows(path):
    with open(path) as fh:
        first = fh.readline()
        assert first.startswith("# written by: mcdenoise bench")
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def quick_run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = cli_main(["bench", "--quick", "--data", tiny_dataset, "--out", str(out), "--frames", "2",
                   "--warmup", "1"])
    assert rc == 0
    return out


def test_quick_bench_writes_every_file_and_method(quick_run):
    out = quick_run
    names = [onnx.load(p, load_external_data=False) for p in shipped_models()]
    models = [next(p.value for p in m.metadata_props if p.key == "mcdenoise.spec_name") for m in names]
    methods = models + list(bench.BUILTIN_METHODS)
    md = (out / "bench.md").read_text()
    assert "mcdenoise bench --quick" in md
    for m in methods:
        assert f"| {m} |" in md, m
    for png in ("psnr_vs_time.png", "psnr_vs_spp.png", "trmae.png"):
        data = (out / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
        assert b"mcdenoise bench --quick" in data      # the command, in the PNG's metadata
    quality = _rows(out / "bench_quality.csv")
    bare = [r for r in quality if r["method"].endswith(" (no history)")]
    quality = [r for r in quality if r not in bare]
    assert {r["method"] for r in quality} == set(methods)
    # the long sets also score every model reset before each frame
    assert {r["method"] for r in bare} == {m + " (no history)" for m in models}
    assert {r["set"] for r in bare} == {"long-quick", "long-quick after warm-up"}
    # tiny set: 4 stored spp -> stills at 1, 2, 4; sequences at 1 and 4; the tiny set again
    # standing in for the long sequences, with scores after a 1-frame warm-up
    assert {(r["set"], r["spp"]) for r in quality} == {
        ("stills", "1"), ("stills", "2"), ("stills", "4"), ("sequences", "1"), ("sequences", "4"),
        *((s, spp) for s in ("long-quick", "long-quick after warm-up") for spp in ("1", "4"))}
    after = {(r["method"], r["spp"]): r for r in quality if r["set"] == "long-quick after warm-up"}
    full = {(r["method"], r["spp"]): r for r in quality if r["set"] == "long-quick"}
    for key, r in after.items():
        assert int(r["frames"]) == int(full[key]["frames"]) - 2        # 2 sequences, 1 frame each left out
        assert float(r["wte"]) > 0 and float(full[key]["wte"]) > 0
    assert "### Long sequences" in md and "after the first 1 of each sequence" in md
    assert f"| {models[0]} (no history) |" in md
    for r in quality:
        assert np.isfinite(float(r["psnr"])) and r["flip"] and r["ssim"]
    psnr = {(r["method"], r["set"], r["spp"]): float(r["psnr"]) for r in quality}
    for m in models:
        for s, spp in (("stills", "1"), ("sequences", "1"), ("sequences", "4")):
            assert psnr[(m, s, spp)] > psnr[("noisy", s, spp)] + 1.0, (m, s, spp)
    stages = _rows(out / "bench.csv")
    assert {r["model"] for r in stages} == set(methods)
    flops = _rows(out / "bench_flops.csv")
    assert {r["method"] for r in flops} >= set(models)
    # per-sample models timed again at 1, 2, 4, 8 spp, every stage (no speed is asserted: timing
    # belongs in the bench's numbers, not in a unit test's pass or fail)
    scaling = md[md.index("## Per-sample models against samples per pixel, 64x64"):]
    for m, stages in (("anf-s", ("embedding", "unet", "kernels")),
                      ("ndle-s", ("sample_reducer", "unet", "sample_partitioner", "layer_filtering"))):
        table = scaling[scaling.index(f"{m}:"):].split("\n\n")[1].splitlines()
        assert table[0] == "| stage | 1 spp | 2 spp | 4 spp | 8 spp | 8/1 |"
        rows = {r.split(" | ")[0][2:]: r.split(" | ")[1:] for r in table[2:]}
        for st in stages + ("total",):
            assert all(float(v) > 0 for v in rows[st][:4]), (m, st, rows[st])
    # peak memory, each method in its own process
    mem = md[md.index("## Peak memory at 64x64"):]
    for m in methods:
        assert f"| {m} | " in mem, m


@pytest.mark.parametrize("spec_name", ["wskpn-3", "wskpn-6e", "nbg-2l-1g", "anf-s", "ndle-s"])
def test_torch_timing_feeds_every_input_of_every_family(spec_name):
    """The full bench's torch eager rows (``--quick`` skips them): each family's inputs,
    per-sample data and fed state weights included, come from the same protocol the driver
    uses, and every contract stage gets a time (anf-s once failed here: 'embed_weight')."""
    from mcdenoise.training.specs import build_model, load_spec

    spec = load_spec(spec_name)
    model = build_model(spec).eval().deploy()
    stages = list(spec.stages)
    med = harness.bench_torch(model, spec.protocol, stages, 32, 24, frames=1, warmup=1, spp=2)
    assert med[harness.timing.GRAPH] > 0
    for s in stages:
        assert s in med and med[s] > 0, s


def test_peak_memory_grows_with_the_frame_and_failures_say_why():
    """The fresh-process peak sees onnxruntime's own allocations: a 256x256 frame through
    wskpn-3 adds more than a 32x32 one (by much more than the 64x more pixels' input, which is
    built before the peak is taken)."""
    from mcdenoise.training.memory import peak_memory

    path = next(p for p in shipped_models() if p.endswith("wskpn-3.onnx"))
    small, big = peak_memory(path, 32, 32, frames=2), peak_memory(path, 256, 256, frames=2)
    assert big["added_mb"] > small["added_mb"] + 5 and big["peak_mb"] >= big["base_mb"] > 0
    with pytest.raises(RuntimeError, match="no-such.onnx: no such model file"):
        peak_memory("no-such.onnx", 32, 32)


def test_pareto_front():
    pts = {"noisy": (0.0, 16.0), "a": (5.0, 24.0), "b": (10.0, 23.0), "c": (12.0, 26.0),
           "d": (12.0, 25.0), "e": (30.0, 26.0), "f": (40.0, 27.0)}
    assert scoring.pareto_front(pts) == ["noisy", "a", "c", "f"]
    # equal points are both kept; a point equal in time but better in quality dominates
    assert scoring.pareto_front({"x": (1.0, 2.0), "y": (1.0, 2.0)}) == ["x", "y"]
    assert scoring.pareto_front({"x": (1.0, 2.0), "y": (1.0, 3.0)}) == ["y"]
    assert scoring.pareto_front({}) == []


def _conv_model(cin, cout, k, groups, h, w, bias=True, stride=1):
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, ["N", cin, "H", "W"])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    wt = helper.make_tensor("w", TensorProto.FLOAT, [cout, cin // groups, k, k],
                            np.zeros(cout * cin // groups * k * k, np.float32))
    inits = [wt]
    inputs = ["x", "w"]
    if bias:
        inits.append(helper.make_tensor("b", TensorProto.FLOAT, [cout], np.zeros(cout, np.float32)))
        inputs.append("b")
    conv = helper.make_node("Conv", inputs, ["c"], name="/prediction/conv", kernel_shape=[k, k],
                            pads=[k // 2] * 4, group=groups, strides=[stride, stride])
    relu = helper.make_node("Relu", ["c"], ["y"], name="/prediction/relu")
    g = helper.make_graph([conv, relu], "t", [x], [y], inits)
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])


def test_flops_single_conv_exact():
    m = _conv_model(cin=6, cout=8, k=3, groups=2, h=None, w=None)
    c = count_flops(m, width=20, height=10, stages=["prediction"])
    fmas = 1 * 8 * 10 * 20 * (6 // 2) * 3 * 3
    assert c.fmas == fmas
    assert c.flops == 2 * fmas + 8 * 10 * 20 + 8 * 10 * 20      # bias + relu
    assert c.params == 8 * 3 * 3 * 3 + 8
    assert c.per_stage == {"prediction": {"flops": c.flops, "fmas": fmas, "nodes": 2}}
    assert not c.uncounted
    # stride 2, no bias: output 5 x 10
    c2 = count_flops(_conv_model(4, 4, 5, 1, None, None, bias=False, stride=2), 20, 10)
    assert c2.fmas == 4 * 5 * 10 * 4 * 25 and c2.flops == 2 * c2.fmas + 4 * 5 * 10


def test_flops_command_prints_the_count_and_names_a_file_it_cannot_read(tmp_path, capsys):
    """The command the result pages quote parameter counts from: one line per file, the same
    numbers as count_flops; a missing file is named and the others still counted."""
    import onnx
    from mcdenoise.training import flops
    f = tmp_path / "conv.onnx"
    onnx.save(_conv_model(cin=6, cout=8, k=3, groups=2, h=None, w=None), f)
    assert flops.main([str(f), str(tmp_path / "missing.onnx"), "--size", "20x10"]) == 1
    out, err = capsys.readouterr()
    c = count_flops(str(f), 20, 10)
    assert f"{f}: " in out and f"{c.params} parameters" in out and c.params == 8 * 3 * 3 * 3 + 8
    assert f"{c.flops / 1e9:.3f} GFLOP" in out and "at 20x10" in out
    assert "missing.onnx: cannot count" in err
    with pytest.raises(SystemExit):
        flops.main([str(f), "--size", "720p"])


def _loop_model(trips: int, padded: bool = False):
    """y = x + 1 repeated ``trips`` times by a Loop whose body also multiplies by 2 on every
    iteration but the first (an If: the else branch is a Mul, the then branch an Identity);
    ``padded``: the body also emits (x + 1) padded by 1 pixel, times 3, as a scan output (a cost
    not proportional to the pixel count)."""
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", 3, "h", "w"])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    inits = [helper.make_tensor("trips", TensorProto.INT64, [], [trips]),
             helper.make_tensor("cond", TensorProto.BOOL, [], [True]),
             helper.make_tensor("one", TensorProto.FLOAT, [], [1.0]),
             helper.make_tensor("two", TensorProto.FLOAT, [], [2.0]),
             helper.make_tensor("zero", TensorProto.INT64, [], [0])]
    then = helper.make_graph([helper.make_node("Identity", ["a"], ["t"], name="then_id")], "then", [],
                             [helper.make_tensor_value_info("t", TensorProto.FLOAT, None)])
    other = helper.make_graph([helper.make_node("Mul", ["a", "two"], ["e"], name="else_mul")], "else", [],
                              [helper.make_tensor_value_info("e", TensorProto.FLOAT, None)])
    body = helper.make_graph(
        [helper.make_node("Add", ["v", "one"], ["a"], name="body_add"),
         helper.make_node("Equal", ["i", "zero"], ["first"], name="body_eq"),
         helper.make_node("If", ["first"], ["v_out"], name="body_if", then_branch=then, else_branch=other),
         helper.make_node("Identity", ["c"], ["c_out"], name="body_cond")]
        + ([helper.make_node("Pad", ["a", "pads"], ["p"], name="body_pad"),
            helper.make_node("Mul", ["p", "three"], ["q"], name="body_mul3")] if padded else []), "body",
        [helper.make_tensor_value_info("i", TensorProto.INT64, []),
         helper.make_tensor_value_info("c", TensorProto.BOOL, []),
         helper.make_tensor_value_info("v", TensorProto.FLOAT, None)],
        [helper.make_tensor_value_info("c_out", TensorProto.BOOL, []),
         helper.make_tensor_value_info("v_out", TensorProto.FLOAT, None)]
        + ([helper.make_tensor_value_info("q", TensorProto.FLOAT, None)] if padded else []))
    inits += [helper.make_tensor("pads", TensorProto.INT64, [8], [0, 0, 1, 1, 0, 0, 1, 1]),
              helper.make_tensor("three", TensorProto.FLOAT, [], [3.0])]
    outs = ["y"] + (["qs"] if padded else [])
    loop = helper.make_node("Loop", ["trips", "cond", "x"], outs, name="/kernels/loop", body=body)
    g = helper.make_graph([loop], "t", [x], [y] + ([helper.make_tensor_value_info("qs", TensorProto.FLOAT, None)]
                                                    if padded else []), inits)
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])


@pytest.mark.parametrize("trips", [1, 4])
def test_flops_inside_a_loop_count_every_iteration_and_the_branch_taken(trips):
    """A Loop body's nodes count once per iteration, an If's only in the branch it took, at the
    shapes they ran at, in the stage of the Loop; nothing is left uncounted."""
    c = count_flops(_loop_model(trips), width=5, height=4, stages=["kernels"])
    n = 3 * 4 * 5
    assert not c.uncounted
    assert c.per_op["Add"]["flops"] == trips * n
    assert c.per_op.get("Mul", {"flops": 0})["flops"] == (trips - 1) * n
    assert c.per_op["Equal"]["flops"] == trips      # a scalar compare per iteration
    assert c.flops == c.per_stage["kernels"]["flops"] == (2 * trips - 1) * n + trips


def test_flops_inside_a_loop_at_a_large_size_come_from_two_small_runs_only_where_exact(monkeypatch):
    """Above PROFILE_PIXELS the body is profiled at two smaller sizes of the frame's aspect and
    carried to the full size where that is exact: counts proportional to the pixel count, and
    scalars'. A node whose cost is not (a padded tensor's) sends the count to the full size."""
    from mcdenoise.training import flops

    monkeypatch.setattr(flops, "PROFILE_PIXELS", 16)
    monkeypatch.setattr(flops, "PROFILE_MIN_PIXELS", 4)
    runs = []
    real = flops._profiled_costs
    monkeypatch.setattr(flops, "_profiled_costs", lambda m, w, h, *a: runs.append((w, h)) or real(m, w, h, *a))
    w, h, trips = 12, 8, 3
    c = count_flops(_loop_model(trips), width=w, height=h, stages=["kernels"])
    assert runs == [(3, 2), (6, 4)]           # W/d x H/d for the two largest divisors d of gcd(12, 8)
    assert c.per_op["Add"]["flops"] == trips * 3 * w * h and c.per_op["Equal"]["flops"] == trips
    assert c.per_op["Mul"]["flops"] == (trips - 1) * 3 * w * h
    runs.clear()
    c = count_flops(_loop_model(trips, padded=True), width=w, height=h, stages=["kernels"])
    assert runs == [(3, 2), (6, 4), (12, 8)]
    assert c.flops == (2 * trips - 1) * 3 * w * h + trips + trips * 3 * (w + 2) * (h + 2)


def test_flops_of_anf_count_its_taps_at_the_kernel_size_setting():
    """ANF's taps are a Loop over kernel_size² taps (the spatial kernels skip the centre): one
    exp per pixel per tap, so Exp's count is H·W·(K·(k²−1) + k²) at each kernel size k, and
    the kernels stage is counted, not left out."""
    from mcdenoise.training.models.anf import ANFParams
    from mcdenoise.training.specs import load_spec

    path = next(p for p in shipped_models() if p.endswith("anf-s.onnx"))
    kernels = load_spec("anf-s").params_as(ANFParams).kernels
    w, h = 12, 8
    got = {}
    for k in (3, 5):
        c = count_flops(path, w, h, settings={"kernel_size": k})
        assert not c.uncounted
        assert c.per_op["Exp"]["flops"] == w * h * (kernels * (k * k - 1) + k * k)
        got[k] = c.per_stage["kernels"]["flops"]
    assert got[5] > 2 * got[3] > 0


def test_flops_of_a_model_conv_layers():
    path = next(p for p in shipped_models() if p.endswith("wskpn-3.onnx"))
    model = onnx.load(path)
    w, h = 96, 64
    c = count_flops(model, w, h)
    inits = {i.name: tuple(i.dims) for i in model.graph.initializer}
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    assert convs
    # stride-1 'same' convolutions: FMAs = H*W*Cout*Cin*kh*kw, read off the weight shapes
    expected = sum(h * w * int(np.prod(inits[n.input[1]])) for n in convs)
    assert c.per_op["Conv"]["fmas"] == expected == c.fmas
    assert c.params == sum(int(np.prod(inits[n.input[k]])) for n in convs for k in (1, 2) if len(n.input) > k)
    assert set(c.per_stage) == {"prediction", "reconstruction"}  # the driver accumulates the colour
    assert sum(v["flops"] for v in c.per_stage.values()) == c.flops
    assert not c.uncounted
    # doubling the pixel count doubles the count (but for a few per-frame scalar ops)
    c2 = count_flops(model, 2 * w, h)
    assert c2.fmas == 2 * c.fmas and 0 <= 2 * c.flops - c2.flops < 16


def test_oidn_unet_count_and_peak():
    c = harness.oidn_unet_count(1280, 720)
    # hand sum of the published layer table, FMAs per full-resolution pixel / 9:
    # full 8128 + half 13824/4 + quarter 27648/16 + eighth 35584/64 + sixteenth 16896/256
    assert c["fmas"] == 9 * (1280 * 720 * 8128 + 640 * 360 * 13824 + 320 * 180 * 27648
                             + 160 * 90 * 35584 + 80 * 45 * 16896)
    assert c["padded"] == "1280x720" and harness.oidn_unet_count(100, 50)["padded"] == "112x64"
    p = cpu_peak(threads=2)
    assert p["cores"] == 2 and p["flops_per_cycle"] in (8, 16, 32, 64)


def test_flops_of_an_nbg_graph_with_data_dependent_grid_sizes(tmp_path):
    # NBG's grid sizes are computed from H and W inside the graph: static inference cannot
    # size the splat, so the counter runs the graph once for those shapes.
    import torch

    from mcdenoise.export.onnx_export import export_model
    from mcdenoise.training.specs import build_model, load_spec

    torch.manual_seed(0)
    spec = load_spec("nbg-2l-3g")
    path = tmp_path / "nbg.onnx"
    export_model(spec, build_model(spec).eval(), path)
    w, h = 64, 48
    c = count_flops(str(path), w, h)
    assert not c.uncounted
    assert set(c.per_stage) == set(spec.stages)
    model = onnx.load(str(path))
    inits = {i.name: tuple(i.dims) for i in model.graph.initializer}
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    assert c.per_op["Conv"]["fmas"] == sum(h * w * int(np.prod(inits[n.input[1]])) for n in convs)
    # the splat's block MatMuls: per grid, 4 spatial corners x (padded pixels) x D range cells
    # x 4 channels (irradiance and the weight)
    from mcdenoise.training.models.nbg import NBGParams, grid_shape
    params = spec.params_as(NBGParams)
    want = 0
    for s in range(params.grids):
        rates = params.scale_rates(s)
        d, hg, wg = grid_shape(h, w, rates)
        want += 4 * (hg - 1) * rates[0] * (wg - 1) * rates[1] * d * 4
    assert c.per_op["MatMul"]["fmas"] == want and "ScatterElements" not in c.per_op


def test_cuda_bench_says_clearly_when_there_is_no_cuda_provider(tmp_path, capsys):
    import onnxruntime as ort

    rc = cli_main(["bench", "--device", "cuda", "--quick", "--no-torch", "--methods", "noisy",
                   "--sizes", "32x32", "--chart-size", "32x32", "--frames", "1", "--warmup", "0",
                   "--out", str(tmp_path)])
    if "CUDAExecutionProvider" in ort.get_available_providers():   # onnxruntime-gpu on a GPU host
        assert rc == 0 and (tmp_path / "bench.md").exists()
    else:
        assert rc == 2
        err = capsys.readouterr().err
        assert "no CUDA provider" in err and "onnxruntime-gpu" in err and "Traceback" not in err


def test_two_files_of_one_spec_are_refused_by_name(tmp_path, capsys):
    """bench and evaluate report methods by spec name: two exports of one spec would be pooled
    into one row (it crashed on mismatched shapes before), so both refuse, naming both files."""
    import shutil

    src = next(p for p in shipped_models() if p.endswith("wskpn-3.onnx"))
    a, b = tmp_path / "a.onnx", tmp_path / "b.onnx"
    shutil.copy(src, a)
    shutil.copy(src, b)
    for argv in (["bench", str(a), str(b), "--quick", "--no-torch", "--methods", "noisy",
                  "--out", str(tmp_path / "out")],
                 ["evaluate", str(a), str(b), "--data", str(tmp_path)]):
        assert cli_main(argv) == 2, argv[0]
        err = capsys.readouterr().err
        assert str(a) in err and str(b) in err and "'wskpn-3'" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_score_pools_frames_of_several_sizes():
    """evaluate's score: frames of one size give the metrics of their stacks exactly; frames
    of several sizes pool as one size does (PSNR/SMAPE/relMSE over all pixels, SSIM over all
    window positions, FLIP over all pixels) and TRMAE runs over equal-sized frames."""
    from mcdenoise.training import metrics
    from mcdenoise.training.scoring import score

    rng = np.random.default_rng(3)

    def img(h, w):
        return rng.random((h, w, 3), dtype=np.float32) * 2

    a_out, a_ref = [img(20, 24) for _ in range(3)], [img(20, 24) for _ in range(3)]
    one = score(a_out, a_ref, [3])
    so, sr = np.stack(a_out), np.stack(a_ref)
    assert one == {"psnr": metrics.psnr(so, sr), "ssim": metrics.ssim(so, sr), "flip": metrics.flip(so, sr),
                   "smape": metrics.smape(so, sr), "relmse": metrics.relmse(so, sr),
                   "trmae": metrics.trmae(so, sr), "wte": None, "frames": 3}   # wte needs the frames
    # A second sequence that changes size after two frames; its last frame is exact, so it
    # pulls SSIM to 1 and FLIP to 0 in proportion to its window positions and pixels.
    b_out, b_ref = [img(16, 30), img(16, 30), img(14, 12)], [img(16, 30), img(16, 30), None]
    b_ref[2] = b_out[2].copy()
    mixed = score(a_out + b_out, a_ref + b_ref, [3, 3])
    flat = metrics.pixels
    assert mixed["psnr"] == metrics.psnr(flat(a_out + b_out), flat(a_ref + b_ref))
    assert mixed["smape"] == metrics.smape(flat(a_out + b_out), flat(a_ref + b_ref))
    win = {(20, 24): 3 * 10 * 14, (16, 30): 2 * 6 * 20, (14, 12): 1 * 4 * 2}
    ssims = {(20, 24): one["ssim"], (16, 30): metrics.ssim(np.stack(b_out[:2]), np.stack(b_ref[:2])), (14, 12): 1.0}
    assert mixed["ssim"] == pytest.approx(sum(ssims[k] * n for k, n in win.items()) / sum(win.values()), rel=1e-12)
    flips = {(20, 24): (one["flip"], 3 * 480), (16, 30): (metrics.flip(np.stack(b_out[:2]), np.stack(b_ref[:2])), 2 * 480),
             (14, 12): (0.0, 168)}
    assert mixed["flip"] == pytest.approx(sum(v * n for v, n in flips.values()) / sum(n for _, n in flips.values()), rel=1e-12)
    # TRMAE: sequence a, and b's first two frames (its third is a run of one: no derivative).
    want = np.mean([one["trmae"], metrics.trmae(np.stack(b_out[:2]), np.stack(b_ref[:2]))])
    assert mixed["trmae"] == pytest.approx(want, rel=1e-12) and mixed["frames"] == 6
    with pytest.raises(ValueError, match="frame 1 is"):
        score([img(20, 24), img(20, 24)], [img(20, 24), img(20, 22)], [2])


def test_evaluate_scores_after_a_warmup_and_with_another_alpha(tiny_dataset, tmp_path, capsys):
    import json

    wskpn = next(p for p in shipped_models() if p.endswith("wskpn-3.onnx"))
    out = tmp_path / "e.json"
    for alpha in ("0.2", "1"):
        assert cli_main(["evaluate", wskpn, "--data", tiny_dataset, "--spp", "1", "--warmup", "1", "--alpha", alpha,
                         "--no-oidn", "--json", str(out)]) == 0
        res = json.loads(out.read_text())
        assert res["_setup"]["warmup"] == 1 and res["_setup"]["accumulate_alpha"] == float(alpha)
        a = res["wskpn-3"]["after_warmup"]
        assert a["frames"] == res["wskpn-3"]["frames"] - 2 and np.isfinite(a["psnr"]) and a["wte"] > 0
        if alpha == "0.2":
            low = res["wskpn-3"]["after_warmup"]["psnr"]
    assert a["psnr"] != low                 # the weight changed what the history gave
    assert "after warm-up" in capsys.readouterr().out
    assert cli_main(["evaluate", wskpn, "--data", tiny_dataset, "--alpha", "0", "--no-oidn"]) == 2


def test_evaluate_scores_each_model_without_its_history_beside_it(tiny_dataset, tmp_path):
    import json

    wskpn = next(p for p in shipped_models() if p.endswith("wskpn-3.onnx"))
    ndle = next(p for p in shipped_models() if "ndle-s" in p)
    out = tmp_path / "e.json"
    assert cli_main(["evaluate", wskpn, "--data", tiny_dataset, "--no-oidn", "--json", str(out)]) == 0
    plain = json.loads(out.read_text())
    assert cli_main(["evaluate", wskpn, ndle, "--data", tiny_dataset, "--no-oidn", "--no-history",
                     "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    # ndle-s keeps no history: nothing to reset, no second row.
    assert sorted(k for k in res if k != "_setup") == ["ndle-s", "noisy", "wskpn-3", "wskpn-3 (no history)"]
    # The reset copy is its own driver: the model's row is what it is without the flag...
    assert res["wskpn-3"] == plain["wskpn-3"]
    # ...and the history changed what the frames after the first look like.
    assert res["wskpn-3 (no history)"]["frames"] == res["wskpn-3"]["frames"]
    assert res["wskpn-3 (no history)"]["psnr"] != res["wskpn-3"]["psnr"]
    # What reports read back: the rows with history, after warm-up where a file has it.
    from mcdenoise.training.evaluate import load_results

    assert load_results(out) == {k: res[k] for k in ("ndle-s", "noisy", "wskpn-3")}
    assert load_results(tmp_path / "not-made-yet.json") == {}
    later = dict(res["wskpn-3"], psnr=99.0)
    out.write_text(json.dumps({"_setup": {}, "wskpn-3": dict(res["wskpn-3"], after_warmup=later)}))
    assert load_results(out) == {"wskpn-3": later}
    assert load_results(out, after_warmup=False)["wskpn-3"]["psnr"] == res["wskpn-3"]["psnr"]
