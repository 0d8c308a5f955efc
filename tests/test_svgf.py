"""The SVGF-style baseline (runtime/svgf.py): denoises, accumulates over time, follows motion,
keeps edges, survives bad input, resets on a cut or a new resolution, beats the noisy input on
rendered frames."""
import numpy as np
import pytest

from mcdenoise.runtime.frames import read_frame
from mcdenoise.training.methods import load_method
from mcdenoise.training.metrics import psnr
from mcdenoise.training.svgf import ALBEDO_EPS, SVGF


def _plane(h=64, w=64, depth=2.0):
    """Guide layers of a fronto-parallel plane facing the camera."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = -1.0
    pos = np.stack([xx / w, yy / h, np.full_like(xx, depth)], axis=-1)
    return {"normal": normal, "depth": np.full((h, w, 1), depth, np.float32), "position": pos,
            "motion": np.zeros((h, w, 2), np.float32)}


def _gradient_scene(h=64, w=64, shift=0.0):
    """Clean radiance of a smooth illumination gradient times a smooth albedo (x shifted)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xs = xx - shift
    illum = np.stack([0.5 + xs / w, 0.5 + yy / h, 1.0 + 0.5 * np.sin(xs / 9.0)], axis=-1)
    albedo = np.stack([0.3 + 0.4 * yy / h, 0.6 - 0.2 * xs / w, np.full_like(xx, 0.5)], axis=-1)
    return (illum * albedo).astype(np.float32), albedo.astype(np.float32)


def _noisy(clean, rng, spread=0.6):
    return (clean * rng.gamma(1 / spread ** 2, spread ** 2, clean.shape)).astype(np.float32)


def test_method_interface_and_single_frame_gain():
    s = load_method("svgf")
    assert isinstance(s, SVGF) and s.name == "svgf"
    rng = np.random.default_rng(0)
    clean, albedo = _gradient_scene()
    noisy = _noisy(clean, rng)
    out = s(dict(color=noisy, albedo=albedo, **_plane()))
    assert out.shape == (64, 64, 3) and out.dtype == np.float32
    gain = psnr(out, clean) - psnr(noisy, clean)
    assert gain >= 5.0, gain


def test_static_sequence_error_decreases():
    rng = np.random.default_rng(1)
    clean, albedo = _gradient_scene()
    s = SVGF()
    scores = [psnr(s(dict(color=_noisy(clean, rng), albedo=albedo, **_plane())), clean) for _ in range(8)]
    assert scores[1] > scores[0] + 0.5 and scores[7] > scores[3] > scores[1], scores
    assert float(s._length.max()) == 8.0
    # Temporal accumulation alone (no à-trous pass): 1/n blending, then the EMA, must gain a lot.
    rng = np.random.default_rng(1)
    s = SVGF(iterations=0)
    scores = [psnr(s(dict(color=_noisy(clean, rng), albedo=albedo, **_plane())), clean) for _ in range(8)]
    assert scores[4] > scores[0] + 5.0 and scores[7] > scores[0] + 5.0, scores


def test_moving_sequence_follows_motion_vectors():
    # The content moves 2 px right per frame; motion points back to where it was (prev = x + m).
    rng = np.random.default_rng(2)
    h = w = 64
    guides = _plane(h, w)
    guides.pop("position")  # plane is uniform in depth: consistency by depth alone
    guides["motion"][..., 0] = -2.0
    s, scores, scores_wrong = SVGF(), [], []
    s_wrong = SVGF()
    for t in range(6):
        clean, albedo = _gradient_scene(h, w, shift=2.0 * t)
        noisy = _noisy(clean, rng)
        scores.append(psnr(s(dict(color=noisy, albedo=albedo, **guides)), clean))
        wrong = dict(guides, motion=-guides["motion"])
        scores_wrong.append(psnr(s_wrong(dict(color=noisy, albedo=albedo, **wrong)), clean))
    assert scores[5] > scores[0] + 1.0, scores
    assert scores[5] > scores_wrong[5] + 0.5, (scores, scores_wrong)


@pytest.mark.parametrize("edge", ["depth", "normal"])
def test_step_edge_is_not_blurred(edge):
    h, w = 32, 32
    g = _plane(h, w)
    color = np.full((h, w, 3), 0.2, np.float32)
    color[:, w // 2:] = 2.0
    if edge == "depth":
        g["depth"][:, w // 2:] = 5.0
        g["position"][:, w // 2:, 2] = 5.0
    else:
        g["normal"][:, w // 2:] = (1.0, 0.0, 0.0)
    rng = np.random.default_rng(3)
    noisy = _noisy(color, rng, spread=0.3)
    albedo = np.full((h, w, 3), 0.5, np.float32)
    out = SVGF()(dict(color=noisy, albedo=albedo, **g))
    left = out[:, : w // 2].mean(axis=(0, 2))
    right = out[:, w // 2:].mean(axis=(0, 2))
    # Columns right next to the edge keep their side's level (no bleeding across).
    assert abs(left[-1] - 0.2) < 0.05 and abs(left[-2] - 0.2) < 0.05, left
    assert abs(right[0] - 2.0) < 0.3 and abs(right[1] - 2.0) < 0.3, right
    # Without guides the same filter does blur across (the edge-stopping is what holds it).
    flat = SVGF()(dict(color=noisy, albedo=albedo, **_plane(h, w)))
    assert flat[:, w // 2 - 1].mean() > left[-1] + 0.1


def test_nonfinite_input_gives_finite_output_and_state():
    rng = np.random.default_rng(4)
    clean, albedo = _gradient_scene(32, 32)
    s = SVGF()
    for t in range(3):
        fr = dict(color=_noisy(clean, rng), albedo=albedo.copy(), **_plane(32, 32))
        fr["color"][5, 5] = np.nan
        fr["color"][6, 6] = np.inf
        fr["color"][7, 7] = -np.inf
        fr["color"][8, 8] = -3.0
        fr["albedo"][9, 9] = np.nan
        fr["normal"][10, 10] = np.inf
        fr["depth"][11, 11] = np.nan
        fr["position"][12, 12] = -np.inf
        fr["motion"][13, 13] = np.nan
        out = s(fr)
        assert np.isfinite(out).all() and (out >= 0).all()
        for st in (s._illum, s._moments, s._length):
            assert np.isfinite(st).all()
    # counted per value: 3 pixels x 3 channels x 3 frames non-finite, 1 pixel negative
    assert s.report.nonfinite["color"] == 27 and s.report.negative["color"] == 9
    # All-NaN colour: still finite.
    out = s(dict(color=np.full((32, 32, 3), np.nan, np.float32), albedo=albedo, **_plane(32, 32)))
    assert np.isfinite(out).all()


def test_reset_on_resolution_change_cut_and_reset():
    rng = np.random.default_rng(5)
    s = SVGF()
    clean, albedo = _gradient_scene(32, 32)
    for _ in range(3):
        s(dict(color=_noisy(clean, rng), albedo=albedo, **_plane(32, 32)))
    assert float(s._length.max()) == 3.0
    clean2, albedo2 = _gradient_scene(24, 40)
    out = s(dict(color=_noisy(clean2, rng), albedo=albedo2, **_plane(24, 40)))
    assert out.shape == (24, 40, 3) and float(s._length.max()) == 1.0
    s(dict(color=_noisy(clean2, rng), albedo=albedo2, **_plane(24, 40)))
    assert float(s._length.max()) == 2.0
    s(dict(color=_noisy(clean2, rng), albedo=albedo2, meta={"cut": True}, **_plane(24, 40)))
    assert float(s._length.max()) == 1.0
    s.reset()
    assert s._illum is None


def test_plain_colour_input_and_identity_modulation():
    # Colour only (no albedo / guides) works; a constant image stays constant (weights are
    # normalised, demodulation by albedo + eps is undone exactly).
    s = SVGF()
    out = s(np.full((16, 16, 3), 0.7, np.float32))
    np.testing.assert_allclose(out, 0.7, rtol=1e-5)
    albedo = np.full((16, 16, 3), 0.25, np.float32)
    out = SVGF()(dict(color=np.full((16, 16, 3), 0.3, np.float32), albedo=albedo, **_plane(16, 16)))
    np.testing.assert_allclose(out, 0.3, rtol=1e-5)
    assert ALBEDO_EPS == 1e-2


def test_beats_noisy_input_on_rendered_frames(tiny_dataset):
    from mcdenoise.training.testsets import at_spp, sequences

    outs, noisy, refs = [], [], []
    s = SVGF()
    for paths in sequences(tiny_dataset):
        s.reset()
        for p in paths:
            fr = at_spp(read_frame(p), 1)
            outs.append(s(fr))
            noisy.append(fr.color)
            refs.append(fr.reference)
    p_svgf = psnr(np.stack(outs), np.stack(refs))
    p_noisy = psnr(np.stack(noisy), np.stack(refs))
    assert p_svgf > p_noisy + 3.0, (p_svgf, p_noisy)
