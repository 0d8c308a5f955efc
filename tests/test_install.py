"""The package as a user gets it: a wheel, installed into a clean virtual environment without
torch, running the main job (``mcdenoise denoise`` on the shipped sample) from a directory
outside the checkout. Needs pip to reach a package index (or its cache) for numpy,
onnxruntime and OpenEXR, as any install does."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from mcdenoise.training.specs import tomllib

REPO = Path(__file__).resolve().parent.parent


def _run(cmd, **kw):
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, **kw)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built from a copy of the package's folders (so the build leaves nothing in the
    checkout), without build isolation: the installed setuptools builds it, offline."""
    src = tmp_path_factory.mktemp("src")
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    for folder in set(config["tool"]["setuptools"]["package-dir"].values()):
        shutil.copytree(REPO / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out), str(src)])
    (whl,) = out.glob("mcdenoise-*.whl")
    return whl


def test_wheel_installs_one_namespace_with_its_data(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"mcdenoise", next(t for t in tops if t.endswith(".dist-info"))}, tops
    for need in ("mcdenoise/runtime/denoiser.py", "mcdenoise/training/models/wskpn.py",
                 "mcdenoise/export/onnx_export.py", "mcdenoise/models/wskpn-3.onnx", "mcdenoise/models/wskpn-3.md",
                 "mcdenoise/models_spec/wskpn-3.toml", "mcdenoise/samples/sequence/scene_0300000/frame_0000.exr"):
        assert need in names, need
    shipped = sorted(p.relative_to(REPO).as_posix() for d in ("models", "models_spec", "samples")
                     for p in (REPO / d).rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    assert sorted(n[len("mcdenoise/"):] for n in names if n.split("/")[1] in ("models", "models_spec", "samples")) == shipped


def test_wheel_alone_runs_the_main_job_outside_the_checkout(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, clear=True).create(env_dir)
    py = env_dir / ("Scripts" if os.name == "nt" else "bin") / "python"
    _run([str(py), "-m", "pip", "install", "-q", str(wheel)])
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    probe = _run([str(py), "-c", "import importlib.util as u, json, mcdenoise.runtime as r; print(json.dumps("
                  "[str(r.__file__), [n for n in ('torch', 'runtime', 'training', 'export') if u.find_spec(n)]]))"],
                 cwd=work, env=env)
    where, importable = json.loads(probe.stdout)
    assert Path(where).resolve().is_relative_to(env_dir.resolve()), where
    assert importable == [], f"a clean environment with the wheel alone can import {importable}"
    mcd = env_dir / ("Scripts" if os.name == "nt" else "bin") / "mcdenoise"
    proc = _run([str(mcd), "denoise", "--output", "out", "--json", "out/run.json"], cwd=work, env=env)
    assert "PSNR vs reference" in proc.stdout
    report = json.loads((work / "out" / "run.json").read_text())
    assert len(list((work / "out").rglob("*.exr"))) == 6
    assert report["psnr_db"] > 20, report["psnr_db"]
    # Commands that need what the wheel alone does not bring say so in one line.
    proc = subprocess.run([str(mcd), "train", "wskpn-3", "--data", "d", "--out", "r"], cwd=work, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "torch" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_the_carried_mitsuba_wheel_keeps_only_the_variants_asked_for(tmp_path):
    """training.carry strips a Mitsuba wheel for a machine without network: the other
    variants' modules leave the archive and its RECORD, everything else stays."""
    from mcdenoise.training.carry import strip_wheel

    src, dst = tmp_path / "mitsuba-9-py3-none-any.whl", tmp_path / "out.whl"
    files = {f"mitsuba/{v}.cpython-311-x86_64-linux-gnu.so": b"x" * 10
             for v in ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb", "cuda_ad_spectral")}
    files.update({"mitsuba/__init__.py": b"", "mitsuba/plugins/path.so": b"p"})
    record = "".join(f"{n},sha256=x,1\n" for n in files) + "mitsuba-9.dist-info/RECORD,,\n"
    with zipfile.ZipFile(src, "w") as z:
        for n, data in files.items():
            z.writestr(n, data)
        z.writestr("mitsuba-9.dist-info/RECORD", record)
    assert strip_wheel(src, dst, ("cuda_ad_rgb", "scalar_rgb")) == ["cuda_ad_spectral", "llvm_ad_rgb"]
    with zipfile.ZipFile(dst) as z:
        names = set(z.namelist())
        rec = z.read("mitsuba-9.dist-info/RECORD").decode()
    assert names == {n for n in files if "llvm" not in n and "spectral" not in n} | {"mitsuba-9.dist-info/RECORD"}
    assert "llvm_ad_rgb" not in rec and "cuda_ad_rgb" in rec and "plugins/path.so" in rec
