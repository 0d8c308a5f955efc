"""ONNX export of every spec: checker, onnxruntime and onnx.reference parity, contract metadata,
stage prefixes, run-folder export and the CLI."""
from __future__ import annotations

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx.reference import ReferenceEvaluator

from mcdenoise.export.onnx_export import (CHECK_SIZE, DARK_FRACTION, EXPORT_SIZE, FLOAT32_MARGIN, PARITY_TOL, ExportError,
                                adopt_protocol, export_model, export_run, parity_error, parity_errors, parity_ok, reexport,
                                unstaged_nodes)
from mcdenoise.runtime import contract as C
from mcdenoise.training import runs
from mcdenoise.training.models import example_inputs
from mcdenoise.training.specs import build_model, list_specs, load_spec, parse_spec, spec_hash

SPECS = list_specs()
#: Model type -> the stage that runs its neural network.
NETWORK_STAGE = {"wskpn": ("prediction",), "nbg": ("guide",), "anf": ("embedding", "unet"),
                 # NDLE: every stage holds a network (reducer, U-Net, partitioner, kernel generators)
                 "ndle": ("sample_reducer", "unet", "sample_partitioner", "layer_filtering")}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """spec name -> (spec, untrained model in eval mode, path of its ONNX export, report)."""
    out = {}
    d = tmp_path_factory.mktemp("onnx")
    for name in SPECS:
        spec = load_spec(name)
        torch.manual_seed(0)
        model = build_model(spec).eval()
        report = export_model(spec, model, d / f"{name}.onnx")
        out[name] = (spec, model, d / f"{name}.onnx", report)
    return out


def _session(path):
    so = ort.SessionOptions()
    so.intra_op_num_threads = 2
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def _torch(model, feeds):
    with torch.no_grad():
        return [o.numpy() for o in model(*[torch.from_numpy(feeds[n]) for n in model.input_names])]


def _assert_parity(errors):
    """Graph vs torch float64 within PARITY_TOL, or within FLOAT32_MARGIN x torch float32's
    own error where float32 cannot do better (cancellation); torch float32 itself is sane."""
    for name, (graph, torch32) in errors.items():
        assert graph <= max(PARITY_TOL, FLOAT32_MARGIN * torch32), (name, graph, torch32)
        assert torch32 < 1e-2, (name, torch32)
    assert parity_ok(errors)


def test_parity_error_definition():
    ref = np.array([1.0, 2.0, 1e-9, 0.0], np.float32)
    assert parity_error(ref, ref) == 0.0
    assert parity_error(ref * (1 + 1e-3), ref) == pytest.approx(1e-3, rel=1e-3)
    dark_floor = DARK_FRACTION * np.mean(np.abs(ref))
    test = ref.copy()
    test[3] = 0.5 * dark_floor  # a dark value off by half the floor
    assert parity_error(test, ref) == pytest.approx(0.5, rel=1e-3)
    assert parity_error(np.array([np.nan]), np.array([1.0])) == float("inf")


@pytest.mark.parametrize("name", SPECS)
def test_export_checks_pass(name, exported):
    spec, model, path, report = exported[name]
    assert CHECK_SIZE != EXPORT_SIZE
    onnx.checker.check_model(str(path), full_check=True)
    proto = onnx.load(str(path))
    assert proto.opset_import[0].version >= 17
    assert set(report.parity) == set(report.torch_float32) == set(model.output_names)
    _assert_parity({n: (report.parity[n], report.torch_float32[n]) for n in report.parity})


@pytest.mark.parametrize("name", SPECS)
def test_dynamic_axes(name, exported):
    _, model, path, _ = exported[name]
    sess = _session(path)
    assert [i.name for i in sess.get_inputs()] == list(model.input_names)
    assert [o.name for o in sess.get_outputs()] == list(model.output_names)
    settings = getattr(model, "settings", {})
    for t in (*sess.get_inputs(), *sess.get_outputs()):
        if t.name in settings:                       # an int64 scalar
            assert t.shape == [] and t.type == "tensor(int64)"
            continue
        if t.name in getattr(model, "state_weights", {}):   # a state's blend weight, per image
            assert isinstance(t.shape[0], str) and t.shape[1:] == [1, 1, 1]
            continue
        n, *s, c, h, w = t.shape                     # (N, S, F, H, W) for a per-sample input
        assert isinstance(n, str) and isinstance(h, str) and isinstance(w, str) and isinstance(c, int)
        assert all(isinstance(x, str) for x in s) and len(s) == (t.name == "samples")


@pytest.mark.parametrize("name", SPECS)
def test_onnxruntime_matches_torch_at_another_size(name, exported):
    """Odd size (neither export nor check size), batch 3: max relative error vs torch float64
    <= 1e-4 on values >= DARK_FRACTION·mean|ref| (dark values: absolute error <= 1e-4 · that
    floor), unless torch float32 itself is worse (see export.onnx_export)."""
    _, model, path, _ = exported[name]
    feeds = example_inputs(model, 3, 37, 29, seed=5)
    sess = _session(path)
    _assert_parity(parity_errors(model, lambda f: sess.run(list(model.output_names), f), feeds))
    for n, g, r in zip(model.output_names, sess.run(list(model.output_names), feeds), _torch(model, feeds)):
        assert g.shape == r.shape == (3, r.shape[1], 37, 29)
        assert np.mean(np.abs(r) >= DARK_FRACTION * np.mean(np.abs(r))) > 0.9  # mostly non-dark


@pytest.mark.parametrize("name", SPECS)
def test_reference_evaluator_matches_on_tiny_input(name, exported):
    """onnx.reference (a plain-numpy ONNX interpreter) agrees with torch and onnxruntime."""
    _, model, path, _ = exported[name]
    feeds = example_inputs(model, 1, 8, 12, seed=6)
    evaluator = ReferenceEvaluator(str(path))
    errors = parity_errors(model, lambda f: evaluator.run(list(model.output_names), f), feeds)
    _assert_parity(errors)
    ortv = _session(path).run(list(model.output_names), feeds)
    for n, g, o in zip(model.output_names, evaluator.run(list(model.output_names), feeds), ortv):
        assert g.shape == o.shape == (1, o.shape[1], 8, 12)
        # two float32 evaluations, each within its margin of float64 (see _assert_parity)
        assert parity_error(g, o) <= max(PARITY_TOL, 2 * FLOAT32_MARGIN * errors[n][1]), n


@pytest.mark.parametrize("name", SPECS)
def test_every_node_has_a_stage_prefix(name, exported):
    spec, _, path, _ = exported[name]
    graph = onnx.load(str(path)).graph
    assert unstaged_nodes(graph, spec.stages) == []
    for stage in spec.stages:  # each stage has compute of its own
        assert any(n.name.startswith(f"/{stage}/") for n in graph.node), stage
    assert sum(n.op_type == "Conv" for n in graph.node) > 0
    network = NETWORK_STAGE[spec.type]  # the network's convolutions are charged to its stages
    assert all(n.name.startswith(tuple(f"/{s}/" for s in network)) for n in graph.node if n.op_type == "Conv")


@pytest.mark.parametrize("name", SPECS)
def test_contract_round_trips(name, exported):
    spec, model, path, report = exported[name]
    meta = _session(path).get_modelmeta().custom_metadata_map
    assert all(k.startswith(C.PREFIX) for k in meta)
    con = C.parse_contract(meta)
    assert con.version == C.FORMAT_VERSION
    assert (con.spec_name, con.model_type) == (spec.name, spec.type)
    assert con.spec_toml == spec.raw and con.spec_hash == spec_hash(spec)
    assert spec_hash(parse_spec(con.spec_toml)) == con.spec_hash
    assert con.code_hash == runs.code_hash()
    # image inputs, then the int64 settings (ANF's kernel size), as the graph takes them
    assert con.input_names + [st["input"] for st in con.settings] == list(model.input_names)
    assert con.output_names == list(model.output_names)
    assert [st["name"] for st in con.settings] == [st.name for st in spec.setting]
    layers = {i["name"]: i["layer"] for i in con.inputs}
    assert [layers[l] for l in spec.inputs.layers] == list(spec.inputs.layers)
    assert all(i["layout"] == ("NSCHW" if i["name"] == "samples" else "NCHW") and i["transfer"] == "linear"
               for i in con.inputs)
    if spec.inputs.samples:
        assert [(g["group"], g["transfer"]) for g in con.samples_input["groups"]] == list(spec.inputs.sample_groups)
    if "color" in spec.inputs.layers:
        assert {i["name"]: i["channels"] for i in con.inputs}["color"] == 3
    assert con.stage_names == list(spec.stages)
    assert con.stage_of(f"/{spec.stages[-1]}/Mul_3") == spec.stages[-1] and con.stage_of("/other/Mul") is None
    assert [(s["name"], s["channels"], s["input"], s["output"]) for s in con.state] == \
        [(s.name, s.channels, f"prev_{s.name}", f"next_{s.name}") for s in spec.state]
    assert con.history == ("history" if spec.state else "")
    channels = {i["name"]: i["channels"] for i in con.inputs}
    assert [(a["layer"], a["input"], a["channels"], a["alpha"], a.get("history_spp", 0.0)) for a in con.accumulate] == \
        [(a.layer, a.layer, channels[a.layer], a.alpha, a.history_spp) for a in spec.accumulate]
    assert con.temporal == bool(spec.state or spec.accumulate)
    assert con.paper == dict(spec.paper)
    assert con.export["opset"] >= 17 and con.export["parity_max_rel_error"] == report.max_parity_error
    assert C.parse_contract(C.contract_metadata(con)) == con


def test_parse_contract_errors(exported):
    good = _session(next(iter(exported.values()))[2]).get_modelmeta().custom_metadata_map
    with pytest.raises(ValueError, match="not an mcdenoise model"):
        C.parse_contract({})
    with pytest.raises(ValueError, match="not an mcdenoise model"):
        C.parse_contract({"producer": "someone"})
    with pytest.raises(ValueError, match="newer than this mcdenoise reads"):
        C.parse_contract({**good, C.KEY_VERSION: str(C.FORMAT_VERSION + 1)})
    with pytest.raises(ValueError, match=r"lacks key\(s\) \['mcdenoise.stages'\]"):
        C.parse_contract({k: v for k, v in good.items() if k != C.KEY_STAGES})
    with pytest.raises(ValueError, match="'mcdenoise.inputs' is not valid JSON"):
        C.parse_contract({**good, C.KEY_INPUTS: "[{"})
    bad_layout = json.loads(good[C.KEY_INPUTS])
    bad_layout[0]["layout"] = "NHWC"
    with pytest.raises(ValueError, match="only NCHW"):
        C.parse_contract({**good, C.KEY_INPUTS: json.dumps(bad_layout)})


def test_parse_contract_checks_accumulate(exported):
    good = _session(exported["wskpn-3"][2]).get_modelmeta().custom_metadata_map
    acc = json.loads(good[C.KEY_ACCUMULATE])
    assert acc == [{"layer": "color", "input": "color", "channels": 3, "alpha": 0.2, "history_spp": 1.0}]
    assert C.parse_contract(good).version == 4
    for change, pattern in [({"input": "colour"}, "does not match the graph's inputs"),
                            ({"channels": 1}, "does not match the graph's inputs"),
                            ({"alpha": 0}, r"alpha of 'color' must be in \(0, 1\], got 0"),
                            ({"alpha": "0.2"}, r"must be in \(0, 1\], got '0.2'")]:
        with pytest.raises(ValueError, match=pattern):
            C.parse_contract({**good, C.KEY_ACCUMULATE: json.dumps([{**acc[0], **change}])})
    with pytest.raises(ValueError, match="accumulated twice"):
        C.parse_contract({**good, C.KEY_ACCUMULATE: json.dumps(acc * 2)})
    with pytest.raises(ValueError, match=r"'mcdenoise.accumulate'\[0\]: missing field\(s\) \['alpha'\]"):
        C.parse_contract({**good, C.KEY_ACCUMULATE: json.dumps([{k: v for k, v in acc[0].items() if k != "alpha"}])})
    # history_spp: a number >= 0, and only from format 4 on (a format-3 reader ignores it)
    fixed = json.dumps([{k: v for k, v in acc[0].items() if k != "history_spp"}])
    assert "history_spp" not in C.parse_contract({**good, C.KEY_VERSION: "3", C.KEY_ACCUMULATE: fixed}).accumulate[0]
    for bad, version, pattern in [(-1, "4", "history_spp of 'color' must be a number >= 0"),
                                  ("1", "4", "got '1'"), (1.0, "3", "in format 3")]:
        with pytest.raises(ValueError, match=pattern):
            C.parse_contract({**good, C.KEY_VERSION: version,
                              C.KEY_ACCUMULATE: json.dumps([{**acc[0], "history_spp": bad}])})
    # A format-1 file (before accumulation existed) has no such key: nothing accumulated.
    old = {k: v for k, v in good.items() if k != C.KEY_ACCUMULATE}
    assert C.parse_contract({**old, C.KEY_VERSION: "1"}).accumulate == ()


@pytest.mark.parametrize("name", SPECS)
def test_failed_parity_raises_and_leaves_no_file(name, tmp_path):
    """A deploy() that changes the function (a fusion bug) must fail the export."""
    spec = load_spec(name)
    torch.manual_seed(0)
    model = build_model(spec)
    honest = model.deploy

    # An untrained NDLE's kernels are near-uniform splats whose ratios cancel most of a change
    # of its first convolution (0.1% moves the output by 1e-5): there the bug is 5%.
    factor = 1.05 if spec.type == "ndle" else 1.001

    def broken_deploy():
        d = honest()
        conv = next(m for m in d.modules() if isinstance(m, torch.nn.Conv2d))
        with torch.no_grad():
            conv.weight.mul_(factor)
        return d

    model.deploy = broken_deploy
    with pytest.raises(ExportError, match="onnxruntime differs from torch"):
        export_model(spec, model, tmp_path / "m.onnx")
    assert list(tmp_path.iterdir()) == []


def test_ops_outside_stages_are_refused(tmp_path):
    spec = load_spec("wskpn-3")
    inner = build_model(spec).deploy()

    class Wrapped(torch.nn.Module):  # its ops run under "/inner/..." and at the top level
        def __init__(self):
            super().__init__()
            self.inner = inner
            self.input_names, self.output_names = inner.input_names, inner.output_names
            self.state_channels = inner.state_channels

        def forward(self, *x):
            return tuple(o * 1.5 for o in self.inner(*x))

    with pytest.raises(ExportError, match="outside every stage"):
        export_model(spec, Wrapped(), tmp_path / "w.onnx")
    assert not (tmp_path / "w.onnx").exists()


def test_opset_below_17_is_refused(tmp_path):
    spec = load_spec(SPECS[0])
    with pytest.raises(ValueError, match="opset must be >= 17"):
        export_model(spec, build_model(spec), tmp_path / "m.onnx", opset=16)


@pytest.mark.parametrize("name", SPECS)
def test_export_run_rebuilds_from_the_run_folder_only(name, tmp_path):
    """A run folder with perturbed (i.e. 'trained') weights and BN statistics: the export must
    reproduce exactly those, and carry the run's code hash."""
    spec = load_spec(name)
    torch.manual_seed(1)
    model = build_model(spec)
    with torch.no_grad():
        for p in model.parameters():
            # half each tensor's own spread (ANF's deep U-Net explodes under a fixed 0.05: its
            # parameters reach a·‖Δf‖² in the thousands, where float32 sums of any order differ)
            scale = 0.05 if p.numel() < 2 else min(0.05, 0.5 * float(p.std()))
            p.add_(scale * torch.randn_like(p))
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 2.0)
    model.eval()
    run = runs.init_run(tmp_path / "run", spec.path, {"spec": name})
    runs.save_checkpoint(run, {"model": model.state_dict(), "step": 0})
    (run / runs.CODE_HASH_FILE).write_text("f" * 64 + "\n")
    rep = export_run(run, tmp_path / "m.onnx")
    _assert_parity({n: (rep.parity[n], rep.torch_float32[n]) for n in rep.parity})
    sess = _session(tmp_path / "m.onnx")
    assert C.parse_contract(sess.get_modelmeta().custom_metadata_map).code_hash == "f" * 64
    feeds = example_inputs(model, 1, 21, 30, seed=9)
    _assert_parity(parity_errors(model, lambda f: sess.run(list(model.output_names), f), feeds))


@pytest.mark.parametrize("name", ["nbg-2l-1g", "anf-s"])
def test_reexport_carries_weights_and_code_hash(name, exported, tmp_path):
    """An earlier export, exported again with the current graph code (how a graph change
    reaches a shipped model whose run folder is gone): the same outputs, the same code hash,
    and the same spec."""
    spec, model, path, _ = exported[name]
    reexport(path, tmp_path / "again.onnx")
    old, new = _session(path), _session(tmp_path / "again.onnx")
    meta = [C.parse_contract(s.get_modelmeta().custom_metadata_map) for s in (old, new)]
    assert meta[0].code_hash == meta[1].code_hash and meta[0].spec_hash == meta[1].spec_hash
    feeds = example_inputs(model, 1, 20, 28, seed=4)
    for a, b in zip(old.run(None, feeds), new.run(None, feeds)):
        np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-7)


def test_reexport_refuses_a_file_whose_weights_were_folded(exported, tmp_path, capsys):
    """WSKPN's deploy() folds its layers, so its export has no initializer per parameter: the
    command says to re-export from the run folder, in one line."""
    from mcdenoise.runtime.cli import main

    _, _, path, _ = exported["wskpn-3"]
    with pytest.raises(ExportError, match="re-export it from its run folder"):
        reexport(path, tmp_path / "again.onnx")
    assert main(["export", str(path), "--out", str(tmp_path / "again.onnx")]) == 2
    err = capsys.readouterr().err
    assert "run folder" in err and "Traceback" not in err and not (tmp_path / "again.onnx").exists()


def test_adopt_protocol_changes_only_the_accumulation_weights(exported, tmp_path, capsys):
    """A shipped file takes a spec's accumulation weights without a new graph: the graph and
    weights are byte-equal, the contract's accumulation and spec change, the export info
    says what it was trained with; a spec that differs in anything else is refused."""
    import re

    from mcdenoise.runtime.cli import main

    spec, _, path, _ = exported["wskpn-3"]
    fixed = tmp_path / "wskpn-3.toml"
    fixed.write_text(re.sub(r"(?m)^history_spp = .*\n", "", spec.raw).replace("alpha = 0.2", "alpha = 0.5"))
    con = adopt_protocol(path, tmp_path / "a.onnx", fixed)
    assert [(a["alpha"], "history_spp" in a) for a in con.accumulate] == [(0.5, False)]
    assert con.export["protocol_from"]["trained_with"] == [{"layer": "color", "alpha": 0.2, "history_spp": 1.0}]
    before, after = onnx.load(str(path)), onnx.load(str(tmp_path / "a.onnx"))
    assert before.graph.SerializeToString() == after.graph.SerializeToString()
    assert C.parse_contract({p.key: p.value for p in after.metadata_props}).spec_toml == fixed.read_text()
    with pytest.raises(ExportError, match=r"differs from .* in \['paper', 'params'\]"):
        adopt_protocol(path, tmp_path / "b.onnx", load_spec("wskpn-6").path)
    assert main(["export", str(path), "--out", str(tmp_path / "c.onnx"), "--protocol-from", str(fixed)]) == 0
    assert "alpha 0.5" in capsys.readouterr().out


def test_adopt_protocol_accumulates_one_more_layer(exported, tmp_path):
    """wskpn-6e's file under wskpn-6e-aa's rules (the driver also accumulates the albedo): the
    graph stays byte-equal, the contract lists both accumulations and says what it was trained
    as, and the driver then gives what the same weights exported as wskpn-6e-aa give (equal
    specs but for that, equal seeds), which differs from the file as shipped from frame 2 on."""
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.harness import synthetic_frame
    from mcdenoise.runtime.frames import Frame

    _, _, path, _ = exported["wskpn-6e"]
    con = adopt_protocol(path, tmp_path / "aa.onnx", load_spec("wskpn-6e-aa").path)
    assert [a["layer"] for a in con.accumulate] == ["color", "albedo"] and con.spec_name == "wskpn-6e-aa"
    assert con.export["protocol_from"]["trained_as"] == "wskpn-6e"
    assert onnx.load(str(path)).graph.SerializeToString() == onnx.load(str(tmp_path / "aa.onnx")).graph.SerializeToString()
    dens = [Denoiser.load(p, log=lambda m: None) for p in (tmp_path / "aa.onnx", exported["wskpn-6e-aa"][2], path)]
    for t in range(2):
        frame = synthetic_frame(24, 20, t, spp=2)
        frame["albedo"] = frame["albedo"] * (1.0 + 0.5 * t)      # a layer that changes: its history counts
        adopted, built, shipped = (d(Frame(**{k: (v.copy() if hasattr(v, "copy") else v) for k, v in frame.items()}))
                                   for d in dens)
        np.testing.assert_allclose(adopted, built, rtol=1e-5, atol=1e-6)
        assert (np.abs(adopted - shipped).max() > 1e-4) == (t > 0)


def test_shipped_protocol_files_are_their_base_under_the_committed_spec():
    """A shipped file made by ``export --protocol-from`` (wskpn-6e-aa, wskpn-3-aa, nbg-2l-1g-aa:
    a base model's weights under a spec that also accumulates the albedo) holds the shipped base's
    graph byte for byte and exactly its committed spec file, so its card's scores stay those of
    what ships. nbg-2l-3g-aa was one until it was trained with its accumulation (2026-12-07, its card)."""
    from mcdenoise.training.methods import shipped_models

    def contract(path):
        return C.parse_contract({p.key: p.value for p in onnx.load(path).metadata_props})

    adopted = {}
    for path in shipped_models():
        con = contract(path)
        base = (con.export.get("protocol_from") or {}).get("trained_as")
        if base:
            adopted[con.spec_name] = base
            base_path = path.rsplit("/", 1)[0] + f"/{base}.onnx"
            assert onnx.load(path).graph.SerializeToString() == onnx.load(base_path).graph.SerializeToString()
            assert con.spec_toml == load_spec(con.spec_name).raw
            assert [a["layer"] for a in con.accumulate][-1] == "albedo"
            assert [a["layer"] for a in con.accumulate][:-1] == [a["layer"] for a in contract(base_path).accumulate]
    assert adopted == {"wskpn-3-aa": "wskpn-3", "wskpn-6e-aa": "wskpn-6e", "nbg-2l-1g-aa": "nbg-2l-1g"}


def test_a_fed_state_weight_is_declared_and_checked(exported):
    """nbg-2l-1g's [[state]] accum has an alpha: the contract's state entry names its weight
    input (N, 1, 1, 1 in the graph, only N dynamic), format 4; malformed entries are refused."""
    good = _session(exported["nbg-2l-1g"][2]).get_modelmeta().custom_metadata_map
    state = json.loads(good[C.KEY_STATE])
    assert state[0]["weight_input"] == "accum_weight" and (state[0]["alpha"], state[0]["history_spp"]) == (0.2, 1.0)
    shape = {i.name: i.shape for i in _session(exported["nbg-2l-1g"][2]).get_inputs()}["accum_weight"]
    assert shape[1:] == [1, 1, 1]
    for change, version in [({"weight_input": "nope"}, "4"), ({"alpha": 0}, "4"), ({"history_spp": -1}, "4"), ({}, "3")]:
        with pytest.raises(ValueError, match="weight input"):
            C.parse_contract({**good, C.KEY_VERSION: version, C.KEY_STATE: json.dumps([{**state[0], **change}])})


def test_adopt_protocol_exports_again_when_a_state_weight_becomes_an_input(tmp_path):
    """A file whose state blend weight was a graph constant takes a spec that feeds it: the model
    is exported again with the file's weights; at an unknown spp (the fixed alpha) its outputs
    equal the old file's."""
    import re

    spec = load_spec("nbg-2l-1g")
    plain = tmp_path / "nbg-2l-1g.toml"
    plain.write_text(re.sub(r"(?m)^(alpha|history_spp) = .*# .*(unknown|else).*\n", "", spec.raw))
    torch.manual_seed(3)
    old_spec = load_spec(plain)
    export_model(old_spec, build_model(old_spec), tmp_path / "old.onnx")
    con = adopt_protocol(tmp_path / "old.onnx", tmp_path / "new.onnx", spec.path)
    assert con.export["protocol_from"]["trained_with"] == "its graph's fixed weights"
    old, new = _session(tmp_path / "old.onnx"), _session(tmp_path / "new.onnx")
    assert "accum_weight" in [i.name for i in new.get_inputs()] and len(old.get_inputs()) == len(new.get_inputs()) - 1
    feeds = example_inputs(build_model(spec), 1, 20, 24, seed=2)
    feeds["accum_weight"][:] = 0.2
    got = new.run(None, feeds)
    del feeds["accum_weight"]
    for a, b in zip(old.run(None, feeds), got):
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)


def test_export_command(tmp_path, capsys):
    from mcdenoise.runtime.cli import main

    spec = load_spec(SPECS[0])
    torch.manual_seed(0)
    run = runs.init_run(tmp_path / "run", spec.path, {})
    runs.save_checkpoint(run, {"model": build_model(spec).state_dict()})
    assert main(["export", str(run), "--out", str(tmp_path / "cli.onnx"), "--opset", "17"]) == 0
    assert "max relative error" in capsys.readouterr().out
    assert C.parse_contract(_session(tmp_path / "cli.onnx").get_modelmeta().custom_metadata_map).spec_name == spec.name
    assert main(["export", str(tmp_path / "missing"), "--out", str(tmp_path / "x.onnx")]) == 2
