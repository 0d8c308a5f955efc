"""The onnxruntime driver: temporal state, parity with the training unroll, bad input.

Uses a randomly initialised (seeded) wskpn-3 exported to ONNX: behaviour, not quality, is
under test here.  Parity: the driver (numpy reprojection + onnxruntime) and the training
unroll (torch reprojection + torch model) give the same output for the same 2-frame sequence.
"""
import os

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from mcdenoise.runtime.denoiser import Denoiser, ModelFileError
from mcdenoise.runtime.frames import Frame, FrameError, read_frame, read_rgb
from mcdenoise.runtime.writers import write_frame
from mcdenoise.runtime.inputs import frame_inputs
from mcdenoise.training.methods import shipped_models
from mcdenoise.training.harness import synthetic_frame

SPEC = "wskpn-3"
#: The driver's two kinds of temporal state: wskpn-3's colour is accumulated by the driver
#: ([[accumulate]]), nbg-2l-1g carries a model state (prev_accum / next_accum / history);
#: wskpn-6e-aa accumulates two layers (colour and albedo), the second at a fixed weight.
TEMPORAL_SPECS = [SPEC, "nbg-2l-1g", "wskpn-6e-aa"]


@pytest.fixture(scope="module", params=TEMPORAL_SPECS)
def model_file(tmp_path_factory, request):
    from mcdenoise.export.onnx_export import export_model
    from mcdenoise.training.specs import build_model, load_spec

    torch.manual_seed(0)
    spec = load_spec(request.param)
    model = build_model(spec).eval()
    path = tmp_path_factory.mktemp("model") / f"{request.param}.onnx"
    export_model(spec, model, path)
    return path, spec, model


def _frame(t, w=24, h=20, spp=2, **kw):
    f = synthetic_frame(w, h, t, spp=spp)   # with samples: shipped per-sample models read them
    f.update(kw)
    return Frame(**f)


def test_denoise_shapes_and_state(model_file):
    path, _, _ = model_file
    den = Denoiser.load(path, log=lambda m: None)
    out0 = den(_frame(0))
    assert out0.shape == (20, 24, 3) and out0.dtype == np.float32 and np.isfinite(out0).all()
    out1 = den(_frame(1))
    fresh = Denoiser.load(path, log=lambda m: None)
    alone = fresh(_frame(1))
    # The history from frame 0 changes frame 1's result; after reset() it no longer does.
    assert np.abs(out1 - alone).max() > 1e-4
    den.reset()
    np.testing.assert_allclose(den(_frame(1)), alone, rtol=1e-5, atol=1e-6)


def test_driver_matches_training_unroll(model_file):
    """Same two frames through the runtime driver and through training.train.run_window (the
    batch's spp, as the dataset gives it: the accumulation weight depends on it)."""
    from mcdenoise.training.train import run_window

    path, spec, model = model_file
    den = Denoiser.load(path, log=lambda m: None)
    frames = [_frame(0), _frame(1)]
    outs = [den(f) for f in frames]
    batch = {}
    for f in frames:
        arrays = frame_inputs(f, list(spec.inputs.layers) + ["motion", "position"])
        arrays["normal_world"] = f.normal.transpose(2, 0, 1)[None].copy()
        for k, v in arrays.items():
            batch.setdefault(k, []).append(torch.from_numpy(v))
    batch = {k: torch.stack(v, dim=1) for k, v in batch.items()}  # (1, T, C, H, W)
    batch["spp"] = torch.tensor([frames[0].color_spp])
    with torch.no_grad():
        ref = run_window(model, batch, spec.protocol)
    for t in range(2):
        np.testing.assert_allclose(outs[t], ref[t]["output"][0].numpy().transpose(1, 2, 0),
                                   rtol=1e-4, atol=1e-5)


def test_nonfinite_and_negative_input_is_sanitised_not_propagated(model_file):
    path, _, _ = model_file
    msgs = []
    den = Denoiser.load(path, log=msgs.append)
    f = _frame(0)
    f.color[0, 0] = np.nan
    f.color[1, 1] = np.inf
    f.color[2, 2] = -5.0
    f.albedo[3, 3] = np.nan
    out = den(f)
    assert np.isfinite(out).all()
    assert all(np.isfinite(v).all() for v in den._state.values())
    assert den.report.sanitized_frames == 1 and any("non-finite" in m for m in msgs)
    out2 = den(_frame(1))
    assert np.isfinite(out2).all()
    # broken guides and motion of a frame with history: reported, never in the state
    f3 = _frame(2)
    f3.motion[4, 4] = np.nan
    f3.position[5, 5] = -np.inf
    msgs.clear()
    out3 = den(f3)
    assert np.isfinite(out3).all() and all(np.isfinite(v).all() for v in den._state.values())
    assert den.report.sanitized_frames == 2
    assert any("non-finite values in motion" in m and "non-finite values in position" in m for m in msgs)


def test_missing_layer_and_wrong_shape_are_named(model_file):
    path, _, _ = model_file
    den = Denoiser.load(path, log=lambda m: None)
    f = _frame(0)
    f.albedo = None
    with pytest.raises(FrameError, match="missing layer 'albedo'"):
        den(f)
    g = _frame(0)
    g.depth = np.zeros((20, 24, 2), np.float32)
    with pytest.raises(FrameError, match="layer 'depth' has shape"):
        den(g)
    with pytest.raises(FrameError, match="expected a Frame"):
        den("not a frame")


def test_resolution_change_resets_state_and_says_so(model_file):
    path, _, _ = model_file
    msgs = []
    den = Denoiser.load(path, log=msgs.append)
    den(_frame(0))
    den(_frame(1))
    out = den(_frame(2, w=32, h=16))
    assert out.shape == (16, 32, 3)
    assert len(den.report.resets) == 1 and "resolution changed from 24x20 to 32x16" in den.report.resets[0][1]
    fresh = Denoiser.load(path, log=lambda m: None)
    np.testing.assert_allclose(out, fresh(_frame(2, w=32, h=16)), rtol=1e-5, atol=1e-6)


def test_camera_cut_resets(model_file):
    path, _, _ = model_file
    den = Denoiser.load(path, log=lambda m: None)
    den(_frame(0))
    cut = _frame(1, meta={"cut": True})
    out = den(cut)
    assert den.report.resets and den.report.resets[-1][1] == "camera cut"
    fresh = Denoiser.load(path, log=lambda m: None)
    np.testing.assert_allclose(out, fresh(_frame(1)), rtol=1e-5, atol=1e-6)


def test_foreign_corrupt_and_missing_model_files(tmp_path):
    with pytest.raises(ModelFileError, match="no such model file"):
        Denoiser.load(tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"\x08\x07garbage" * 10)
    with pytest.raises(ModelFileError, match="not a loadable ONNX model"):
        Denoiser.load(tmp_path / "junk.onnx")
    # A valid ONNX file that is not ours.
    from onnx import TensorProto, helper

    g = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    onnx.save(helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]), tmp_path / "other.onnx")
    with pytest.raises(ModelFileError, match="not an mcdenoise model"):
        Denoiser.load(tmp_path / "other.onnx")


@pytest.mark.parametrize("profile", [False, True])
def test_truncated_model_file(model_file, tmp_path, capfd, profile):
    """One clear error, and nothing from onnxruntime on stderr (a profiled session that
    failed to load logged its profiler's complaint there)."""
    path, _, _ = model_file
    data = path.read_bytes()
    (tmp_path / "cut.onnx").write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="cut.onnx: not a loadable ONNX model"):
        Denoiser.load(tmp_path / "cut.onnx", profile=profile)
    import gc

    gc.collect()
    assert capfd.readouterr().err == ""


def test_stage_times_cover_graph_stages(model_file):
    path, spec, _ = model_file
    den = Denoiser.load(path, profile=True, log=lambda m: None)
    for t in range(3):
        den(_frame(t))
    rows = den.stage_times()
    assert len(rows) == 3
    for stage in spec.stages:
        assert all(stage in r for r in rows)
    assert sum(rows[-1][s] for s in spec.stages) > 0
    table = den.stage_table()
    for stage in ("preprocess", "reproject", "total") + tuple(spec.stages):
        assert stage in table


@pytest.mark.parametrize("path", shipped_models(), ids=os.path.basename)
def test_stage_table_charges_each_conv_to_its_own_stage(path):
    """onnxruntime renames fused nodes after their last output (a conv fused with a clamp that
    belongs to the next stage would be charged to that stage): per stage, the profile must
    count as many Conv kernels as the graph has Conv nodes in that stage's scope. A conv fused
    with its activation runs as FusedConv (seen on AVX2 EPYC hosts, not on AVX-512 Xeons)."""
    import collections

    from mcdenoise.runtime import timing

    den = Denoiser.load(path, profile=True, log=lambda m: None)
    stages = den.graph_stages
    want = collections.Counter(next(s for s in stages if n.name.startswith(f"/{s}/"))
                               for n in onnx.load(path).graph.node if n.op_type == "Conv")
    den(_frame(0, 32, 24))
    got = collections.Counter(stage for _, op, stage in timing.node_stages(den.session.end_profiling(), stages)
                              if op in ("Conv", "FusedConv"))
    assert want and got == want


def test_denoise_command_on_a_sequence(model_file, tmp_path):
    from mcdenoise.runtime.cli import main

    path, _, _ = model_file
    seq = tmp_path / "seq"
    seq.mkdir()
    for t in range(3):
        f = _frame(t)
        f.reference = f.albedo.copy()
        write_frame(seq / f"frame_{t:04d}.exr", f)
    out = tmp_path / "out"
    assert main(["denoise", "--model", str(path), "--input", str(seq), "--output", str(out), "--png"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"frame_{t:04d}.{e}" for t in range(3) for e in ("exr", "png")]
    assert main(["denoise", "--model", str(tmp_path / "nope.onnx"), "--input", str(seq),
                 "--output", str(out)]) == 2


def test_denoise_command_across_resolutions(model_file, tmp_path, capsys):
    """A sequence that changes resolution mid-way and a second sequence at a third size: the
    command resets the state (said once), scores PSNR over all pixels of all frames, and
    times only the frames at one resolution, saying how many it left out."""
    import json

    from mcdenoise.runtime.cli import main
    from mcdenoise.runtime.denoise import run
    from mcdenoise.training.metrics import psnr

    path, _, _ = model_file
    sizes = {"a": [(24, 20), (24, 20), (24, 20), (30, 16)], "b": [(18, 22)]}
    for seq, wh in sizes.items():
        (tmp_path / seq).mkdir()
        for t, (w, h) in enumerate(wh):
            f = _frame(t, w, h)
            f.reference = f.albedo.copy()
            write_frame(tmp_path / seq / f"frame_{t:04d}.exr", f)
    msgs = []
    res = run(str(path), str(tmp_path), str(tmp_path / "out"), log=msgs.append)
    assert res["frame_sizes"] == [list(s) for s in sizes["a"] + sizes["b"]]
    assert res["stage_median_size"] == [24, 20]
    assert any("median over 2 frames at 24x20 (2 frames at other sizes left out)" in m for m in msgs)
    assert [r for _, r in res["resets"]].count("resolution changed from 24x20 to 30x16") == 1
    outs, refs = [], []
    for seq, wh in sizes.items():
        for t in range(len(wh)):
            outs.append(read_rgb(tmp_path / "out" / seq / f"frame_{t:04d}.exr"))
            refs.append(read_frame(tmp_path / seq / f"frame_{t:04d}.exr").reference)
    from mcdenoise.training.metrics import pixels as flat
    assert res["psnr_db"] == pytest.approx(psnr(flat(outs), flat(refs)), rel=1e-9)
    # ... and each frame's pixels count once: not the mean of per-frame or per-size PSNRs.
    assert res["psnr_db"] != pytest.approx(np.mean([psnr(o, r) for o, r in zip(outs, refs)]), rel=1e-6)
    assert main(["denoise", "--model", str(path), "--input", str(tmp_path / "a"),
                 "--output", str(tmp_path / "out2"), "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["stage_median_size"] == [24, 20]


def test_denoise_command_on_plain_images(model_file, tmp_path, capsys):
    """A plain colour image (the Open Image Denoise convention) with the albedo, normal and
    depth images a model needs gives the driver's image of the same frame; without them the
    command names the flags to give, in one line."""
    from mcdenoise.runtime.cli import main
    from mcdenoise.runtime.writers import write_rgb

    path, spec, _ = model_file
    f = _frame(0)
    others = [n for n in spec.inputs.layers if n not in ("color", "albedo")]
    for n in ["color", "albedo"] + others:
        v = getattr(f, n)
        write_rgb(tmp_path / f"{n}.exr", v if v.shape[-1] == 3 else np.repeat(v, 3, axis=-1))
    args = ["denoise", "--model", str(path), "--input", str(tmp_path / "color.exr"), "--output", str(tmp_path / "o")]
    assert main(args + ["--albedo", str(tmp_path / "albedo.exr")]) == 2
    flags = " ".join(f"--{n} FILE" for n in others)
    assert f"needs {', '.join(others)} beside the colour: give {flags}" in capsys.readouterr().err
    assert main(args + ["--albedo", str(tmp_path / "albedo.exr")]
                + [a for n in others for a in (f"--{n}", str(tmp_path / f"{n}.exr"))]) == 0
    want = Denoiser.load(path, log=lambda m: None)(Frame(color=f.color, **{n: getattr(f, n) for n in ["albedo"] + others}))
    np.testing.assert_array_equal(read_rgb(tmp_path / "o" / "color.exr"), want)


def test_negative_model_output_is_clamped_and_counted(tmp_path):
    """A contract-carrying graph that returns -color: the driver must not hand out negative
    radiance, and says so."""
    from onnx import TensorProto, helper

    from mcdenoise.runtime.contract import Contract, contract_metadata

    io = {"layout": "NCHW", "transfer": "linear", "channels": 3}
    contract = Contract(version=1, spec_name="neg", model_type="test", spec_toml="", spec_hash="",
                        code_hash="", inputs=(dict(io, name="color", layer="color"),),
                        outputs=(dict(io, name="output"),),
                        stages=({"name": "prediction", "node_prefix": "/prediction/"},), state=(), history="")
    shape = ["n", 3, "h", "w"]
    g = helper.make_graph([helper.make_node("Neg", ["color"], ["output"], name="/prediction/Neg")], "neg",
                          [helper.make_tensor_value_info("color", TensorProto.FLOAT, shape)],
                          [helper.make_tensor_value_info("output", TensorProto.FLOAT, shape)])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    helper.set_model_props(m, contract_metadata(contract))
    onnx.save(m, tmp_path / "neg.onnx")
    msgs = []
    den = Denoiser.load(tmp_path / "neg.onnx", log=msgs.append)
    out = den(np.full((4, 5, 3), 2.0, np.float32))
    assert np.all(out == 0) and den.report.negative_output_values == 60
    assert any("negative" in m for m in msgs)


def test_nonfinite_albedo_does_not_black_out_the_pixel():
    # Demodulating models re-modulate by albedo: a broken albedo must not become 0 (black).
    shipped = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models", "wskpn-3.onnx")
    clean = Denoiser.load(shipped, log=lambda m: None)(_frame(0, 48, 40))
    broken = _frame(0, 48, 40)
    broken.albedo[10, 10] = np.nan
    out = Denoiser.load(shipped, log=lambda m: None)(broken)
    assert np.isfinite(out).all()
    assert (out[10, 10] > 0.3 * clean[10, 10]).all(), (out[10, 10], clean[10, 10])


def test_exposure_scale_values():
    from mcdenoise.runtime.inputs import AUTOEXPOSURE_KEY, exposure_scale

    grey = np.full((1, 3, 32, 48), 0.5, np.float32)
    assert exposure_scale(grey).shape == (1, 1, 1, 1)
    np.testing.assert_allclose(exposure_scale(grey).ravel(), AUTOEXPOSURE_KEY / 0.5, rtol=1e-5)
    # geometric mean of block means: half the 16x16 blocks at 0.02, half at 2 -> 0.2
    two = np.full((1, 3, 32, 32), 2.0, np.float32)
    two[:, :, :16] = 0.02
    np.testing.assert_allclose(exposure_scale(two).ravel(), AUTOEXPOSURE_KEY / 0.2, rtol=1e-5)
    # black blocks are left out; an all-black image keeps its exposure
    part = grey.copy()
    part[:, :, :16] = 0.0
    np.testing.assert_allclose(exposure_scale(part).ravel(), AUTOEXPOSURE_KEY / 0.5, rtol=1e-5)
    assert exposure_scale(np.zeros((2, 3, 8, 8), np.float32)).ravel().tolist() == [1.0, 1.0]
    rng = np.random.default_rng(0)
    x = rng.exponential(0.3, (2, 3, 40, 50)).astype(np.float32)
    np.testing.assert_allclose(exposure_scale(x * 1e-3), exposure_scale(x) * 1e3, rtol=1e-4)
    np.testing.assert_allclose(exposure_scale(torch.from_numpy(x)).numpy(), exposure_scale(x), rtol=1e-5)


def test_autoexposure_makes_output_independent_of_radiance_units():
    shipped = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models", "wskpn-3.onnx")

    def run(scale, auto=True):
        den = Denoiser.load(shipped, log=lambda m: None, autoexposure=auto)
        outs = []
        for t in range(3):
            f = _frame(t, 48, 40)
            f.color = f.color * np.float32(scale)
            outs.append(den(f) / np.float32(scale))
        return np.stack(outs)

    base = run(1.0)
    for scale in (1e-3, 1e3):
        np.testing.assert_allclose(run(scale), base, rtol=2e-3, atol=1e-6)
    # without it the network sees different inputs, and the result changes
    assert np.abs(run(1e-3, auto=False) - run(1.0, auto=False)).max() > 1e-2 * np.abs(base).max()


def test_denoise_command_device_and_autoexposure_flags(tmp_path, capsys):
    import onnxruntime as ort

    from mcdenoise.runtime.cli import main as cli_main

    assert cli_main(["denoise", "--output", str(tmp_path / "a"), "--no-autoexposure", "--no-profile"]) == 0
    rc = cli_main(["denoise", "--output", str(tmp_path / "b"), "--device", "cuda"])
    if "CUDAExecutionProvider" in ort.get_available_providers():
        assert rc == 0
    else:
        err = capsys.readouterr().err
        assert rc == 2 and "no CUDA provider" in err and "Traceback" not in err


@pytest.mark.parametrize("bad,kind", [(np.nan, "nonfinite"), (np.inf, "nonfinite"), (-np.inf, "nonfinite"),
                                      (-0.5, "negative"), (1e9, "clamped")])
def test_sanitize_catches_a_single_bad_value_of_each_kind(bad, kind):
    from mcdenoise.runtime.inputs import MAX_RADIANCE, SanitizeReport, sanitize_array

    arr = np.random.default_rng(0).random((5, 7, 3), dtype=np.float32)
    arr[3, 4, 1] = bad
    rep = SanitizeReport()
    out = sanitize_array(arr, True, "color", rep)
    assert getattr(rep, kind) == {"color": 1} and rep.total == 1
    assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= MAX_RADIANCE
    assert out[3, 4, 1] == (MAX_RADIANCE if kind == "clamped" else 0.0)
    k = 3 * 21 + 4 * 3 + 1                     # flat index of [3, 4, 1]
    np.testing.assert_array_equal(np.delete(out.ravel(), k), np.delete(arr.ravel(), k))
    # geometric layers keep negatives and large values; only non-finite ones are replaced
    rep2 = SanitizeReport()
    out2 = sanitize_array(arr, False, "position", rep2)
    assert rep2.total == (1 if kind == "nonfinite" else 0)
    assert out2[3, 4, 1] == (0.0 if kind == "nonfinite" else np.float32(bad))
    # the driver's path: planes with the extrema taken block by block, in a tall frame
    from mcdenoise.runtime.frames import Frame
    from mcdenoise.runtime.inputs import frame_planes

    tall = np.random.default_rng(1).random((153, 7, 3), dtype=np.float32)
    tall[140, 2, 0] = bad
    rep3 = SanitizeReport()
    planes = frame_planes(Frame(color=tall, position=tall.copy()), ["color", "position"], rep3)
    assert getattr(rep3, kind)["color"] == 1 and rep3.nonfinite.get("position", 0) == (kind == "nonfinite")
    assert planes["color"][0, 0, 140, 2] == (MAX_RADIANCE if kind == "clamped" else 0.0)
    want = sanitize_array(tall, False, "position", SanitizeReport()).transpose(2, 0, 1)
    np.testing.assert_array_equal(planes["position"][0], want)


@pytest.mark.parametrize("bad", [None, "nan", "negative", "huge", "just-above"])
def test_scaling_while_converting_equals_sanitising_then_scaling(bad):
    """frame_planes(scale=...) (the driver's exposure, applied during the layout change) gives
    the values and report of sanitising the raw layer and multiplying after, to the bit."""
    from mcdenoise.runtime.inputs import MAX_RADIANCE, SanitizeReport, frame_planes

    rng = np.random.default_rng(4)
    color = rng.random((37, 21, 3), dtype=np.float32) * 5
    value = {"nan": np.nan, "negative": -2.0, "huge": 1e30,
             "just-above": np.nextafter(np.float32(MAX_RADIANCE), np.float32(np.inf))}.get(bad)
    if value is not None:
        color[30, 4, 2] = value
    frame = Frame(color=color, albedo=color.copy())
    for s in (np.float32(0.37), np.float32(1e4), np.float32(3.3)):
        rep_a, rep_b = SanitizeReport(), SanitizeReport()
        a = frame_planes(frame, ["color", "albedo"], rep_a, scale={"color": s})
        b = frame_planes(frame, ["color", "albedo"], rep_b)
        np.testing.assert_array_equal(a["color"], b["color"] * s)
        np.testing.assert_array_equal(a["albedo"], b["albedo"])
        assert (rep_a.nonfinite, rep_a.negative, rep_a.clamped) == (rep_b.nonfinite, rep_b.negative, rep_b.clamped)
        assert (rep_a.total > 0) == (bad is not None)


def test_planes_round_trip_and_screen_normals_agree():
    from mcdenoise.runtime.inputs import from_planes, screen_normal_planes, screen_normals, to_planes

    rng = np.random.default_rng(1)
    img = rng.random((137, 21, 3), dtype=np.float32)   # not a multiple of the transpose block
    p = to_planes(img)
    assert p.shape == (1, 3, 137, 21) and p.flags.c_contiguous
    np.testing.assert_array_equal(p[0], img.transpose(2, 0, 1))
    np.testing.assert_array_equal(from_planes(p[0]), img)
    assert to_planes(img[..., :1]).shape == (1, 1, 137, 21)
    rot = np.eye(4)
    rot[:3, :3] = [[0.6, 0.0, -0.8], [0.0, 1.0, 0.0], [0.8, 0.0, 0.6]]
    meta = {"camera": {"to_world": rot.tolist()}}
    np.testing.assert_allclose(screen_normal_planes(p, meta)[0], screen_normals(img, meta).transpose(2, 0, 1),
                               rtol=0, atol=1e-6)
    assert screen_normal_planes(p, {}) is p


@pytest.mark.parametrize("split_min", [1, 1 << 30])
def test_from_planes_split_rows_give_the_same_image_and_extrema(monkeypatch, split_min):
    """The postprocess's layout change on two threads (rows split) or one: same image, and the
    extrema taken on the way see a NaN or a negative value in either half."""
    import mcdenoise.runtime.inputs as ri

    monkeypatch.setattr(ri, "SPLIT_MIN_VALUES", split_min)
    rng = np.random.default_rng(3)
    chw = rng.random((3, 33, 17), dtype=np.float32)
    want = (chw * np.float32(0.5)).transpose(1, 2, 0)
    for threads in (1, 2):
        ext = []
        np.testing.assert_array_equal(ri.from_planes(chw, np.float32(0.5), threads=threads, extrema=ext), want)
        assert ext == [chw.min(), chw.max()]
    for y, value in ((2, -3.0), (30, np.nan)):
        bad = chw.copy()
        bad[1, y, 4] = value
        ext = []
        ri.from_planes(bad, threads=2, extrema=ext)
        assert (np.isnan(ext[0]) and np.isnan(ext[1])) if np.isnan(value) else ext[0] == value


def test_driver_threads_do_not_change_the_output(model_file):
    """One, two or three driver threads: the same images, to the bit, over a sequence with
    history, a NaN and a negative value."""
    path, _, _ = model_file
    outs = {}
    for threads in (1, 2, 3):
        den = Denoiser.load(path, log=lambda m: None, driver_threads=threads)
        assert den.driver_threads == threads
        frames = [_frame(t, 40, 150) for t in range(3)]
        frames[1].color[5, 7, 1] = np.nan
        frames[2].color[9, 3, 0] = -4.0
        outs[threads] = ([den(f) for f in frames], den.report.sanitized_frames)
    ref = outs[1]
    assert ref[1] == 2
    for key, (images, sanitized) in outs.items():
        assert sanitized == 2, key
        for a, b in zip(ref[0], images):
            np.testing.assert_array_equal(a, b)


def test_driver_threads_across_resolution_changes(model_file):
    """A sequence whose resolution changes twice (new buffers, state reset each time) gives on
    two driver threads what one thread gives, to the bit."""
    path, _, _ = model_file
    frames = [_frame(t, 40, 64) for t in range(3)] + [_frame(t, 32, 48) for t in range(3, 6)] \
        + [_frame(t, 40, 64) for t in range(6, 8)]
    ref = Denoiser.load(path, log=lambda m: None, driver_threads=1)
    den = Denoiser.load(path, log=lambda m: None, driver_threads=2)
    for f in frames:
        np.testing.assert_array_equal(den(f), ref(f))
    assert len(den.report.resets) == len(ref.report.resets) == 2


def test_reused_input_buffers_never_overwrite_the_kept_guides(model_file, monkeypatch):
    """The driver reuses two sets of input planes; the previous frame's guides must reach the
    reprojection intact, also when the frame before failed half-way."""
    import mcdenoise.runtime.temporal as rt

    seen = []
    real = rt.reproject
    monkeypatch.setattr(rt, "reproject", lambda s, m, cur, prev, **kw: (
        seen.append({k: v.copy() for k, v in prev.items()}), real(s, m, cur, prev, **kw))[1])
    path, _, _ = model_file
    den = Denoiser.load(path, log=lambda m: None)
    frames = [_frame(t) for t in range(4)]
    den(frames[0])
    den(frames[1])
    bad = _frame(9)
    bad.albedo = bad.albedo[:, :, :2]          # wrong channel count: rejected, no state change
    with pytest.raises(FrameError):
        den(bad)
    den(frames[2])
    den(frames[3])
    assert len(seen) == 3
    for prev_frame, got in zip(frames[:3], seen):
        np.testing.assert_array_equal(got["position"][0], prev_frame.position.transpose(2, 0, 1))
        np.testing.assert_array_equal(got["depth"][0, 0], prev_frame.depth[..., 0])


@pytest.mark.parametrize("io_binding", [False, True])
def test_an_unflagged_cut_is_found_by_the_history_test_and_starts_a_new_history(model_file, io_binding):
    """A frame of other geometry without meta["cut"] (the stress test's unflagged cut): the
    history test keeps under CUT_HISTORY of its pixels, so the driver resets and denoises it as
    a new history's first frame, its exposure its own: the image of a fresh driver, to the bit;
    said once, and its sanitising counted once."""
    from mcdenoise.runtime.denoiser import CUT_HISTORY

    path, spec, _ = model_file
    assert spec.state or spec.accumulate              # both of model_file's specs keep a history
    msgs = []
    den = Denoiser.load(path, log=msgs.append, io_binding=io_binding)
    for t in range(3):
        den(_frame(t))
    def elsewhere(t):
        f = _frame(t)
        f.position = f.position + np.float32(50.0)          # other geometry, same screen
        f.depth = f.depth * np.float32(3.0)
        f.color = f.color * np.float32(20.0)                 # and another exposure
        f.meta.pop("cut", None)
        return f

    other = elsewhere(5)
    other.color[1, 2] = np.nan
    fresh = Denoiser.load(path, log=lambda m: None, io_binding=io_binding)(other)
    np.testing.assert_array_equal(den(other), fresh)
    assert len(den.report.resets) == 1 and "of the pixels (an unflagged camera cut)" in den.report.resets[0][1]
    assert sum("unflagged camera cut" in m for m in msgs) == 1 and den.report.sanitized_frames == 1
    assert CUT_HISTORY < 0.05
    den(elsewhere(6))                                       # and the new history goes on
    assert len(den.report.resets) == 1 and den._state is not None


@pytest.mark.parametrize("io_binding", [False, True])
def test_nonfinite_model_output_falls_back_to_the_input_and_resets(model_file, io_binding, monkeypatch):
    """Should the graph ever emit NaN/Inf, those pixels get the (sanitised) input colour in the
    caller's units, auto-exposure notwithstanding, the state is reset, and it is said; also
    with the output kept on the device (io_binding: the post graph's checks say so)."""
    import onnxruntime as ort

    import mcdenoise.runtime.denoiser as driver

    path, _, _ = model_file
    msgs = []
    den = Denoiser.load(path, log=msgs.append, io_binding=io_binding)
    frames = [_frame(t) for t in range(3)]
    for f in frames:
        f.color *= 37.0                        # far from the auto-exposure key: a factor != 1
    den(frames[0])
    assert den.exposure != 1.0
    real, real_bound = den.session.run, driver.run_bound

    def spoil(out):
        out[0, :, 2, 3] = np.nan
        out[0, 1, 4, 5] = np.inf
        return out

    def broken(names, feeds):
        outs = real(names, feeds)
        spoil(outs[0])
        return outs

    def broken_bound(session, feeds, device, host=()):
        named = real_bound(session, feeds, device, host)
        if session is den.session:
            o = named["output"]
            named["output"] = spoil(o) if isinstance(o, np.ndarray) else ort.OrtValue.ortvalue_from_numpy(spoil(o.numpy()))
        return named

    den.session.run = broken
    monkeypatch.setattr(driver, "run_bound", broken_bound)
    out = den(frames[1])
    monkeypatch.setattr(driver, "run_bound", real_bound)
    np.testing.assert_allclose(out[2, 3], frames[1].color[2, 3], rtol=1e-6)
    np.testing.assert_allclose(out[4, 5, 1], frames[1].color[4, 5, 1], rtol=1e-6)   # that value only
    assert np.isfinite(out).all() and den._state is None
    assert any("non-finite values; replaced by the input" in m for m in msgs)
    den.session.run = real
    assert np.isfinite(den(frames[2])).all() and den._state is not None


@pytest.mark.parametrize("path", shipped_models(), ids=os.path.basename)
def test_the_prelude_graph_gives_the_numpy_prelude(path):
    """The driver's reprojection and accumulation as the shipped prelude graph (what a device
    provider runs; exercised here on the CPU provider) gives the numpy prelude's images over a
    sequence with history, within float rounding."""
    frames = [_frame(t, 36, 52) for t in range(4)]
    a = Denoiser.load(path, log=lambda m: None, prelude="numpy")
    b = Denoiser.load(path, log=lambda m: None, prelude="graph")
    assert a.prelude is None and b.prelude is not None
    for f in frames:
        np.testing.assert_allclose(b(f), a(f), rtol=1e-5, atol=1e-6)
    assert b.report.frames == 4 and not b.report.resets


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_the_shipped_prelude_graphs_are_the_torch_prelude(k):
    """models/driver/prelude-<K>.onnx computes what runtime.temporal's torch path computes, at two
    sizes and channel counts other than the export's, non-finite kept values read as 0
    (regenerate: python -m mcdenoise.export.prelude --out models/driver)."""
    from mcdenoise.export.prelude import example
    from mcdenoise.runtime.prelude import PreludeGraph, outputs
    from mcdenoise.runtime.temporal import accumulate, reproject

    sess = PreludeGraph().session(k)
    for h, w, seed in ((17, 29, 1), (40, 23, 2)):
        f = example(k, h, w, seed, channels=[(2, 5, 1, 3)[(i + seed) % 4] for i in range(k)])
        f["prev0"][0, 0, 3, 4] = np.nan
        f["prev0"][0, -1, 5, 6] = np.inf
        t = {n: torch.from_numpy(v) for n, v in f.items()}
        cur = {g: t[f"cur_{g}"] for g in ("depth", "position", "normal")}
        old = {g: t[f"prev_{g}"] for g in ("depth", "position", "normal")}
        prev = [t[f"prev{i}"].nan_to_num(nan=0.0, posinf=0.0, neginf=0.0) for i in range(k)]
        warped, hist = reproject(prev, t["motion"], cur, old)
        got = sess.run(list(outputs(k)), f)
        for i in range(k):
            want = warped[i] + t["blend"][i] * (accumulate(t[f"current{i}"], warped[i], hist, t["alpha"][i]) - warped[i])
            np.testing.assert_allclose(got[i], want.numpy(), rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(got[-1], hist.numpy())


@pytest.mark.parametrize("path", shipped_models(), ids=os.path.basename)
def test_state_kept_on_the_device_gives_the_host_drivers_images(path):
    """io_binding=True (what a device provider gets by default; here on the CPU provider, with
    CPU OrtValues): the model's state outputs and the prelude graph's warped tensors stay
    onnxruntime values between frames, never numpy arrays, and the images equal the numpy
    driver's over a sequence with history, a frame without world positions (the graphs need
    them: that frame's kept values are fetched for the numpy path), a camera cut and a frame
    without motion vectors; the frame's layers are converted by the conversion graphs."""
    import onnxruntime as ort

    frames = [_frame(t, 36, 52) for t in range(5)]
    frames[2].position = None
    frames[3].meta["cut"] = True
    frames[4].motion = None
    host = Denoiser.load(path, log=lambda m: None, prelude="numpy")
    bound = Denoiser.load(path, log=lambda m: None, io_binding=True)
    assert bound.prelude is not None and bound.io_binding
    assert bound._convert      # and, after a history's first frame, the layers converted on the device
    for i, f in enumerate(frames):
        np.testing.assert_allclose(bound(f), host(f), rtol=1e-5, atol=1e-6)
        # a history's first frame keeps its own inputs, and the numpy path's frame its results
        if bound.protocol.temporal and i not in (0, 2, 3):
            assert bound._state and all(isinstance(v, ort.OrtValue) for v in bound._state.values())
    assert [r[1] for r in bound.report.resets] == [r[1] for r in host.report.resets] == ["camera cut"]


@pytest.mark.parametrize("scale", [1.0, 0.37])
def test_the_conversion_graphs_give_the_numpy_planes_and_counts(scale):
    """models/driver/convert.onnx and screen.onnx (what a device provider converts a frame's
    layers with; here CPU values): the planes, the model inputs (screen-space normals) and the
    sanitising counts of runtime.inputs' numpy path, for layers with NaN, ±Inf, negative and
    huge values, at an exposure scale (regenerate: python -m mcdenoise.export.prelude --out models/driver)."""
    import onnxruntime as ort

    from mcdenoise.runtime.inputs import MAX_RADIANCE, SanitizeReport, frame_planes, model_inputs
    from mcdenoise.runtime.prelude import PreludeGraph

    fr = _frame(1, 29, 17)
    fr.color[2, 3] = [np.nan, -2.0, 7e5]
    fr.color[4, 5, 1] = np.inf
    fr.albedo[6, 7, 0] = np.nan
    fr.normal[1, 1] = [np.nan, 0.0, -np.inf]
    fr.depth[3, 3, 0] = -np.inf
    fr.color[8, 8] = MAX_RADIANCE * scale * (1 - 1e-7)     # on the scaled bound's edge
    names = ("color", "albedo", "normal", "depth", "position", "motion")
    layers = ("color", "albedo", "normal", "depth")
    a, b = SanitizeReport(), SanitizeReport()
    want = frame_planes(fr, names, a, scale=None if scale == 1 else {"color": np.float32(scale)})
    want_inputs = model_inputs(want, layers, fr.meta)
    planes, inputs = PreludeGraph(device=("cpu", 0)).convert(fr, names, layers, b, scale)
    assert all(isinstance(v, ort.OrtValue) for v in (*planes.values(), *inputs.values()))
    for name in names:
        np.testing.assert_array_equal(planes[name].numpy(), want[name])
    for name in layers:
        np.testing.assert_allclose(inputs[name].numpy(), want_inputs[name], rtol=1e-6, atol=1e-7)
    assert (b.nonfinite, b.negative, b.clamped) == (a.nonfinite, a.negative, a.clamped)
    assert b.nonfinite == {"color": 2, "albedo": 1, "normal": 2, "depth": 1} and b.clamped == {"color": 1}
    # and back: post.onnx gives from_planes' image, with a minimum and a sum that say what its
    # extrema say (a NaN or Inf makes the sum non-finite, whatever the minimum does with it)
    from mcdenoise.runtime.inputs import from_planes

    out = np.random.default_rng(3).normal(1.0, 0.5, (1, 3, 17, 29)).astype(np.float32)
    graph = PreludeGraph(device=("cpu", 0))
    for bad in (None, np.nan, np.inf):
        if bad is not None:
            out[0, 1, 2, 3] = bad
        ext: list = []
        want = from_planes(out[0], np.float32(scale), extrema=ext)
        image, (lo, total) = graph.post(ort.OrtValue.ortvalue_from_numpy(out), np.float32(scale))
        np.testing.assert_array_equal(image, want)
        assert np.isfinite(total) == (bad is None) == bool(np.isfinite(ext).all())
        if bad is None:
            assert lo == ext[0] < 0


def test_accumulate_alpha_overrides_the_files_and_1_means_no_accumulation(model_file):
    """accumulate_alpha: a run-time weight for every accumulated input. At 1 the accumulation is
    the frame itself, so a model whose only history is its accumulated colour (wskpn) gives
    the images of the same model reset before every frame, to the bit (auto-exposure off: a
    reset would pick a new exposure at every frame)."""
    path, spec, _ = model_file
    frames = [_frame(t, 30, 44) for t in range(3)]
    one = Denoiser.load(path, log=lambda m: None, accumulate_alpha=1.0, autoexposure=False)
    assert all(a[2] == 1.0 for a in one.protocol.accumulate)
    if spec.accumulate and not spec.state:
        fresh = Denoiser.load(path, log=lambda m: None, autoexposure=False)
        for f in frames:
            fresh.reset()
            np.testing.assert_array_equal(one(f), fresh(f))
    half = Denoiser.load(path, log=lambda m: None, accumulate_alpha=0.5)
    base = Denoiser.load(path, log=lambda m: None)
    outs = [(half(f), base(f)) for f in frames]
    if spec.accumulate:
        assert not np.allclose(*outs[-1])          # the weight reaches the frames with history
    np.testing.assert_array_equal(*outs[0])        # and nothing before there is a history
    with pytest.raises(ValueError, match="accumulate_alpha"):
        Denoiser.load(path, log=lambda m: None, accumulate_alpha=0.0)


def test_history_spp_weighs_each_frame_by_its_spp():
    """history_spp = 1: a 1-spp frame is blended as with accumulate_alpha 0.5, a 3-spp frame
    as with 0.75, to the bit; a frame whose spp is unknown (no samples, no spp in its
    metadata) keeps the file's fixed weight."""
    for path in [p for p in shipped_models() if p.endswith(("wskpn-3.onnx", "nbg-2l-1g.onnx"))]:
        _check_history_spp(path)


def _check_history_spp(path):
    """wskpn-3 accumulates its colour in the driver; nbg-2l-1g blends its state itself with
    the weight the driver feeds (accum_weight): one rule for both."""
    for spp, alpha in ((1, 0.5), (3, 0.75)):
        rule = Denoiser.load(path, log=lambda m: None, history_spp=1.0)
        fixed = Denoiser.load(path, log=lambda m: None, accumulate_alpha=alpha)
        for t in range(3):
            np.testing.assert_array_equal(rule(_frame(t, 30, 44, spp=spp)), fixed(_frame(t, 30, 44, spp=spp)))
    rule = Denoiser.load(path, log=lambda m: None, history_spp=1.0)
    base = Denoiser.load(path, log=lambda m: None)
    for t in range(3):
        np.testing.assert_array_equal(rule(_frame(t, 30, 44, spp=0)), base(_frame(t, 30, 44, spp=0)))
    assert _frame(0, spp=0).color_spp == 0 and _frame(0, spp=0, meta={"spp": 16}).color_spp == 16
    with pytest.raises(ValueError, match="history_spp"):
        Denoiser.load(path, log=lambda m: None, history_spp=-1.0)
