"""Every failure a user can cause reaches them as one line on stderr and exit status 2, never a
traceback: one test per kind (the frame, plain-input and spec kinds are in test_frames.py,
test_runtime.py and test_train.py; the missing package in test_install.py)."""
from __future__ import annotations

import pytest
import torch

from mcdenoise.export import onnx_export
from mcdenoise.runtime.args import CommandError
from mcdenoise.runtime.cli import main
from mcdenoise.training import runs
from mcdenoise.training.specs import build_model, load_spec


def _one_line_error(capsys, code, *words):
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()  # progress lines (train) may come first
    assert lines and lines[-1].startswith("mcdenoise ") and "Traceback" not in err, err
    assert sum(ln.startswith("mcdenoise ") for ln in lines) == 1, err
    for w in words:
        assert w in lines[-1], lines[-1]
    return lines[-1]


@pytest.fixture
def run_folder(tmp_path):
    spec = load_spec("wskpn-3")
    torch.manual_seed(0)
    run = runs.init_run(tmp_path / "run", spec.path, {})
    runs.save_checkpoint(run, {"model": build_model(spec).state_dict()})
    return run


def test_export_of_a_checkpoint_that_does_not_fit_its_spec(run_folder, tmp_path, capsys):
    spec_file = run_folder / runs.SPEC_FILE
    spec_file.write_text(spec_file.read_text().replace("blocks = 3", "blocks = 4"))
    code = main(["export", str(run_folder), "--out", str(tmp_path / "m.onnx")])
    _one_line_error(capsys, code, "does not match spec.toml")
    assert not (tmp_path / "m.onnx").exists()


def test_export_of_a_corrupt_checkpoint(run_folder, tmp_path, capsys):
    ckpt = run_folder / runs.CHECKPOINT_FILE
    ckpt.write_bytes(ckpt.read_bytes()[:1000])
    code = main(["export", str(run_folder), "--out", str(tmp_path / "m.onnx")])
    _one_line_error(capsys, code, "not a readable checkpoint")


def test_export_error_is_a_one_line_error(run_folder, tmp_path, capsys, monkeypatch):
    """An export that fails its own checks (parity, stages) raises ExportError: a RuntimeError
    for library callers, a one-line error for the command."""
    assert issubclass(onnx_export.ExportError, CommandError) and issubclass(onnx_export.ExportError, RuntimeError)

    def failing(*a, **k):
        raise onnx_export.ExportError("wskpn-3: onnxruntime differs from torch\nby 1e-2 (tolerance 1e-4)")

    monkeypatch.setattr(onnx_export, "export_model", failing)
    code = main(["export", str(run_folder), "--out", str(tmp_path / "m.onnx")])
    _one_line_error(capsys, code, "onnxruntime differs from torch by 1e-2")


def test_training_that_diverges(tiny_dataset, tmp_path, capsys):
    spec_file = tmp_path / "wskpn-3-hot.toml"
    spec_file.write_text(load_spec("wskpn-3").path.read_text().replace("lr = 1e-3", "lr = 1e30"))
    code = main(["train", str(spec_file), "--data", tiny_dataset, "--out", str(tmp_path / "r"), "--steps", "20",
                 "--crop", "32", "--batch-size", "2", "--quiet"])
    _one_line_error(capsys, code, "loss is nan", "last checkpoint kept")


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code = main(["denoise", "--output", str(blocker / "out")])
    _one_line_error(capsys, code)


def test_shared_flags_mean_the_same_in_every_command():
    """--size, --seed, --data and --threads: one definition (runtime.args), in every command
    that takes them."""
    from mcdenoise.runtime.args import SHARED_HELP
    from mcdenoise.runtime.cli import COMMANDS, build_parser

    seen = set()
    for name in COMMANDS:
        parser, _ = build_parser(name)
        for action in parser._actions:
            for flag in set(action.option_strings) & set(SHARED_HELP):
                seen.add(flag)
                assert action.help.startswith(SHARED_HELP[flag]), (name, flag, action.help)
    assert seen == set(SHARED_HELP)


def test_a_test_set_that_fails_to_render(tmp_path, capsys):
    """bench and stress render missing test sets in a subprocess (testsets.render): a render
    that fails is one line naming the set, the command and the render's own error."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    code = main(["stress", "--quick", "--render-dir", str(blocker), "--out", str(tmp_path / "out")])
    line = _one_line_error(capsys, code, "rendering stress set 'base' failed", "mcdenoise render --out")
    assert line.count("mcdenoise render: error:") == 1, line


@pytest.mark.parametrize("argv", [["bench", "--sizes", "foo"], ["bench", "--chart-size", "3x"],
                                  ["render", "--out", "x", "--size", "0x0"], ["denoise", "--output", "o", "--threads", "two"]])
def test_bad_flag_values(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and "Traceback" not in err and err.strip().splitlines()[-1].startswith(f"mcdenoise {argv[0]}: error:"), err


def test_scoring_a_set_still_being_rendered(tiny_dataset, tmp_path, capsys):
    import shutil
    from pathlib import Path

    from mcdenoise.training.dataset import PARTIAL

    data = tmp_path / "data"
    shutil.copytree(tiny_dataset, data)
    seq = sorted(p for p in data.iterdir() if p.is_dir())[-1]
    (seq / PARTIAL).write_text("{}")     # what render keeps there until the sequence is whole
    _one_line_error(capsys, main(["evaluate", "noisy", "--data", str(data), "--no-oidn"]),
                    seq.name, "not finished rendering")
    (seq / PARTIAL).unlink()
    assert main(["evaluate", "noisy", "--data", str(data), "--no-oidn"]) == 0
