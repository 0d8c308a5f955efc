"""Training on the tiny set: exact resume, the run folder as the record, export from it alone."""
import json

import numpy as np
import pytest
import onnxruntime as ort
import torch

from mcdenoise.export.onnx_export import export_run
from mcdenoise.runtime.cli import main
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import FrameError
from mcdenoise.training import runs
from mcdenoise.training.train import train

# precise_bn_windows: a new run's default (256) calibrates BatchNorm over more windows than the
# tiny set needs; 16 keeps the calibration in every run here at a test's cost.
KW = dict(crop=32, batch_size=2, quiet=True, val_every=0, precise_bn_windows=16)


def _weights(run):
    return torch.load(run / runs.CHECKPOINT_FILE, weights_only=False)["model"]


def test_resume_continues_exactly(tiny_dataset, tmp_path):
    train("wskpn-3", tiny_dataset, tmp_path / "straight", steps=4, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "split", steps=2, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "split", steps=4, resume=True, **KW)
    a, b = _weights(tmp_path / "straight"), _weights(tmp_path / "split")
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    # and training changed the weights at all
    torch.manual_seed(0)
    from mcdenoise.training.specs import build_model, load_spec

    fresh = build_model(load_spec("wskpn-3")).state_dict()
    assert any(not torch.equal(fresh[k], a[k]) for k in a if a[k].dtype.is_floating_point)


def test_resuming_a_finished_run_returns_its_score_without_reading_data(tiny_dataset, tmp_path, capsys):
    # Scripts resume every arm of an A/B; an arm already at its steps must not re-read its frames
    # (minutes for per-sample data) or train further, and must say so.
    run = tmp_path / "done"
    final = train("wskpn-3", tiny_dataset, run, steps=2, **KW)
    before = (run / runs.CHECKPOINT_FILE).read_bytes(), (run / runs.METRICS_FILE).read_text()
    cfg = json.loads((run / runs.CONFIG_FILE).read_text())
    cfg["data"] = str(tmp_path / "gone")        # reading any frame would now fail
    (run / runs.CONFIG_FILE).write_text(json.dumps(cfg))
    capsys.readouterr()
    assert train("wskpn-3", tiny_dataset, run, steps=2, resume=True, **KW) == final
    assert "already at step 2 of 2" in capsys.readouterr().out
    assert ((run / runs.CHECKPOINT_FILE).read_bytes(), (run / runs.METRICS_FILE).read_text()) == before
    # more steps than it has: it trains on, and so needs its data
    with pytest.raises(FrameError, match="does not exist"):
        train("wskpn-3", tiny_dataset, run, steps=3, resume=True, **KW)


def test_loader_workers_build_the_same_batches(tiny_dataset, tmp_path):
    # Batches built ahead by two forked processes train the same weights as the loop's own, and a
    # run may resume with another number of them (it is not part of the run).
    train("wskpn-3", tiny_dataset, tmp_path / "inline", steps=5, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "workers", steps=3, loader_workers=2, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "workers", steps=5, resume=True, loader_workers=1, **KW)
    a, b = _weights(tmp_path / "inline"), _weights(tmp_path / "workers")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    ck = torch.load(tmp_path / "workers" / runs.CHECKPOINT_FILE, weights_only=False)
    assert ck["step"] == 5 and ck["epoch"] >= 1, "the test must cross an epoch boundary"


def test_init_starts_a_new_run_from_another_runs_weights(tiny_dataset, tmp_path, capsys):
    # A later sitting continues training on other shards: a new run, seeded by the old one's state.
    train("wskpn-3", tiny_dataset, tmp_path / "a", steps=2, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "b", steps=0, init=str(tmp_path / "a"), **KW)
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    train("wskpn-3", tiny_dataset, tmp_path / "c", steps=2, init=str(tmp_path / "b"), **KW)
    c = _weights(tmp_path / "c")
    assert any(not torch.equal(a[k], c[k]) for k in a if a[k].dtype.is_floating_point)
    cfg = json.loads((tmp_path / "c" / runs.CONFIG_FILE).read_text())
    assert cfg["init"]["run"] == str((tmp_path / "b").resolve()) and cfg["init"]["step"] == 0
    assert cfg["init"]["chain_steps"] == 2     # b took none of its own, a took 2
    out = tmp_path / "d"
    assert main(["train", "nbg-2l-1g", "--data", tiny_dataset, "--out", str(out), "--init", str(tmp_path / "a")]) == 2
    assert "trained wskpn-3 (type 'wskpn'), not a spec of type 'nbg'" in capsys.readouterr().err
    assert not out.exists()
    # another spec of the same type starts from it only where the weights fit (anf-s -> anf-sd do)
    assert main(["train", "wskpn-6", "--data", tiny_dataset, "--out", str(out), "--init", str(tmp_path / "a")]) == 2
    assert "its weights do not fit spec wskpn-6" in capsys.readouterr().err and not out.exists()
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "c"), "--resume",
                 "--init", str(tmp_path / "a")]) == 2
    assert "give one of them" in capsys.readouterr().err


def test_init_from_an_exported_file_fine_tunes_its_weights(tiny_dataset, tmp_path, capsys):
    # A user fine-tunes a shipped file on their own renders: --init FILE.onnx reads its weights back
    # exactly, under its own spec or another of its type whose weights fit (nbg-2l-1g -> -aa).
    import hashlib

    train("nbg-2l-1g", tiny_dataset, tmp_path / "a", steps=2, **KW)
    export_run(tmp_path / "a", tmp_path / "a.onnx")
    train("nbg-2l-1g-aa", tiny_dataset, tmp_path / "b", steps=0, init=str(tmp_path / "a.onnx"), **KW)
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    cfg = json.loads((tmp_path / "b" / runs.CONFIG_FILE).read_text())
    assert cfg["init"] == {"run": str((tmp_path / "a.onnx").resolve()), "step": 0, "chain_steps": 0,
                           "sha256": hashlib.sha256((tmp_path / "a.onnx").read_bytes()).hexdigest()}
    # the shipped file, then steps: Adam starts afresh and the weights move
    shipped = runs.ROOT / "models" / "nbg-2l-1g.onnx"
    train("nbg-2l-1g-aa", tiny_dataset, tmp_path / "c", steps=2, init=str(shipped), **KW)
    c = _weights(tmp_path / "c")
    import onnx
    from onnx import numpy_helper

    stored = {i.name: numpy_helper.to_array(i) for i in onnx.load(str(shipped)).graph.initializer}
    assert any(not np.array_equal(stored[k], c[k].numpy()) for k in c if c[k].dtype.is_floating_point)
    # refused with one clear line each: a file whose export folded batch norm (WSKPN), a file of
    # another shape, another type, and a file that is no ONNX at all
    out = tmp_path / "d"
    cases = [("wskpn-3", runs.ROOT / "models" / "wskpn-3.onnx", "the export folded it into another"),
             ("nbg-2l-1g", runs.ROOT / "models" / "nbg-2l-3g.onnx", "its weights do not fit spec nbg-2l-1g"),
             ("wskpn-3", shipped, "not a model of type 'wskpn'")]
    (tmp_path / "bad.onnx").write_bytes(b"not a protobuf at all")
    cases.append(("nbg-2l-1g", tmp_path / "bad.onnx", "not a readable ONNX file"))
    from onnx import TensorProto, helper   # a valid ONNX file that no mcdenoise export wrote

    io = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1]) for n in ("x", "y")]
    onnx.save(helper.make_model(helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", io[:1], io[1:])),
              str(tmp_path / "plain.onnx"))
    cases.append(("nbg-2l-1g", tmp_path / "plain.onnx", "not an mcdenoise export"))
    for spec, f, says in cases:
        assert main(["train", spec, "--data", tiny_dataset, "--out", str(out), "--init", str(f)]) == 2, f
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err, err
        assert not out.exists()


def test_run_folder_is_the_record_and_exports(tiny_dataset, tmp_path):
    run = tmp_path / "run"
    row = train("wskpn-3", tiny_dataset, run, steps=2, **KW)
    for name in (runs.SPEC_FILE, runs.CONFIG_FILE, runs.CHECKPOINT_FILE, runs.METRICS_FILE, runs.CODE_HASH_FILE):
        assert (run / name).exists(), name
    cfg = json.loads((run / runs.CONFIG_FILE).read_text())
    assert cfg["steps"] == 2 and cfg["spec"] == "wskpn-3"
    assert (run / runs.CODE_HASH_FILE).read_text().strip() == runs.code_hash()
    metrics = runs.read_metrics(run)
    assert metrics[-1]["final"] and np.isfinite(metrics[-1]["val_psnr"]) and row == metrics[-1]
    out = tmp_path / "m.onnx"
    export_run(run, out)
    den = Denoiser.load(out, log=lambda m: None)
    assert den.contract.spec_name == "wskpn-3"
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert sess.get_modelmeta().custom_metadata_map["mcdenoise.spec_name"] == "wskpn-3"


def test_train_errors_are_clear(tiny_dataset, tmp_path, capsys):
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "r"), "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    assert main(["train", "no-such-spec", "--data", tiny_dataset, "--out", str(tmp_path / "r2")]) == 2
    assert main(["train", "wskpn-3", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "r3"),
                 "--steps", "1"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "r4"), "--steps", "1",
                 "--loader-workers", "-1"]) == 2
    assert "--loader-workers must be >= 0" in capsys.readouterr().err and not (tmp_path / "r4").exists()


def test_window_loss_adds_the_temporal_term_on_frame_differences():
    from mcdenoise.training.train import LOSSES, window_loss

    torch.manual_seed(0)
    refs = torch.rand(2, 3, 3, 8, 8) + 0.1
    steady = [refs[:, t] * 1.1 for t in range(3)]                   # off by 10%, the same each frame
    flicker = [refs[:, t] * (1.1 if t % 2 else 1 / 1.1) for t in range(3)]  # as far off (SMAPE), alternating
    smape = LOSSES["smape"]
    base = sum(smape(o, refs[:, t]) for t, o in enumerate(flicker)) / 3
    assert torch.allclose(window_loss(smape, flicker, refs), base)
    # Same per-frame error, but only the flicker pays the temporal term.
    assert torch.allclose(window_loss(smape, steady, refs), window_loss(smape, flicker, refs), rtol=1e-2)
    d_steady = window_loss(smape, steady, refs, 0.25) - window_loss(smape, steady, refs)
    d_flicker = window_loss(smape, flicker, refs, 0.25) - window_loss(smape, flicker, refs)
    assert d_flicker > 4 * d_steady > 0
    want = 0.25 * sum(smape(flicker[t] - flicker[t - 1], refs[:, t] - refs[:, t - 1]) for t in (1, 2)) / 2
    assert torch.allclose(d_flicker, want)


def test_the_gamma_loss_temporal_term_charges_darkening_and_brightening_alike():
    # NBG's l1_gamma compares in the gamma domain, which clips below 0: a frame difference put
    # through it lost every darkening (the temporal term saw only half the flicker, and pulled
    # brightenings toward the reference's with gamma's infinite slope at 0). The differences are
    # taken after gamma instead.
    from mcdenoise.runtime.transfer import gamma
    from mcdenoise.training.train import LOSSES, window_loss

    l1g = LOSSES["l1_gamma"]
    refs = torch.full((1, 2, 3, 4, 4), 0.25)                         # a still scene
    darker = [refs[:, 0], refs[:, 1] * 0.8]
    brighter = [refs[:, 0], refs[:, 1] * 1.25]
    terms = []
    for outs in (darker, brighter):
        d = window_loss(l1g, outs, refs, 0.25) - window_loss(l1g, outs, refs)
        want = 0.25 * ((gamma(outs[1]) - gamma(outs[0])) - (gamma(refs[:, 1]) - gamma(refs[:, 0]))).abs().mean()
        assert torch.allclose(d, want) and float(d) > 0.005
        terms.append(float(d))
    # a step down and its inverse step up cost about the same (0.8 and 1.25: 0.051 and 0.057 in gamma)
    assert terms[0] == pytest.approx(terms[1], rel=0.15)


def test_the_coarse_term_charges_a_loss_of_energy_not_zero_mean_noise(tiny_dataset, tmp_path):
    # A frame 10% too dark everywhere and one off by +-10% in a checkerboard pay about the same
    # per-pixel SMAPE; only the darkening survives in the 8x8 block means.
    from mcdenoise.training.train import COARSE_BLOCK, LOSSES, coarse, window_loss

    smape = LOSSES["smape"]
    refs = torch.rand(2, 2, 3, 2, 2).repeat_interleave(COARSE_BLOCK, 3).repeat_interleave(COARSE_BLOCK, 4) + 0.1
    sign = (torch.arange(2 * COARSE_BLOCK)[:, None] + torch.arange(2 * COARSE_BLOCK)[None]) % 2 * 2 - 1
    checker = [refs[:, t] * (1 + 0.1 * sign) for t in range(2)]
    dark = [refs[:, t] * 0.9 for t in range(2)]
    assert torch.allclose(window_loss(smape, checker, refs), window_loss(smape, dark, refs), rtol=0.06)
    d_checker = window_loss(smape, checker, refs, coarse_weight=0.5) - window_loss(smape, checker, refs)
    d_dark = window_loss(smape, dark, refs, coarse_weight=0.5) - window_loss(smape, dark, refs)
    assert abs(float(d_checker)) < 1e-6 and float(d_dark) > 0.02
    want = 0.5 * sum(smape(coarse(o), coarse(refs[:, t])) for t, o in enumerate(dark)) / 2
    assert torch.allclose(d_dark, want)
    # the run records its weight; a resume keeps it and refuses another
    train("wskpn-3", tiny_dataset, tmp_path / "c", steps=1, coarse_weight=0.5, **KW)
    assert json.loads((tmp_path / "c" / runs.CONFIG_FILE).read_text())["coarse_weight"] == 0.5
    with pytest.raises(ValueError, match="coarse-weight 0.5"):
        train("wskpn-3", tiny_dataset, tmp_path / "c", steps=2, resume=True, coarse_weight=0.0, **KW)
    with pytest.raises(ValueError, match="--coarse-weight must be >= 0"):
        train("wskpn-3", tiny_dataset, tmp_path / "d", steps=1, coarse_weight=-1.0, **KW)


def test_window_spp_and_temporal_weight_reach_the_run(tiny_dataset, tmp_path, capsys):
    run = tmp_path / "r"
    train("wskpn-3", tiny_dataset, run, steps=1, window=3, spp=[1, 2, 4], temporal_weight=0.25, fireflies=1e-3, **KW)
    cfg = json.loads((run / runs.CONFIG_FILE).read_text())
    assert cfg["window"] == 3 and cfg["spp"] == [1, 2, 4] and cfg["temporal_weight"] == 0.25
    assert cfg["fireflies"] == 1e-3
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "r2"), "--window", "0"]) == 2
    assert "--window must be >= 1" in capsys.readouterr().err
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "r3"), "--fireflies", "1"]) == 2
    assert "--fireflies must be a mean count per pixel in [0, 1)" in capsys.readouterr().err
    assert not (tmp_path / "r3").exists()


def test_two_processes_match_one_with_the_same_global_batch(tiny_dataset, tmp_path):
    """torchrun with 2 CPU processes (DDP over gloo), each taking half of every step's batch of
    4, ends with the weights of one process training on the whole batch (nbg-2l-1g: no
    BatchNorm, whose statistics are per process on the CPU)."""
    import socket
    import subprocess
    import sys

    args = ["train", "nbg-2l-1g", "--data", tiny_dataset, "--steps", "3", "--batch-size", "4", "--crop", "32",
            "--quiet", "--val-every", "0"]
    with socket.socket() as s:      # a free port for the rendezvous
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2",
                           "--master_addr", "127.0.0.1", "--master_port", str(port),
                           "-m", "mcdenoise.runtime.cli", *args, "--out", str(tmp_path / "two")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert main([*args, "--out", str(tmp_path / "one")]) == 0
    a, b = _weights(tmp_path / "one"), _weights(tmp_path / "two")
    assert a.keys() == b.keys()
    # Two processes sum each gradient in another order than one (half batches, one thread
    # each), and Adam divides by the gradient's running magnitude, which amplifies rounding
    # where a gradient is near 0: 1.8e-6 on this Xeon, under 1e-6 on the EPYC hosts. A wrong
    # share or a missing average moves a weight by the order of an Adam step (lr = 1e-3).
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-5, atol=1e-5, msg=k)
    cfg = json.loads((tmp_path / "two" / runs.CONFIG_FILE).read_text())
    assert cfg["batch_size"] == 4 and cfg["processes"] == 2
    assert len(runs.read_metrics(tmp_path / "two")) == len(runs.read_metrics(tmp_path / "one"))


def test_the_processes_share_each_global_batch_without_overlap():
    from mcdenoise.training.train import batch_share

    order = list(range(100, 124))
    for pos in (0, 2):
        shares = [batch_share(order, pos, 8, r, 4) for r in range(4)]
        assert all(len(s) == 2 for s in shares)
        assert sorted(i for s in shares for i in s) == order[pos * 8:(pos + 1) * 8]
    assert batch_share(order, 1, 8, 0, 1) == order[8:16]


def test_learning_curves_train_every_variant_and_resume(tiny_dataset, tmp_path):
    """curves: one run per (spec value, training-set size), each scoring the test folder at
    every validation; run again with more steps, every run resumes and its curve grows."""
    from mcdenoise.training.curves import spec_variant
    from mcdenoise.training.specs import SpecError, build_model, load_spec, parse_spec

    text = spec_variant(load_spec("wskpn-3").path.read_text(), "widths", "[8]")
    assert parse_spec(text).params["widths"] == (8,) and parse_spec(text).name == "wskpn-3-widths-8"
    # a key the spec leaves at its default is added; one its type lacks is refused on building
    added = parse_spec(spec_variant(load_spec("wskpn-3").path.read_text(), "conv", "3"))
    assert added.params["conv"] == 3 and added.name == "wskpn-3-conv-3"
    with pytest.raises(SpecError, match="unknown key 'nonsense'"):
        build_model(parse_spec(spec_variant(load_spec("wskpn-3").path.read_text(), "nonsense", "3")))
    argv = ["curves", "wskpn-3", "--data", tiny_dataset, "--test", tiny_dataset, "--out", str(tmp_path / "c"),
            "--sequences", "1", "--vary", "widths", "[4]", "[8]", "--steps", "2", "--eval-every", "1",
            "--batch-size", "2", "--crop", "32"]
    assert main(argv) == 0
    first = json.loads((tmp_path / "c" / "curves.json").read_text())["runs"]
    assert sorted(first) == ["wskpn-3-widths-4-n1", "wskpn-3-widths-8-n1"]
    for r in first.values():
        assert [p[0] for p in r["points"]] == [2, 4] and all(np.isfinite(p[2]) for p in r["points"])
    argv[argv.index("--steps") + 1] = "3"
    assert main(argv) == 0
    again = json.loads((tmp_path / "c" / "curves.json").read_text())["runs"]
    for name, r in again.items():
        assert r["points"][:2] == first[name]["points"] and r["points"][-1][0] == 6
    assert (tmp_path / "c" / "curves.png").read_bytes()[:4] == b"\x89PNG"
    assert "wskpn-3-widths-8-n1" in (tmp_path / "c" / "curves.md").read_text()
    assert main([*argv[:-2], "--vary", "no_such_key", "1"]) == 2


def test_anf_trains_on_one_spp_per_batch_exports_and_denoises_the_rendered_frames(tiny_dataset, tmp_path):
    """The per-sample path end to end: ANF trains (samples of one S per batch, its
    regulariser, 2-frame windows), resumes, exports, and the driver denoises rendered frames."""
    from mcdenoise.runtime.frames import frame_paths, read_frame
    from mcdenoise.training.dataset import discover

    kw = dict(batch_size=2, crop=32, window=2, spp=[1, 2, 4], threads=1, quiet=True)
    run = tmp_path / "anf"
    row = train("anf-s", tiny_dataset, run, steps=2, **kw)
    assert np.isfinite(row["val_psnr"]) and row["step"] == 2
    assert json.loads((run / runs.CONFIG_FILE).read_text())["regularizer_weight"] == 1e-5
    train("anf-s", tiny_dataset, run, steps=3, resume=True, **kw)
    export_run(run, tmp_path / "anf.onnx")
    den = Denoiser.load(tmp_path / "anf.onnx", log=lambda m: None, settings={"kernel_size": 5})
    for path in frame_paths(discover(tiny_dataset)[0].folder):
        out = den(read_frame(path))
        assert out.shape == (64, 64, 3) and np.isfinite(out).all() and (out >= 0).all()
    assert den.report.frames == 3 and not den.report.resets
    # Fig. 7's sweep: the same loaded file at two kernel sizes, quality and time per size
    assert main(["sweep", str(tmp_path / "anf.onnx"), "--data", tiny_dataset, "--values", "3", "5",
                 "--spp", "2", "--out", str(tmp_path / "sweep")]) == 0
    res = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert res["setting"] == "kernel_size" and set(res["results"]) == {"3", "5"}
    assert res["results"]["3"]["psnr"] != res["results"]["5"]["psnr"]
    assert all(r["ms"] > 0 and r["frames"] == 6 for r in res["results"].values())
    assert (tmp_path / "sweep" / "sweep.png").stat().st_size > 0
    assert "mcdenoise sweep" in (tmp_path / "sweep" / "sweep.md").read_text()
    assert main(["sweep", str(tmp_path / "anf.onnx"), "--data", tiny_dataset, "--values", "4",
                 "--out", str(tmp_path / "s2")]) == 2


def test_lr_sets_the_peak_rate_of_a_new_run_and_a_resume_keeps_it(tiny_dataset, tmp_path):
    """--lr: a run started with --init begins its schedule again, so a chain settles its
    weights with a lower peak (docs/results/scale, sitting 4)."""
    from mcdenoise.training.train import learning_rate

    run = tmp_path / "low"
    train("wskpn-3", tiny_dataset, run, steps=2, lr=2e-4, lr_schedule="cosine", **KW)
    config = json.loads((run / runs.CONFIG_FILE).read_text())
    ckpt = torch.load(run / runs.CHECKPOINT_FILE, weights_only=False)
    assert config["lr"] == 2e-4 and ckpt["optimizer"]["param_groups"][0]["lr"] == learning_rate(config, 1) < 2e-4
    with pytest.raises(ValueError, match="keeps its rate"):
        train("wskpn-3", tiny_dataset, run, steps=3, resume=True, lr=1e-3, **KW)
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(ValueError, match="positive"):
            train("wskpn-3", tiny_dataset, tmp_path / "bad", steps=1, lr=bad, **KW)
    assert not (tmp_path / "bad").exists()


def test_gradient_clipping_is_recorded_bounds_the_step_and_a_resume_keeps_it(tiny_dataset, tmp_path, capsys):
    """--clip-grad: every validation row carries the interval's gradient norms; a norm above
    every step's is a no-op, one below every step's scales each step (docs/results/scale,
    mr-e sitting 4)."""
    train("wskpn-3", tiny_dataset, tmp_path / "plain", steps=3, **KW)
    rows = runs.read_metrics(tmp_path / "plain")
    first = rows[0]
    assert first["interval_steps"] >= 1 and first["clipped"] == 0
    assert 0 < first["grad_norm_median"] <= first["grad_norm_max"] and np.isfinite(first["train_loss_mean"])
    assert sum(r.get("interval_steps", 0) for r in rows) == 3
    top = max(r["grad_norm_max"] for r in rows if "grad_norm_max" in r)
    low = min(r["grad_norm_median"] for r in rows if "grad_norm_median" in r)

    train("wskpn-3", tiny_dataset, tmp_path / "loose", steps=3, clip_grad=top * 2, **KW)
    plain, loose = _weights(tmp_path / "plain"), _weights(tmp_path / "loose")
    for k in plain:
        torch.testing.assert_close(plain[k], loose[k], rtol=0, atol=0, msg=k)
    train("wskpn-3", tiny_dataset, tmp_path / "tight", steps=3, clip_grad=low / 1e3, **KW)
    tight_rows = runs.read_metrics(tmp_path / "tight")
    assert sum(r.get("clipped", 0) for r in tight_rows) == 3
    tight = _weights(tmp_path / "tight")
    assert any(not torch.equal(plain[k], tight[k]) for k in plain if plain[k].dtype.is_floating_point)
    assert json.loads((tmp_path / "tight" / runs.CONFIG_FILE).read_text())["clip_grad"] == low / 1e3
    with pytest.raises(ValueError, match="keeps its clipping"):
        train("wskpn-3", tiny_dataset, tmp_path / "tight", steps=4, resume=True, clip_grad=1.0, **KW)
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "bad"), "--clip-grad", "0"]) == 2
    assert "--clip-grad must be a positive norm" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_batchnorm_statistics_are_estimated_afresh_for_scoring_and_export_only(tiny_dataset, tmp_path, capsys):
    """--precise-bn: validation and the run folder's model get BatchNorm statistics averaged over
    a fixed set of training windows (mr-e sitting 4 lost 2.6 dB to the running averages of its
    last batches); the live weights and running averages train exactly as without it."""
    from mcdenoise.training.train import BN_STATS, _datasets, precise_bn

    train("wskpn-3", tiny_dataset, tmp_path / "plain", steps=3, **dict(KW, precise_bn_windows=0))
    train("wskpn-3", tiny_dataset, tmp_path / "cal", steps=3, **KW)
    plain = torch.load(tmp_path / "plain" / runs.CHECKPOINT_FILE, weights_only=False)
    cal = torch.load(tmp_path / "cal" / runs.CHECKPOINT_FILE, weights_only=False)
    for k in plain["model"]:
        torch.testing.assert_close(plain["model"][k], cal["model"][k], rtol=0, atol=0, msg=k)
    assert plain["bn"] is None and cal["bn"] and all(k.endswith(BN_STATS) for k in cal["bn"])
    assert any(not torch.equal(cal["bn"][k], cal["model"][k]) for k in cal["bn"] if k.endswith("running_var"))
    # What export and evaluation rebuild carries the calibrated statistics; without them, the running ones.
    for run, want in ((tmp_path / "cal", cal["bn"]), (tmp_path / "plain", plain["model"])):
        _, model, _ = runs.load_run(run)
        state = model.state_dict()
        for k in cal["bn"]:
            torch.testing.assert_close(state[k], want[k], rtol=0, atol=0, msg=f"{run.name} {k}")
    # The same windows at every calibration, whatever epoch the set is at, which is restored.
    config = json.loads((tmp_path / "cal" / runs.CONFIG_FILE).read_text())
    assert config["precise_bn"] == 16
    spec, model, _ = runs.load_run(tmp_path / "plain")
    train_set = _datasets(config, spec, "float32")[0]
    stats = []
    for epoch in (0, 7):
        train_set.set_epoch(epoch)
        net = precise_bn(model, train_set, spec.protocol, 16, config["batch_size"])
        assert train_set.epoch == epoch and not net.training
        stats.append({k: v for k, v in net.state_dict().items() if k.endswith(BN_STATS)})
    for k in cal["bn"]:
        torch.testing.assert_close(stats[0][k], stats[1][k], rtol=0, atol=0, msg=k)
        torch.testing.assert_close(stats[0][k], cal["bn"][k], rtol=1e-5, atol=1e-7, msg=k)
    tracked = next(v for k, v in stats[0].items() if k.endswith("num_batches_tracked"))
    assert int(tracked) == 16 // config["batch_size"] * config["window"]      # a forward call per batch and frame
    # A model without BatchNorm is scored as it is.
    assert precise_bn(torch.nn.Conv2d(1, 1, 1), train_set, spec.protocol, 16, 2).__class__ is torch.nn.Conv2d
    with pytest.raises(ValueError, match="keeps its own"):
        train("wskpn-3", tiny_dataset, tmp_path / "cal", steps=4, resume=True, **dict(KW, precise_bn_windows=4))
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "bad"), "--precise-bn", "-1"]) == 2
    assert "--precise-bn must be" in capsys.readouterr().err


def test_the_cache_precision_is_chosen_for_the_memory_recorded_and_kept_on_resume(tiny_dataset, tmp_path, monkeypatch,
                                                                                  capsys):
    """--cache-dtype auto caches float32 where the frames fit in memory, float16 where only that
    fits (sitting 5's 110 training sequences took 26 GB of a 23 GB machine in float32), and
    stops with one line before a run folder exists where neither fits; a resume keeps the choice."""
    from mcdenoise.runtime.cli import main as cli
    from mcdenoise.training import dataset

    from mcdenoise.training.specs import load_spec
    from mcdenoise.training.train import _datasets

    train("wskpn-3", tiny_dataset, tmp_path / "roomy", steps=1, **KW)
    config = json.loads((tmp_path / "roomy" / runs.CONFIG_FILE).read_text())
    assert config["cache_dtype"] == "float32"
    need = sum(d.cache_bytes("float32") for d in _datasets(config, load_spec("wskpn-3"), "float32") if d is not None)
    monkeypatch.setattr(dataset, "available_memory", lambda: int(need))     # 85% of it: float16 fits
    run = tmp_path / "tight"
    train("wskpn-3", tiny_dataset, run, steps=1, **KW)
    assert json.loads((run / runs.CONFIG_FILE).read_text())["cache_dtype"] == "float16"
    assert "float16" in capsys.readouterr().err
    monkeypatch.setattr(dataset, "available_memory", lambda: 10**12)
    train("wskpn-3", tiny_dataset, run, steps=2, resume=True, **KW)     # the run's own choice, not auto's
    assert json.loads((run / runs.CONFIG_FILE).read_text())["cache_dtype"] == "float16"
    monkeypatch.setattr(dataset, "available_memory", lambda: int(need) // 4)
    rc = cli(["train", "wskpn-3", "--data", str(tiny_dataset), "--out", str(tmp_path / "none"), "--steps", "1"])
    assert rc == 2 and "--max-sequences" in capsys.readouterr().err and not (tmp_path / "none").exists()


def test_a_disk_cache_trains_the_same_run_and_takes_frames_beyond_the_memory(tiny_dataset, tmp_path, monkeypatch,
                                                                              capsys):
    """--cache-dir: the same weights and metrics as the in-memory cache, through a resume with
    another folder; not recorded in the config; where even float16 does not fit in memory the run
    caches float16 on disk instead of stopping (without the folder it stops, the test above)."""
    from mcdenoise.runtime.cli import main as cli
    from mcdenoise.training import dataset

    kw = dict(KW, fireflies=0.01, val_every=1)
    train("wskpn-3", tiny_dataset, tmp_path / "memory", steps=2, **kw)
    train("wskpn-3", tiny_dataset, tmp_path / "disk", steps=1, cache_dir=str(tmp_path / "c1"), **kw)
    train("wskpn-3", tiny_dataset, tmp_path / "disk", steps=2, resume=True, cache_dir=str(tmp_path / "c2"), **kw)
    a, b = _weights(tmp_path / "memory"), _weights(tmp_path / "disk")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    rows = [[{k: v for k, v in json.loads(line).items() if k != "elapsed_s"}
             for line in (tmp_path / r / runs.METRICS_FILE).read_text().splitlines()] for r in ("memory", "disk")]
    assert rows[0][-1] == rows[1][-1] and rows[0][-1]["final"] and rows[0][-1]["step"] == 2   # the split run adds a final row at 1
    assert any((tmp_path / "c1").iterdir()) and any((tmp_path / "c2").iterdir())
    assert "cache_dir" not in json.loads((tmp_path / "disk" / runs.CONFIG_FILE).read_text())
    monkeypatch.setattr(dataset, "available_memory", lambda: 1)
    capsys.readouterr()
    rc = cli(["train", "wskpn-3", "--data", str(tiny_dataset), "--out", str(tmp_path / "big"), "--steps", "1",
              "--crop", "32", "--batch-size", "2", "--quiet", "--cache-dir", str(tmp_path / "c3")])
    assert rc == 0 and "read from" in capsys.readouterr().err
    assert json.loads((tmp_path / "big" / runs.CONFIG_FILE).read_text())["cache_dtype"] == "float16"


@pytest.mark.parametrize("spec", ["wskpn-3", "nbg-2l-1g", "anf-s", "ndle-s"])
def test_bfloat16_autocast_trains_every_family_close_to_float32(tiny_dataset, tmp_path, spec, monkeypatch):
    """--autocast bf16: the training step's convolutions run in bfloat16 (float32 without it), the
    first step's loss close to float32's, validation (float32) within 0.5 dB, finite weights after
    a second, resumed step; recorded, kept on resume."""
    import mcdenoise.training.train as train_module

    # the tiny sequences are 3 frames; anf-s trains on 8. No BatchNorm calibration: it runs the
    # model in training mode in float32 (as validation scores it), which the spy would count.
    kw = dict(KW, window=2, precise_bn_windows=0)
    conv_dtypes = []
    run_window = train_module.run_window

    def spy(model, batch, protocol, **k):
        # Only training steps: validation runs in float32 by design.
        hooks = [m.register_forward_hook(lambda m, i, o: conv_dtypes.append(o.dtype))
                 for m in model.modules() if isinstance(m, torch.nn.Conv2d)] if model.training else []
        try:
            return run_window(model, batch, protocol, **k)
        finally:
            for h in hooks:
                h.remove()

    monkeypatch.setattr(train_module, "run_window", spy)
    a, b = tmp_path / "fp32", tmp_path / "bf16"
    ra = train(spec, tiny_dataset, a, steps=1, **kw)
    assert conv_dtypes and set(conv_dtypes) == {torch.float32}, set(conv_dtypes)
    conv_dtypes.clear()
    rb = train(spec, tiny_dataset, b, steps=1, autocast="bf16", **kw)
    assert conv_dtypes and set(conv_dtypes) == {torch.bfloat16}, set(conv_dtypes)
    assert json.loads((b / runs.CONFIG_FILE).read_text())["autocast"] == "bf16"
    # The loss itself may come out equal: at initialisation anf-s's affinity kernels barely depend
    # on the U-Net's output (its bf16 rounding moved the output by 1e-5 of 0.44 on the tiny set,
    # below float32's resolution of the mean loss). Adam's first update is about lr·sign(g), so
    # the weights (and validation) may come out the same too.
    la, lb = (json.loads((r / "metrics.jsonl").read_text().splitlines()[0])["train_loss"] for r in (a, b))
    assert abs(la - lb) < 0.05 * la, (la, lb)
    assert abs(ra["val_psnr"] - rb["val_psnr"]) < 0.5, (ra["val_psnr"], rb["val_psnr"])
    train(spec, tiny_dataset, b, steps=2, resume=True, **kw)
    ckpt = torch.load(b / runs.CHECKPOINT_FILE, weights_only=False)
    assert ckpt["step"] == 2 and all(torch.isfinite(v).all() for v in ckpt["model"].values() if v.is_floating_point())
    with pytest.raises(ValueError, match="keeps its arithmetic"):
        train(spec, tiny_dataset, a, steps=2, resume=True, autocast="bf16", **kw)


def test_cosine_learning_rate_decays_over_the_steps(tiny_dataset, tmp_path):
    from mcdenoise.training.train import learning_rate

    cfg = {"lr": 1e-3, "steps": 100, "lr_schedule": "cosine"}
    rates = [learning_rate(cfg, s) for s in range(101)]
    assert rates[0] == 1e-3 and abs(rates[100] - 5e-5) < 1e-12
    assert all(a >= b for a, b in zip(rates, rates[1:]))
    assert learning_rate({**cfg, "lr_schedule": "constant"}, 73) == 1e-3
    run = tmp_path / "cos"
    train("wskpn-3", tiny_dataset, run, steps=3, lr_schedule="cosine", **KW)
    ckpt = torch.load(run / runs.CHECKPOINT_FILE, weights_only=False)
    config = json.loads((run / runs.CONFIG_FILE).read_text())
    assert config["lr_schedule"] == "cosine"
    assert ckpt["optimizer"]["param_groups"][0]["lr"] == learning_rate(config, 2)
    try:
        train("wskpn-3", tiny_dataset, run, steps=4, resume=True, lr_schedule="constant", **KW)
    except ValueError as e:
        assert "keeps its schedule" in str(e)
    else:
        raise AssertionError("a resumed run changed its schedule")
    try:
        train("wskpn-3", tiny_dataset, tmp_path / "endless", lr_schedule="cosine", **KW)
    except ValueError as e:
        assert "finite --steps" in str(e)
    else:
        raise AssertionError("cosine without a finite --steps")
    assert not (tmp_path / "endless").exists()


def test_weight_average_is_what_validation_scores_and_export_ships(tiny_dataset, tmp_path, capsys):
    from mcdenoise.training.train import ema_decay, ema_update

    # The warm-up: early updates follow the weights, later ones average over ~1/(1 - decay).
    assert ema_decay(0.99, 0) == 0.1 and ema_decay(0.99, 10 ** 6) == 0.99
    net = torch.nn.BatchNorm2d(2)
    avg = {k: torch.zeros_like(v) for k, v in net.state_dict().items()}
    net.num_batches_tracked += 7
    ema_update(avg, net, 0.99, 0)
    torch.testing.assert_close(avg["weight"], 0.9 * net.weight.detach(), rtol=0, atol=1e-7)
    assert int(avg["num_batches_tracked"]) == 7

    # Averaging never changes what the optimiser does: the live weights equal a run without it.
    train("wskpn-3", tiny_dataset, tmp_path / "plain", steps=4, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "avg", steps=4, ema=0.9, **KW)
    plain = _weights(tmp_path / "plain")
    ckpt = torch.load(tmp_path / "avg" / runs.CHECKPOINT_FILE, weights_only=False)
    for k in plain:
        torch.testing.assert_close(plain[k], ckpt["model"][k], rtol=0, atol=0, msg=k)
    assert ckpt["ema_updates"] == 4
    # Each validation scores the average and, beside it, the live weights: those are the plain run's.
    last, plain_last = runs.read_metrics(tmp_path / "avg")[-1], runs.read_metrics(tmp_path / "plain")[-1]
    assert last["live_val_psnr"] == plain_last["val_psnr"] and last["val_psnr"] != plain_last["val_psnr"]
    assert "live_val_psnr" not in plain_last
    assert any(not torch.equal(ckpt["ema"][k], ckpt["model"][k]) for k in plain if plain[k].dtype.is_floating_point)
    # The run folder ships the average: load_run (what export and evaluation rebuild from) holds it,
    # with the BatchNorm statistics calibrated for the averaged weights.
    _, model, _ = runs.load_run(tmp_path / "avg")
    for k, v in model.state_dict().items():
        torch.testing.assert_close(v, ckpt["bn"][k] if k in ckpt["bn"] else ckpt["ema"][k], rtol=0, atol=0, msg=k)
    # Resume is exact for the average too, and keeps the run's decay.
    train("wskpn-3", tiny_dataset, tmp_path / "split", steps=2, ema=0.9, **KW)
    train("wskpn-3", tiny_dataset, tmp_path / "split", steps=4, resume=True, **KW)
    split = torch.load(tmp_path / "split" / runs.CHECKPOINT_FILE, weights_only=False)
    for k in plain:
        torch.testing.assert_close(split["ema"][k], ckpt["ema"][k], rtol=0, atol=0, msg=k)
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "split"), "--resume",
                 "--ema", "0.5"]) == 2
    assert "keeps its average" in capsys.readouterr().err
    assert main(["train", "wskpn-3", "--data", tiny_dataset, "--out", str(tmp_path / "bad"), "--ema", "1"]) == 2
    assert "--ema must be a decay" in capsys.readouterr().err
