"""Training on the tiny set: exact resume, the run folder as the record, export from it alone."""
import json

import numpy as np
import onnxruntime as ort
import torch

from mcdenoise.export.onnx_export import export_run
from mcdenoise.runtime.cli import main
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.training import runs
from mcdenoise.training.train import train

KW = dict(crop=32, batch_size=2, quiet=True, val_every=0)


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
