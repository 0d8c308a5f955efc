"""Frame format: round trip, the plain (OIDN-style) reader, and clear errors on bad files."""
import numpy as np
import OpenEXR
import pytest

from mcdenoise.runtime import frames as F
from mcdenoise.runtime import writers as W


def _frame(h=6, w=7, spp=2, seed=0):
    rng = np.random.default_rng(seed)
    r = lambda *s: rng.random(s, dtype=np.float32)
    return F.Frame(color=r(h, w, 3), albedo=r(h, w, 3), normal=r(h, w, 3), depth=r(h, w, 1),
                   emissive=r(h, w, 1), position=r(h, w, 3), motion=r(h, w, 2), valid=np.ones((h, w, 1), np.float32),
                   reference=r(h, w, 3), samples=r(spp, h, w, len(F.SAMPLE_FEATURES)),
                   meta={"scene_seed": 7, "frame": 3})


def _write_raw(path, channels):
    """An EXR with exactly ``channels`` (name -> 2-D array), bypassing write_frame's checks."""
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(str(path))


def test_round_trip_is_exact(tmp_path):
    fr = _frame()
    W.write_frame(tmp_path / "f.exr", fr)
    back = F.read_frame(tmp_path / "f.exr")
    for layer in F.PIXEL_LAYERS:
        np.testing.assert_array_equal(getattr(back, layer.name), getattr(fr, layer.name))
    np.testing.assert_array_equal(back.samples, fr.samples)
    assert back.meta["scene_seed"] == 7 and back.meta["spp"] == 2
    assert back.spp == 2 and back.size == (6, 7)
    assert F.read_frame(tmp_path / "f.exr", samples=1).spp == 1
    assert F.read_frame(tmp_path / "f.exr", samples=False).samples is None


def test_a_file_from_before_the_emissive_layer_gets_it_from_its_samples(tmp_path):
    fr = _frame(spp=3)
    fr.samples[..., F.SAMPLE_GROUPS["emissive"]] = np.arange(3, dtype=np.float32)[:, None, None, None] < 1
    fr.emissive = None
    W.write_frame(tmp_path / "f.exr", fr)
    np.testing.assert_array_equal(F.read_frame(tmp_path / "f.exr").emissive, np.full((6, 7, 1), 1 / 3, np.float32))
    # from part of the samples it would be another mean: left out rather than made up
    assert F.read_frame(tmp_path / "f.exr", samples=1).emissive is None
    assert F.read_frame(tmp_path / "f.exr", samples=False).emissive is None


def test_sample_groups_cover_every_feature_once():
    covered = [i for s in F.SAMPLE_GROUPS.values() for i in range(s.start, s.stop)]
    assert covered == list(range(len(F.SAMPLE_FEATURES)))
    fr = _frame()
    np.testing.assert_array_equal(fr.sample_feature("motion"), fr.samples[..., 21:23])


def test_diffuse_specular_split_sums_to_radiance():
    fr = _frame(spp=2)
    fr.samples[..., F.SAMPLE_GROUPS["specular"]] = (fr.samples[..., F.SAMPLE_GROUPS["specular"]] > 0.5)
    d, s = fr.sample_feature("diffuse_radiance"), fr.sample_feature("specular_radiance")
    np.testing.assert_allclose(d + s, fr.sample_feature("radiance"), rtol=1e-6)
    spec = fr.samples[..., 17] > 0.5
    assert np.all(d[spec] == 0) and np.all(s[~spec] == 0)
    with pytest.raises(F.FrameError, match="unknown sample feature 'glossy'"):
        fr.sample_feature("glossy")


def test_pixel_means_from_samples():
    fr = _frame(spp=3)
    px = F.pixel_means(fr.samples)
    np.testing.assert_allclose(px["color"], fr.samples[..., 0:3].mean(0), rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(px["normal"], axis=-1), 1.0, rtol=1e-5)


def test_frame_paths_lists_only_frame_files(tmp_path):
    for name in (F.frame_name(1), F.frame_name(0), "tex0.exr", "sky.exr", "frame_0000.png"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "scene").mkdir()
    assert F.frame_paths(tmp_path) == [str(tmp_path / F.frame_name(t)) for t in (0, 1)]


def test_missing_file_names_it(tmp_path):
    with pytest.raises(F.FrameError, match="nope.exr: no such file"):
        F.read_frame(tmp_path / "nope.exr")


def test_missing_channel_names_file_and_channel(tmp_path):
    fr = _frame()
    fr.albedo = None
    W.write_frame(tmp_path / "f.exr", fr)
    with pytest.raises(F.FrameError, match=r"f\.exr: missing channel 'albedo\.R'"):
        F.read_frame(tmp_path / "f.exr", require=("color", "albedo"))
    with pytest.raises(F.FrameError, match="missing layer 'albedo'"):
        F.read_frame(tmp_path / "f.exr").layer("albedo")


def test_partially_missing_layer_names_the_channel(tmp_path):
    h, w = 4, 5
    ch = {f"color.{c}": np.ones((h, w), np.float32) for c in "RGB"}
    ch["normal.X"] = np.ones((h, w), np.float32)
    _write_raw(tmp_path / "p.exr", ch)
    with pytest.raises(F.FrameError, match=r"p\.exr: missing channel 'normal\.Y'"):
        F.read_frame(tmp_path / "p.exr")


def test_truncated_file_is_a_clear_error(tmp_path):
    W.write_frame(tmp_path / "f.exr", _frame(h=32, w=32))
    data = (tmp_path / "f.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) // 3])
    with pytest.raises(F.FrameError, match=r"t\.exr: .*(truncated|not a readable)"):
        F.read_frame(tmp_path / "t.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr at all")
    with pytest.raises(F.FrameError, match=r"junk\.exr: not a readable OpenEXR"):
        F.read_frame(tmp_path / "junk.exr")


def test_wrong_dtype_names_channel(tmp_path):
    h, w = 4, 5
    ch = {f"color.{c}": np.ones((h, w), np.float32) for c in "RG"}
    ch["color.B"] = np.ones((h, w), np.uint32)
    _write_raw(tmp_path / "u.exr", ch)
    with pytest.raises(F.FrameError, match=r"u\.exr: channel 'color\.B' has dtype uint32"):
        F.read_frame(tmp_path / "u.exr")


def test_half_channels_are_accepted_as_float32(tmp_path):
    h, w = 4, 5
    ch = {c: np.full((h, w), 0.5, np.float16) for c in "RGB"}
    _write_raw(tmp_path / "h.exr", ch)
    img = F.read_rgb(tmp_path / "h.exr")
    assert img.dtype == np.float32 and img.shape == (h, w, 3) and np.all(img == 0.5)


def test_plain_oidn_style_inputs(tmp_path):
    rng = np.random.default_rng(1)
    col, alb = rng.random((5, 6, 3), dtype=np.float32), rng.random((5, 6, 3), dtype=np.float32)
    W.write_rgb(tmp_path / "color.exr", col)
    W.write_rgb(tmp_path / "albedo.exr", alb)
    # PFM is stored bottom-to-top, little-endian when the scale is negative.
    with open(tmp_path / "normal.pfm", "wb") as fh:
        fh.write(b"PF\n6 5\n-1.0\n" + col[::-1].astype("<f4").tobytes())
    fr = F.read_plain(tmp_path / "color.exr", tmp_path / "albedo.exr", tmp_path / "normal.pfm")
    np.testing.assert_array_equal(fr.color, col)
    np.testing.assert_array_equal(fr.albedo, alb)
    np.testing.assert_array_equal(fr.normal, col)
    W.write_rgb(tmp_path / "small.exr", col[:4])
    with pytest.raises(F.FrameError, match="albedo image is 6x4, colour .* is 6x5"):
        F.read_plain(tmp_path / "color.exr", tmp_path / "small.exr")


def test_plain_emissive_image(tmp_path):
    """The emissive layer of a plain input (models that read it: wskpn-6e): a one-channel image,
    an EXR E channel as our frames store it or a grey RGB EXR; a value outside [0, 1] (not a
    fraction of samples) is refused by name."""
    import OpenEXR

    rng = np.random.default_rng(3)
    col = rng.random((5, 6, 3), dtype=np.float32)
    e = (rng.random((5, 6)) < 0.3).astype(np.float32)
    W.write_rgb(tmp_path / "color.exr", col)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"E": e}).write(str(tmp_path / "e.exr"))
    W.write_rgb(tmp_path / "grey.exr", np.repeat(e[..., None], 3, axis=-1))
    for name in ("e.exr", "grey.exr"):
        fr = F.read_plain(tmp_path / "color.exr", emissive=tmp_path / name)
        assert fr.emissive.shape == (5, 6, 1)
        np.testing.assert_array_equal(fr.emissive[..., 0], e)
    W.write_rgb(tmp_path / "bright.exr", np.repeat(2 * e[..., None], 3, axis=-1))
    with pytest.raises(F.FrameError, match=r"emissive image holds the fraction .* in \[0, 1\]; found \d+ pixel"):
        F.read_plain(tmp_path / "color.exr", emissive=tmp_path / "bright.exr")


def test_plain_depth_image(tmp_path):
    """A depth image for a plain input: an EXR Z channel, a greyscale PFM or a grey RGB EXR
    give the same (H, W, 1) plane; a colour PFM or different R, G, B are refused by name."""
    import OpenEXR

    rng = np.random.default_rng(2)
    col = rng.random((5, 6, 3), dtype=np.float32)
    d = (1 + rng.random((5, 6))).astype(np.float32)
    W.write_rgb(tmp_path / "color.exr", col)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"Z": d}).write(str(tmp_path / "z.exr"))
    with open(tmp_path / "d.pfm", "wb") as fh:
        fh.write(b"Pf\n6 5\n-1.0\n" + d[::-1].astype("<f4").tobytes())
    W.write_rgb(tmp_path / "grey.exr", np.repeat(d[..., None], 3, axis=-1))
    for name in ("z.exr", "d.pfm", "grey.exr"):
        fr = F.read_plain(tmp_path / "color.exr", depth=tmp_path / name)
        assert fr.depth.shape == (5, 6, 1)
        np.testing.assert_array_equal(fr.depth[..., 0], d)
        fr.validate()
    with open(tmp_path / "c.pfm", "wb") as fh:
        fh.write(b"PF\n6 5\n-1.0\n" + col[::-1].astype("<f4").tobytes())
    with pytest.raises(F.FrameError, match="greyscale PFM"):
        F.read_plain(tmp_path / "color.exr", depth=tmp_path / "c.pfm")
    with pytest.raises(F.FrameError, match="found different R, G, B"):
        F.read_plain(tmp_path / "color.exr", depth=tmp_path / "color.exr")
    W.write_rgb(tmp_path / "small.exr", np.repeat(d[:4, :, None], 3, axis=-1))
    with pytest.raises(F.FrameError, match="depth image is 6x4, colour .* is 6x5"):
        F.read_plain(tmp_path / "color.exr", depth=tmp_path / "small.exr")


def test_validate_rejects_wrong_shapes():
    fr = _frame()
    fr.depth = np.zeros((6, 7, 3), np.float32)
    with pytest.raises(F.FrameError, match=r"layer 'depth' has shape \(6, 7, 3\), expected \(6, 7, 1\)"):
        fr.validate()


def test_describe_and_png(tmp_path):
    W.write_frame(tmp_path / "f.exr", _frame())
    from mcdenoise.runtime.inspect import describe

    text = describe(tmp_path / "f.exr")
    assert "per-sample layers: 2 samples" in text and "scene_seed: 7" in text
    W.write_png(tmp_path / "a.png", np.full((3, 4, 3), 0.5))
    data = (tmp_path / "a.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and b"IHDR" in data
