"""``mcdenoise stress``: a quick run on the tiny data set (no rendering beyond the fixture), the
perturbations it is built from, and the failure rule."""
from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest

from mcdenoise.runtime.cli import main as cli_main
from mcdenoise.runtime.frames import SAMPLE_GROUPS, read_frame
from mcdenoise.training.methods import shipped_models
from mcdenoise.training import report, stress, testsets
from mcdenoise.training.render import procedural

MODELS = [os.path.splitext(os.path.basename(p))[0] for p in shipped_models()]
EXTRA = ["noisy", "svgf"]
PERTURBATION_CASES = ("fireflies", "nan-inf", "cut", "cut-unflagged", "dark", "bright", "1spp")
RENDERED_CASES = tuple(c[0] for c in stress.RENDERED_CASES)


@pytest.fixture(scope="module")
def quick_run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("stress")
    argv = ["stress", *shipped_models(), *EXTRA, "--data", tiny_dataset, "--quick", "--no-render",
            "--render-dir", str(out / "no-sets"), "--out", str(out / "results")]
    assert cli_main(argv) == 0
    with open(out / "results" / "stress.csv") as fh:
        rows = {(r["case"], r["method"]): r for r in csv.DictReader(fh)}
    return out / "results", rows


@pytest.fixture(scope="module")
def frame(tiny_dataset):
    from mcdenoise.training.testsets import sequences

    return read_frame(sequences(tiny_dataset)[0][1])


def test_table_has_every_case_and_method(quick_run):
    out, rows = quick_run
    methods = MODELS + EXTRA
    assert {c for c, _ in rows} == set(PERTURBATION_CASES + RENDERED_CASES)
    for case in PERTURBATION_CASES + RENDERED_CASES:
        for m in methods:
            assert (case, m) in rows, (case, m)
    for case in PERTURBATION_CASES:  # run, scored, finite numbers
        for m in methods:
            r = rows[(case, m)]
            assert not r["skipped"] and not r["error"], r
            assert np.isfinite(float(r["psnr_case"])) and np.isfinite(float(r["delta_db"]))
    for case in RENDERED_CASES:  # --no-render: said so, not silently dropped
        assert all("not rendered" in rows[(case, m)]["skipped"] for m in methods)
    md = (out / "stress.md").read_text()
    assert "mcdenoise stress" in md and "--quick" in md and "## Failure rule" in md
    for case in PERTURBATION_CASES:
        assert f"| {case} |" in md


def test_models_stay_finite_on_nonfinite_input(quick_run):
    _, rows = quick_run
    for m in MODELS:
        r = rows[("nan-inf", m)]
        assert r["nonfinite_output_values"] == "0" and not r["error"], r
        assert "non-finite" not in r["failed"]
    # the input really was non-finite: the noisy input passes it through
    assert int(rows[("nan-inf", "noisy")]["nonfinite_output_values"]) > 0


def test_flagged_and_unflagged_cuts_reset_the_driver(quick_run):
    _, rows = quick_run
    for m in MODELS + ["noisy"]:
        assert float(rows[("cut", m)]["delta_db"]) == 0.0, rows[("cut", m)]
    from mcdenoise.runtime.denoiser import Denoiser

    drivers = [Denoiser.load(p, log=lambda m: None) for p in shipped_models()]
    temporal = {d.contract.spec_name: d.protocol.temporal for d in drivers}
    for m in MODELS:
        assert int(rows[("cut", m)]["driver_resets"]) >= 1
        # a model with a history: its history test finds the unflagged cut (under CUT_HISTORY of
        # the pixels kept), and the driver starts a new history there as at a flagged one; a
        # model without one has no test to find it by (its exposure stays the sequence's)
        assert (int(rows[("cut-unflagged", m)]["driver_resets"]) >= 1) == temporal[m], m
        if temporal[m]:
            assert float(rows[("cut-unflagged", m)]["delta_db"]) == 0.0, rows[("cut-unflagged", m)]
    assert not all(temporal.values()) and any(temporal.values())


def test_crops_are_written(quick_run):
    out, _ = quick_run
    for case in PERTURBATION_CASES:
        path = out / "stress" / f"{case}.png"
        data = path.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) < 200_000, case
    assert not (out / "stress" / "glossy.png").exists()


def test_exposure_scales_reference_and_is_undone_for_scoring(frame, quick_run):
    _, rows = quick_run
    for name, k in stress.EXPOSURES.items():
        f = stress.exposed(frame, k)
        np.testing.assert_allclose(f.reference, frame.reference * np.float32(k), rtol=1e-6)
        np.testing.assert_allclose(f.color, frame.color * np.float32(k), rtol=1e-6)
        np.testing.assert_allclose(f.samples[..., SAMPLE_GROUPS["radiance"]],
                                   frame.samples[..., SAMPLE_GROUPS["radiance"]] * np.float32(k), rtol=1e-6)
        np.testing.assert_array_equal(f.albedo, frame.albedo)
        # the noisy input scales exactly, so it loses nothing once the factor is undone
        assert abs(float(rows[(name, "noisy")]["delta_db"])) < 0.01


def test_fireflies_are_samples_at_500x_the_image_mean(frame):
    clean = testsets.at_spp(frame, 4)
    f, where = stress.inject_fireflies(clean, np.random.default_rng(0))
    h, w = clean.size
    assert len(where) == max(1, round(stress.FIREFLY_DENSITY * h * w))
    value = 500.0 * float(np.mean(clean.color, dtype=np.float64))
    rad = f.samples[..., SAMPLE_GROUPS["radiance"]]
    s, y, x = where.T
    np.testing.assert_allclose(rad[s, y, x], value, rtol=1e-5)
    changed = np.any(rad != clean.samples[..., SAMPLE_GROUPS["radiance"]], axis=-1)
    assert changed.sum() == len(where)
    # pixel layers recomputed from the samples
    np.testing.assert_allclose(f.color, rad.mean(axis=0), rtol=1e-6)
    assert f.color[y, x].min() >= value / 4 * 0.999


def test_nonfinite_injection(frame):
    clean = testsets.at_spp(frame, 4)
    f, where = stress.inject_nonfinite(clean, np.random.default_rng(0))
    assert set(where) == {"nan-radiance", "inf-radiance", "nan-sample"}
    s, y, x = where["inf-radiance"].T
    assert np.isposinf(f.color[y, x]).all()
    s, y, x = where["nan-sample"].T
    assert np.isnan(f.samples[s, y, x]).all() and np.isnan(f.motion[y, x]).all()
    assert np.isnan(f.color).any() and np.isfinite(clean.color).all()


def test_failure_rule():
    noisy = {"psnr_case": 20.0, "delta_db": -1.0, "nonfinite": 5}
    ok = {"psnr_case": 25.0, "delta_db": -3.5, "nonfinite": 0}
    assert stress.judge("m", ok, noisy) is None
    assert "more than the noisy" in stress.judge("m", {**ok, "delta_db": -4.5}, noisy)
    assert "worse than the noisy" in stress.judge("m", {**ok, "psnr_case": 19.0}, noisy)
    assert "non-finite" in stress.judge("m", {**ok, "nonfinite": 1}, noisy)
    assert stress.judge("m", {**ok, "error": "ValueError: x"}, noisy) == "crashed"
    assert stress.judge("noisy", noisy, noisy) is None


def test_worst_window():
    m = np.zeros((20, 30))
    m[12:15, 3:6] = 1.0
    assert report.worst_window({(0, 0): np.zeros((20, 30)), (1, 2): m}, 4)[0] == (1, 2)
    key, y, x = report.worst_window({(1, 2): m}, 3)
    assert (y, x) == (12, 3)


def test_render_options_keep_the_scene():
    a = procedural.generate(7, 64, 64, 3, defocus=1.0)
    b = procedural.generate(7, 64, 64, 3, defocus=1.0, aperture_scale=6.0, floor="glossy")
    assert b.intrinsics.aperture_radius == pytest.approx(6.0 * a.intrinsics.aperture_radius)
    assert b.objects["floor"]["bsdf"]["bsdf"]["type"] == "roughconductor"
    assert b.materials["floor"]["kind"] == "roughconductor"
    rest = lambda s: json.dumps({k: v for k, v in s.objects.items() if k != "floor"}, sort_keys=True)
    assert rest(a) == rest(b) and a.path == b.path
    with pytest.raises(ValueError, match="floor"):
        procedural.generate(7, 64, 64, 3, floor="lava")


def test_a_methods_copy_of_a_frame_keeps_every_layer(frame):
    """The copy each method gets holds every pixel layer of the frame format (a model reading
    the emissive layer crashed on every case while the copy listed the layers by hand)."""
    from mcdenoise.runtime.frames import PIXEL_LAYERS

    f = frame
    got = stress._fresh(f)
    for layer in PIXEL_LAYERS:
        src = getattr(f, layer.name)
        assert (getattr(got, layer.name) is None) == (src is None), layer.name
        if src is not None:
            np.testing.assert_array_equal(getattr(got, layer.name), src)
            assert getattr(got, layer.name) is not src
    assert f.emissive is not None

