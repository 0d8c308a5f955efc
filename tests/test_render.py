"""The renderer (``mcdenoise render``): layout and manifest of the tiny dataset, exactness of
per-sample data, motion vectors, scene export, user scenes, variant choice.

Works with either Mitsuba variant (``MCDENOISE_TEST_VARIANT``, see tests/conftest.py).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from mcdenoise.runtime.cli import main as cli_main
from mcdenoise.runtime.frames import MANIFEST, PIXEL_LAYERS, SAMPLE_FEATURES, SAMPLE_GROUPS, frame_name, pixel_means, read_frame
from tests.conftest import REPO, TINY_ARGS, render_variant
from mcdenoise.training.render import camera as cam
from mcdenoise.training.render import command, procedural
from mcdenoise.training.render.variant import choose_variant, llvm_major

G = SAMPLE_GROUPS
SEQS = ("scene_0000000", "scene_0000001")


def tiny_args() -> argparse.Namespace:
    p = argparse.ArgumentParser()
    command.add_arguments(p)
    return p.parse_args(["--out", "unused", *TINY_ARGS])


@pytest.fixture(scope="module")
def mi():
    from mcdenoise.training.render.variant import init_mitsuba

    return init_mitsuba(choose_variant(render_variant())[0])


@pytest.fixture(scope="module")
def frames(tiny_dataset):
    """{sequence folder: [Frame t=0, 1, 2]} of the tiny dataset."""
    return {s: [read_frame(os.path.join(tiny_dataset, s, frame_name(t))) for t in range(3)] for s in SEQS}


def bilinear(img: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Sample img (H, W, C) at (x, y) + motion (pixel centres at +0.5 in both, so indices add)."""
    h, w = img.shape[:2]
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    px, py = xs + motion[..., 0], ys + motion[..., 1]
    x0, y0 = np.floor(px).astype(int), np.floor(py).astype(int)
    fx, fy = (px - x0)[..., None], (py - y0)[..., None]
    tap = lambda dx, dy: img[np.clip(y0 + dy, 0, h - 1), np.clip(x0 + dx, 0, w - 1)]
    return (tap(0, 0) * (1 - fx) * (1 - fy) + tap(1, 0) * fx * (1 - fy)
            + tap(0, 1) * (1 - fx) * fy + tap(1, 1) * fx * fy)


def tonemap(x: np.ndarray) -> np.ndarray:
    x = np.maximum(x, 0.0)
    return x / (1.0 + x)


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------

def test_help_works_without_importing_mitsuba():
    code = ("import sys\nfrom mcdenoise.runtime.cli import main\n"
            "try:\n    main(['render', '--help'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code\n"
            "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    for flag in ("--out", "--scenes", "--frames", "--spp", "--ref-spp", "--size", "--seed", "--defocus",
                 "--motion-blur", "--variant", "--scene", "--camera-path", "--workers"):
        assert flag in proc.stdout


def test_cli_errors_are_one_line(tmp_path, capsys):
    out = str(tmp_path / "o")
    with pytest.raises(SystemExit) as e:
        cli_main(["render", "--out", out, "--size", "64"])
    assert e.value.code == 2 and "size must look like 256x256" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["render", "--out", out, "--defocus", "1.5"])
    assert "probability must be in [0, 1]" in capsys.readouterr().err

    assert cli_main(["render", "--out", out, "--scene", str(tmp_path / "nope.xml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("nope.xml: scene file not found") and "\n" not in err
    assert cli_main(["render", "--out", out, "--camera-path", "p.json"]) == 2
    assert "--camera-path needs --scene" in capsys.readouterr().err


def test_unloadable_scene_file_is_a_clear_error(tmp_path, capsys, mi):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='no_such_plugin'/></scene>")
    rc = cli_main(["render", "--out", str(tmp_path / "o"), "--scene", str(bad), "--frames", "1",
                   "--variant", render_variant()])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2 and "bad.xml: Mitsuba cannot load this scene" in err


def test_render_failure_is_one_line_naming_the_scene(tmp_path, capsys, monkeypatch, mi):
    from mcdenoise.training.render import renderer

    def fail(self, shape, position):
        raise RuntimeError("first line\nshape_index 7 hits lie outside shape 'x'")

    monkeypatch.setattr(renderer.SequenceRenderer, "check_shape_ids", fail)
    rc = cli_main(["render", "--out", str(tmp_path / "o"), "--scenes", "1", "--frames", "1", "--size", "16x16",
                   "--spp", "1", "--ref-spp", "1", "--seed", "3", "--variant", render_variant()])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert err.strip().splitlines()[-1] == ("mcdenoise render: error: scene_0300000: frame 0: "
                                            "shape_index 7 hits lie outside shape 'x'")


def test_variant_choice(monkeypatch):
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.18.1") == 18
    assert llvm_major("/usr/lib/llvm-17/lib/libLLVM.so") == 17
    assert choose_variant("scalar_rgb")[0] == "scalar_rgb"
    with pytest.raises(ValueError, match="unknown variant"):
        choose_variant("optix_rgb")
    assert choose_variant("cuda_ad_rgb")[0] == "cuda_ad_rgb"     # only when asked: auto never picks it
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")
    variant, reason = choose_variant("auto")
    assert variant == "scalar_rgb" and "LLVM 15" in reason
    with pytest.raises(ValueError, match="LLVM >= 16"):
        choose_variant("llvm_ad_rgb")
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    monkeypatch.setattr("mcdenoise.training.render.variant.find_llvm", lambda: None)
    variant, reason = choose_variant("auto")
    assert variant == "scalar_rgb" and "no LLVM" in reason
    monkeypatch.setattr("mcdenoise.training.render.variant.find_llvm", lambda: ("/opt/libLLVM-19.so", 19))
    assert choose_variant("auto")[0] == "llvm_ad_rgb" and os.environ["DRJIT_LIBLLVM_PATH"] == "/opt/libLLVM-19.so"


# ----------------------------------------------------------------------------------------------
# The tiny dataset: layout, manifest, per-sample data
# ----------------------------------------------------------------------------------------------

def test_layout_and_manifest(tiny_dataset, frames):
    with open(os.path.join(tiny_dataset, MANIFEST)) as fh:
        manifest = json.load(fh)
    seqs = manifest["sequences"]
    assert [s["folder"] for s in seqs] == list(SEQS)
    for i, s in enumerate(seqs):
        assert s["scene_seed"] == i and s["frames"] == 3 and s["spp"] == 4 and s["ref_spp"] == 64
        assert s["size"] == [64, 64] and s["variant"] in ("llvm_ad_rgb", "scalar_rgb")
        assert s["defocus"] is False and s["motion_blur"] is False and s["render_seconds"] > 0
        folder = os.path.join(tiny_dataset, s["folder"])
        assert sorted(n for n in os.listdir(folder) if n.endswith(".exr")) == [frame_name(t) for t in range(3)]
        for name in ("scene.xml", "scene.json", "camera_path.json"):
            assert os.path.isfile(os.path.join(folder, "scene", name))
    for seq, fs in frames.items():
        for t, f in enumerate(fs):
            for layer in PIXEL_LAYERS:
                assert f.layer(layer.name).shape == (64, 64, len(layer.channels)), layer.name
            assert f.samples.shape == (4, 64, 64, len(SAMPLE_FEATURES))
            m = f.meta
            assert (m["frame"], m["scene"], m["spp"], m["ref_spp"], m["cut"]) == (t, seq, 4, 64, t == 0)
            assert m["scene_seed"] == SEQS.index(seq) and m["variant"] == seqs[0]["variant"]
            assert np.asarray(m["camera"]["to_world"]).shape == (4, 4) and m["camera"]["aperture_radius"] == 0
            assert len(m["time"]) == 4 and m["motion_blur"] is False
            assert np.all(np.isfinite(f.samples)) and np.all(np.isfinite(f.reference))
        assert not fs[0].valid.any() and not fs[0].motion.any()
        assert all(f.valid.mean() > 0.3 for f in fs[1:])


def test_pixel_layers_and_sample_features(frames):
    for fs in frames.values():
        for t, f in enumerate(fs):
            s = f.samples
            px = pixel_means(s)
            for name in ("color", "albedo", "normal", "depth", "position"):
                np.testing.assert_array_equal(f.layer(name), px[name])
            hit = s[..., G["depth"]][..., 0] > 0
            assert 0.2 < hit.mean() < 1.0  # both geometry and sky (or far floor misses) in view
            n = np.linalg.norm(s[..., G["normal"]], axis=-1)
            np.testing.assert_allclose(n[hit], 1.0, atol=1e-3)
            for g in ("albedo", "normal", "depth", "position", "roughness", "metallic", "transmissive",
                      "emissive", "specular", "specular_color", "motion", "coc"):
                assert not s[~hit][..., G[g]].any(), f"{g} is not 0 on misses"
            for g in ("metallic", "transmissive", "emissive", "specular"):
                assert set(np.unique(s[..., G[g]])) <= {0.0, 1.0}, g
            rough, spec = s[..., G["roughness"]], s[..., G["specular"]]
            assert rough.min() >= 0 and rough.max() <= 1
            assert np.all(spec >= np.maximum(s[..., G["metallic"]], s[..., G["transmissive"]]))
            assert s[..., G["specular_color"]].min() >= 0 and s[..., G["specular_color"]].max() <= 1
            assert not s[..., G["coc"]].any() and not s[..., G["time"]].any()

            # depth is the distance from the camera to the position (pinhole)
            origin = np.asarray(f.meta["camera"]["to_world"])[:3, 3]
            dist = np.linalg.norm(s[..., G["position"]] - origin, axis=-1)
            np.testing.assert_allclose(dist[hit], s[..., G["depth"]][..., 0][hit], rtol=1e-3)

            # each hit, projected with its own camera, lands in the pixel that stored it:
            # camera model, pixel convention (y down, centres at +0.5) and box filter agree
            intr = cam.Intrinsics(64, 64, f.meta["camera"]["x_fov"])
            to_world = np.asarray(f.meta["camera"]["to_world"])
            xy, _ = cam.project(s[..., G["position"]].astype(np.float64), to_world, intr)
            ys, xs = np.meshgrid(np.arange(64), np.arange(64), indexing="ij")
            off_x = xy[..., 0] - xs
            off_y = xy[..., 1] - ys
            assert np.all((off_x[hit] > -1e-2) & (off_x[hit] < 1 + 1e-2) & (off_y[hit] > -1e-2) & (off_y[hit] < 1 + 1e-2))
            # and they jitter over the whole pixel
            assert off_x[hit].std() > 0.25 and off_y[hit].std() > 0.25

            if t == 0:
                continue
            prev_to_world = np.asarray(fs[t - 1].meta["camera"]["to_world"])
            xy_prev, _ = cam.project(s[..., G["position"]].astype(np.float64), prev_to_world, intr)
            np.testing.assert_allclose(s[..., G["motion"]][hit], (xy_prev - xy)[hit], atol=2e-3)
            n_hit = hit.sum(0)
            mean_motion = s[..., G["motion"]].sum(0) / np.maximum(n_hit, 1)[..., None]
            np.testing.assert_allclose(f.motion, mean_motion, atol=1e-5)
            assert np.all(f.valid[..., 0][n_hit < 4] == 0)  # a pixel with a miss has no history


def test_motion_vectors_find_the_same_surface(frames):
    """Frame t-1's positions fetched at (x, y) + motion, seen from camera t, land where frame t's
    own positions do, up to the jitter of 4-sample means (~0.2 px); without the motion they
    land pixels away."""
    warped_err, still_err = [], []
    for fs in frames.values():
        for t in (1, 2):
            f, p = fs[t], fs[t - 1]
            valid = f.valid[..., 0] > 0
            intr = cam.Intrinsics(64, 64, f.meta["camera"]["x_fov"])
            to_world = np.asarray(f.meta["camera"]["to_world"])
            own, _ = cam.project(f.position.astype(np.float64), to_world, intr)
            for prev_pos, errs in ((bilinear(p.position, f.motion), warped_err), (p.position, still_err)):
                xy, _ = cam.project(prev_pos.astype(np.float64), to_world, intr)
                errs.append(np.linalg.norm(xy - own, axis=-1)[valid])
    warped_err, still_err = np.concatenate(warped_err), np.concatenate(still_err)
    assert np.median(warped_err) < 0.3 and np.percentile(warped_err, 90) < 0.6
    assert np.median(still_err) > 5 * np.median(warped_err)


def test_warped_reference_reaches_noise_floor(tiny_dataset, frames, mi):
    """Warping reference t-1 onto t with the motion vectors leaves an error (valid pixels) at the
    level of the difference between two independent references of frame t; not warping is far worse."""
    warped, noise, still = [], [], []
    for seq, fs in frames.items():
        scene_dir = os.path.join(tiny_dataset, seq, "scene")
        scene = mi.load_file(os.path.join(scene_dir, "scene.xml"))
        path, _ = cam.load_camera_path(os.path.join(scene_dir, "camera_path.json"))
        params = mi.traverse(scene.sensors()[0])
        for t in (1, 2):
            params["to_world"] = mi.ScalarTransform4f(path.matrices[t].tolist())
            params.update()
            second = np.asarray(mi.render(scene, spp=64, seed=987 + t))
            f, p = fs[t], fs[t - 1]
            valid = f.valid[..., 0] > 0
            ref = tonemap(f.reference)
            warped.append(np.abs(tonemap(bilinear(p.reference, f.motion)) - ref)[valid])
            noise.append(np.abs(tonemap(second) - ref)[valid])
            still.append(np.abs(tonemap(p.reference) - ref)[valid])
    warped, noise, still = (np.concatenate(x).mean() for x in (warped, noise, still))
    assert warped < 1.3 * noise, (warped, noise)
    assert still > 1.6 * warped, (still, warped)


# ----------------------------------------------------------------------------------------------
# Scenes: determinism, export, material table
# ----------------------------------------------------------------------------------------------

def _spec(seed: int) -> procedural.SceneSpec:
    a = tiny_args()
    return procedural.generate(seed, *a.size, a.frames, a.defocus, a.motion_blur, a.camera_speed)


def test_generator_is_deterministic_and_matches_export(tiny_dataset):
    a, b, c = _spec(0), _spec(0), _spec(1)
    assert json.dumps(a.objects, sort_keys=True) == json.dumps(b.objects, sort_keys=True)
    assert a.assets.keys() == b.assets.keys() and a.path == b.path and a.intrinsics == b.intrinsics
    for k, x in a.assets.items():  # meshes are dicts of arrays, bitmaps arrays
        for key in x if isinstance(x, dict) else [None]:
            np.testing.assert_array_equal(x if key is None else x[key], b.assets[k] if key is None else b.assets[k][key])
    assert json.dumps(a.objects, sort_keys=True) != json.dumps(c.objects, sort_keys=True)
    # the exported dict is exactly what the seed generates (JSON round trip)
    desc = procedural.scene_description(a, a.path.to_world(0.0), 4)
    with open(os.path.join(tiny_dataset, SEQS[0], "scene", "scene.json")) as fh:
        assert json.load(fh) == json.loads(json.dumps(desc))
    # scene content does not depend on the effect probabilities
    d = procedural.generate(0, 64, 64, 3, defocus=1.0, motion_blur=1.0, speed=3.0)
    assert json.dumps(d.objects, sort_keys=True) == json.dumps(a.objects, sort_keys=True) and d.defocus


@pytest.mark.parametrize("make", [procedural.blob_mesh, procedural.torus_mesh, procedural.twisted_mesh])
def test_generated_meshes_are_closed_and_face_outward(make):
    for seed in range(3):
        m = make(np.random.default_rng(seed))
        v, f, n = m["vertices"].astype(np.float64), m["faces"], m["normals"]
        assert m["uv"].shape == (len(v), 2) and m["uv"].min() >= 0 and m["uv"].max() <= 1
        _, weld = np.unique(np.round(v, 5), axis=0, return_inverse=True)
        wf = weld.reshape(-1)[f]
        wf = wf[(wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 0] != wf[:, 2])]  # pole slivers
        edges = np.concatenate([wf[:, [0, 1]], wf[:, [1, 2]], wf[:, [2, 0]]])
        directed = {tuple(e) for e in edges}
        assert len(directed) == len(edges), "an edge is used twice in the same direction"
        assert all((b, a) in directed for a, b in directed), "mesh has a hole"
        volume = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
        assert volume > 0
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        big = np.linalg.norm(fn, axis=1) > 1e-9
        assert np.all(np.einsum("ij,ij->i", fn[big], n[f[big, 0]]) > 0), "vertex normal against its face"


def test_exported_scene_rerenders_the_frames(tiny_dataset, frames, mi):
    from mcdenoise.training.render.renderer import to_mitsuba

    scene_dir = os.path.join(tiny_dataset, SEQS[0], "scene")
    f0 = frames[SEQS[0]][0]
    seed = f0.meta["seeds"]["passes"][0]
    from_xml = mi.load_file(os.path.join(scene_dir, "scene.xml"))
    with open(os.path.join(scene_dir, "scene.json")) as fh:
        from_json = mi.load_dict(to_mitsuba(mi, json.load(fh), scene_dir))
    sample0 = f0.samples[0][..., G["radiance"]]
    for scene in (from_xml, from_json):
        img = np.asarray(mi.render(scene, spp=1, seed=seed))
        close = np.isclose(img, sample0, rtol=1e-3, atol=1e-3).all(-1)
        assert close.mean() > 0.995, close.mean()
    ref = np.asarray(mi.render(from_xml, spp=64, seed=5))
    assert abs(tonemap(ref).mean() / tonemap(f0.reference).mean() - 1) < 0.03


def test_material_table_matches_generator(tiny_dataset, frames, mi):
    from mcdenoise.training.render.materials import fresnel_dielectric_f0, material_table
    from mcdenoise.training.render.renderer import to_mitsuba

    for i, seq in enumerate(SEQS):
        spec = _spec(i)
        scene_dir = os.path.join(tiny_dataset, seq, "scene")
        with open(os.path.join(scene_dir, "scene.json")) as fh:
            scene = mi.load_dict(to_mitsuba(mi, json.load(fh), scene_dir))
        lut, ids, names = material_table(mi, scene)
        assert sorted(names) == sorted(spec.materials)
        kinds = set()
        for sid, name in zip(ids, names):
            rough, metallic, transmissive, emissive, specular, *color = lut[sid]
            rec = spec.materials[name]
            kind = rec["kind"]
            kinds.add(kind)
            assert emissive == (kind == "emitter"), name
            assert metallic == (kind in ("conductor", "roughconductor")), name
            assert transmissive == (kind == "dielectric"), name
            assert specular == (kind in ("conductor", "roughconductor", "dielectric")), name
            want_rough = {"diffuse": 1.0, "emitter": 1.0, "plastic": 0.0, "conductor": 0.0, "dielectric": 0.0}
            np.testing.assert_allclose(rough, rec.get("alpha", want_rough.get(kind)), rtol=1e-5, err_msg=name)
            if kind in ("plastic", "roughplastic", "dielectric"):
                np.testing.assert_allclose(color, [fresnel_dielectric_f0(rec["ior"])] * 3, rtol=1e-4, err_msg=name)
            elif metallic:
                assert min(color) > 0.0 and max(color) <= 1.0
            else:
                assert not any(color)
        assert len(kinds) >= 3
        # every sample's material features are one of the table's rows (0 for a miss)
        rows = {tuple(r) for r in np.round(lut, 6)}
        feats = np.concatenate([f.samples[..., G["roughness"].start:G["specular_color"].stop] for f in frames[seq]])
        assert {tuple(r) for r in np.round(feats.reshape(-1, 8), 6)} <= rows


# ----------------------------------------------------------------------------------------------
# Per-sample exactness with a thin lens and motion blur
# ----------------------------------------------------------------------------------------------

def test_each_sample_radiance_matches_its_own_features(mi):
    """A lit floor and two emitters of different colours in front of nothing, seen through a
    thin lens from a moving camera with motion blur: every sample whose position lies on an
    emitter has exactly that emitter's radiance and emissive = 1, every other hit has neither,
    and misses have zero radiance - so guides and radiance come from the same primary ray."""
    from mcdenoise.training.render.renderer import Sequence, SequenceRenderer

    l_sphere, l_rect = np.array([4.0, 2.0, 1.0]), np.array([0.5, 1.5, 3.0])
    scene = mi.load_dict({
        "type": "scene",
        "ball": {"type": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.5,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": l_sphere.tolist()}},
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}},
        "panel": {"type": "rectangle", "to_world": mi.ScalarTransform4f(
                      (cam.look_at((1.2, 0.8, -1.0), (1.2, 0.8, 1.0)) @ np.diag([0.6, 0.6, 1, 1])).tolist()),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": l_rect.tolist()}},
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f(
                      (cam.look_at((0, 0, 0), (0, 1, 0), up=(0, 0, 1)) @ np.diag([2.0, 2.0, 1, 1])).tolist()),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}},
    })
    keys = [cam.look_at((0.3 * t, 1.5, 4.0), (0.0, 0.5, 0.0)) for t in range(2)]
    intr = cam.Intrinsics(32, 32, 50.0, aperture_radius=0.15, focus_distance=4.0)
    seq = Sequence(name="emitters", seed=3, scene=scene, intrinsics=intr, path=cam.KeyFrames(keys), frames=2,
                   defocus=True, motion_blur=True, source="test")
    renderer = SequenceRenderer(mi, seq, spp=8, ref_spp=8, variant=mi.variant())
    f = renderer.render_frame(1)
    s = f.samples
    rad, pos = s[..., G["radiance"]], s[..., G["position"]]
    hit = s[..., G["depth"]][..., 0] > 0
    on_ball = hit & (np.abs(np.linalg.norm(pos - [0.0, 0.6, 0.0], axis=-1) - 0.5) < 1e-3)
    on_panel = (hit & (np.abs(pos[..., 2] + 1.0) < 1e-3) & (np.abs(pos[..., 0] - 1.2) < 0.6 + 1e-3)
                & (np.abs(pos[..., 1] - 0.8) < 0.6 + 1e-3))
    emissive = s[..., G["emissive"]][..., 0] == 1
    np.testing.assert_array_equal(emissive, on_ball | on_panel)
    assert np.all(np.isclose(rad, l_sphere, rtol=1e-5).all(-1) == on_ball)
    assert np.all(np.isclose(rad, l_rect, rtol=1e-5).all(-1) == on_panel)
    assert not rad[~hit].any()
    for mask in (on_ball, on_panel, hit & ~emissive, ~hit):
        assert mask.sum() > 50
    # the classes mix inside pixels (silhouettes blurred by the lens): sample-level, not pixel-level
    assert (on_ball.any(0) & ~on_ball.all(0)).sum() > 10
    # shutter times: one per pass, stratified over [0, 1); the thin lens gives a circle of confusion
    times = np.asarray(f.meta["time"])
    assert np.all((times >= np.arange(8) / 8) & (times < np.arange(1, 9) / 8))
    np.testing.assert_array_equal(s[..., G["time"]][:, 0, 0, 0], times.astype(np.float32))
    assert np.all(s[..., G["coc"]][hit] > 0) and f.meta["camera"]["type"] == "thinlens"
    assert f.valid.mean() > 0.2 and np.abs(f.motion).max() > 0.5


def test_shape_ids_hold_for_meshes_mitsuba_merged(mi):
    """Scene seed 100044 (--seed 1, scene 44) crashed the id check: Mitsuba 3.9's loader merges
    meshes with an equivalent BSDF (there a rectangle and a twisted prism, both plain tungsten)
    into one mesh with an empty id whose bbox() covers only one of its parts.  The same here:
    a conductor panel and cube far apart, beside a diffuse floor."""
    from mcdenoise.training.render.renderer import Sequence, SequenceRenderer, shape_bounds

    metal = {"type": "twosided", "bsdf": {"type": "conductor", "material": "W"}}
    tf = lambda m: mi.ScalarTransform4f(np.asarray(m, np.float64).tolist())
    scene = mi.load_dict({
        "type": "scene",
        "panel": {"type": "rectangle", "bsdf": metal,
                  "to_world": tf(cam.look_at((-1.5, 0.5, 0.0), (-1.5, 0.5, 1.0)) @ np.diag([0.5, 0.5, 1, 1]))},
        "box": {"type": "cube", "bsdf": metal, "to_world": tf(cam.translation((1.5, 0.5, 0.0)) @ np.diag([0.4] * 3 + [1]))},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"},
                  "to_world": tf(cam.look_at((0, 0, 0), (0, 1, 0), up=(0, 0, 1)) @ np.diag([4.0, 4.0, 1, 1]))},
        "light": {"type": "constant"},
    })
    intr = cam.Intrinsics(48, 32, 60.0)
    seq = Sequence(name="merged", seed=5, scene=scene, intrinsics=intr, path=cam.KeyFrames([cam.look_at((0, 1.0, 5.0), (0, 0.4, 0))]),
                   frames=1, defocus=False, motion_blur=False, source="test")
    renderer = SequenceRenderer(mi, seq, spp=1, ref_spp=1, variant=mi.variant())
    for shape, sid in zip(scene.shapes(), renderer.ids):  # bounds hold every vertex
        if shape.is_mesh():
            v = np.asarray(shape.vertex_positions_buffer()).reshape(-1, 3)
            lo, hi = shape_bounds(shape)
            assert np.all(v >= lo) and np.all(v <= hi), shape.id()
    p = renderer.render_pass(seq.path.to_world(0.0), seed=1)
    renderer.check_shape_ids(p["shape"], p["position"])  # raised RuntimeError before the fix
    f = renderer.render_frame(0)  # the check runs inside
    metallic = f.samples[0, ..., G["metallic"]][..., 0] == 1
    x = f.samples[0, ..., G["position"]][..., 0]
    assert (metallic & (x < -1.0)).sum() > 10 and (metallic & (x > 1.0)).sum() > 10  # both metal parts
    if len(scene.shapes()) < 3:  # merged (Mitsuba 3.9): both metal parts are one shape with an empty id
        assert [s.id() for s in scene.shapes()].count("") == 1


def test_coc_matches_the_rendered_blur_disc(mi):
    """A tiny emitter out of focus renders as a disc whose diameter is the coc feature."""
    from mcdenoise.training.render.renderer import Sequence, SequenceRenderer

    scene = mi.load_dict({"type": "scene", "dot": {
        "type": "sphere", "center": [0.0, 0.0, 2.0], "radius": 0.04,
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}}})
    intr = cam.Intrinsics(64, 64, 40.0, aperture_radius=0.2, focus_distance=6.0)
    seq = Sequence(name="dot", seed=4, scene=scene, intrinsics=intr, path=cam.KeyFrames([cam.look_at((0, 0, 0), (0, 0, 1))]),
                   frames=1, defocus=True, motion_blur=False, source="test")
    f = SequenceRenderer(mi, seq, spp=16, ref_spp=4096, variant=mi.variant()).render_frame(0)
    expected = float(cam.coc_pixels(np.array(2.0), intr))
    assert 10 < expected < 14  # 2 A |z - F| / z over the focal plane's width in pixels
    # The image is the dot's pinhole image (3.5 px wide) spread over the coc disc: flat within
    # (coc - 3.5) / 2 of the centre, and its sum over its plateau value is the disc's area.
    lum = f.reference.mean(-1)
    core = lum[np.hypot(*np.meshgrid(np.arange(64) - 31.5, np.arange(64) - 31.5)) < 3.0]
    measured = 2 * np.sqrt(lum.sum() / core.mean() / np.pi)
    assert measured == pytest.approx(expected, rel=0.02), (measured, expected)
    coc = f.samples[..., G["coc"]][..., 0][f.samples[..., G["emissive"]][..., 0] == 1]
    assert len(coc) > 5  # hits lie on the sphere's front, 1.96 <= z <= 2
    assert np.all((coc >= expected * (1 - 1e-4)) & (coc <= float(cam.coc_pixels(np.array(1.96), intr)) * (1 + 1e-4)))


# ----------------------------------------------------------------------------------------------
# User scenes and re-runs
# ----------------------------------------------------------------------------------------------

def test_user_scene_with_camera_path_reproduces_the_procedural_frames(tiny_dataset, frames, tmp_path, mi):
    scene_dir = os.path.join(tiny_dataset, SEQS[0], "scene")
    out = str(tmp_path / "user")
    rc = cli_main(["render", "--out", out, "--scene", os.path.join(scene_dir, "scene.xml"),
                   "--camera-path", os.path.join(scene_dir, "camera_path.json"), "--frames", "2", "--spp", "4",
                   "--ref-spp", "64", "--size", "64x64", "--seed", "0", "--scenes", "1",
                   "--variant", frames[SEQS[0]][0].meta["variant"]])
    assert rc == 0
    with open(os.path.join(out, MANIFEST)) as fh:
        entry = json.load(fh)["sequences"][0]
    assert entry["source"].endswith("scene.xml") and entry["frames"] == 2
    for t in range(2):
        mine = read_frame(os.path.join(out, entry["folder"], frame_name(t)))
        theirs = frames[SEQS[0]][t]
        np.testing.assert_allclose(mine.meta["camera"]["to_world"], theirs.meta["camera"]["to_world"], atol=1e-9)
        same = np.isclose(mine.samples, theirs.samples, rtol=1e-3, atol=1e-3).all(-1)
        assert same.mean() > 0.99, same.mean()


def test_user_scene_gets_a_camera_path_around_its_sensor(tiny_dataset, tmp_path, mi):
    xml = os.path.join(tiny_dataset, SEQS[1], "scene", "scene.xml")
    out = str(tmp_path / "around")
    assert cli_main(["render", "--out", out, "--scene", xml, "--frames", "2", "--spp", "1", "--ref-spp", "2",
                     "--size", "32x24", "--scenes", "1", "--variant", render_variant()]) == 0
    folder = os.path.join(out, "scene_0000000")
    f0, f1 = (read_frame(os.path.join(folder, frame_name(t))) for t in range(2))
    sensor = mi.load_file(xml).sensors()[0]
    base = np.asarray(mi.traverse(sensor)["to_world"].matrix).reshape(4, 4)
    np.testing.assert_allclose(f0.meta["camera"]["to_world"], base, atol=1e-5)
    assert not np.allclose(f1.meta["camera"]["to_world"], base, atol=1e-4)
    assert f0.color.shape == (24, 32, 3) and f1.valid.any()


def test_rerun_keeps_finished_sequences(tiny_dataset, capsys):
    paths = [os.path.join(tiny_dataset, s, frame_name(t)) for s in SEQS for t in range(3)]
    before = [os.stat(p).st_mtime_ns for p in paths]
    with open(os.path.join(tiny_dataset, MANIFEST)) as fh:
        manifest = json.load(fh)
    variant = manifest["sequences"][0]["variant"]
    assert cli_main(["render", "--out", tiny_dataset, *TINY_ARGS, "--variant", variant]) == 0
    assert "keeping 2 finished sequence(s)" in capsys.readouterr().err
    assert [os.stat(p).st_mtime_ns for p in paths] == before
    with open(os.path.join(tiny_dataset, MANIFEST)) as fh:
        assert json.load(fh)["sequences"] == manifest["sequences"]


def test_an_interrupted_sequence_resumes_at_its_first_missing_frame(tiny_dataset, tmp_path, monkeypatch, capsys):
    """A render stopped mid-sequence keeps the frames it wrote and renders only the rest, which
    then equal an uninterrupted render; frames of other settings are never kept."""
    from mcdenoise.training.render import renderer

    with open(os.path.join(tiny_dataset, MANIFEST)) as fh:
        variant = json.load(fh)["sequences"][0]["variant"]
    args = list(TINY_ARGS)
    args[args.index("--scenes") + 1] = "1"
    out = str(tmp_path / "r")
    folder = os.path.join(out, SEQS[0])
    real = renderer.SequenceRenderer.render_frame
    rendered = []

    def stop_at(n):
        def render_frame(self, t, progress=None):
            if t == n:
                raise RuntimeError("killed")
            rendered.append(t)
            return real(self, t, progress)
        return render_frame

    monkeypatch.setattr(renderer.SequenceRenderer, "render_frame", stop_at(2))
    assert cli_main(["render", "--out", out, *args, "--variant", variant]) != 0
    assert "killed" in capsys.readouterr().err
    kept = [os.path.join(folder, frame_name(t)) for t in range(2)]
    mtimes = [os.stat(p).st_mtime_ns for p in kept]
    assert not os.path.exists(os.path.join(folder, frame_name(2)))

    rendered.clear()
    monkeypatch.setattr(renderer.SequenceRenderer, "render_frame", stop_at(99))
    assert cli_main(["render", "--out", out, *args, "--variant", variant]) == 0
    assert rendered == [2]
    assert [os.stat(p).st_mtime_ns for p in kept] == mtimes
    with open(os.path.join(out, MANIFEST)) as fh:
        entry = json.load(fh)["sequences"][0]
    assert entry["resumed_frames"] == 2 and entry["render_seconds"] == pytest.approx(3 * entry["seconds_per_frame"], abs=2e-3)
    assert not os.path.exists(os.path.join(folder, command.PARTIAL))
    for t in range(3):
        a = read_frame(os.path.join(folder, frame_name(t)))
        b = read_frame(os.path.join(tiny_dataset, SEQS[0], frame_name(t)))
        np.testing.assert_array_equal(a.color, b.color)
        np.testing.assert_array_equal(a.reference, b.reference)

    # Other settings: the old frames go before the first new one is rendered.
    monkeypatch.setattr(renderer.SequenceRenderer, "render_frame", stop_at(0))
    other = list(args)
    other[other.index("--ref-spp") + 1] = "32"
    assert cli_main(["render", "--out", out, *other, "--variant", variant]) != 0
    capsys.readouterr()
    assert not any(os.path.exists(os.path.join(folder, frame_name(t))) for t in range(3))


# ----------------------------------------------------------------------------------------------
# Camera maths
# ----------------------------------------------------------------------------------------------

def test_camera_conventions(mi):
    m = cam.look_at((1.0, 2.0, 3.0), (0.0, 0.5, -1.0))
    theirs = np.asarray(mi.ScalarTransform4f().look_at(origin=[1, 2, 3], target=[0, 0.5, -1], up=[0, 1, 0]).matrix)
    np.testing.assert_allclose(m, theirs, atol=1e-6)
    keys = [cam.look_at((t, 1.0, 5.0), (0.0, 0.0, -t)) for t in range(3)]
    path = cam.KeyFrames(keys)
    for t in range(3):
        np.testing.assert_allclose(path.to_world(float(t)), keys[t], atol=1e-12)
    mid = path.to_world(0.5)[:3, :3]
    np.testing.assert_allclose(mid.T @ mid, np.eye(3), atol=1e-12)
    # past the last key the last step repeats
    np.testing.assert_allclose(path.to_world(3.0)[:3, 3], 2 * keys[2][:3, 3] - keys[1][:3, 3], atol=1e-9)
    # a point on the optical axis projects to the image centre; +x camera is screen left
    intr = cam.Intrinsics(40, 20, 60.0)
    xy, z = cam.project(np.array([m[:3, 3] + 2 * m[:3, 2], m[:3, 3] + 2 * m[:3, 2] + 0.1 * m[:3, 0]]), m, intr)
    np.testing.assert_allclose(xy[0], [20, 10], atol=1e-9)
    assert xy[1, 0] < 20 and z[0] == pytest.approx(2.0)


def test_reference_check_compares_two_references_of_the_same_frame(tmp_path, capsys):
    """--check-references rebuilds each scene from its seed and renders frame 0's reference
    again with the independent seed stream: the two agree far better than two different
    scenes' references, and the result lands in reference_check.json (what the bench quotes)."""
    from mcdenoise.training.metrics import psnr

    out = tmp_path / "o"
    rc = cli_main(["render", "--out", str(out), "--scenes", "2", "--frames", "1", "--size", "32x32", "--spp", "1",
                   "--ref-spp", "32", "--seed", "9", "--variant", render_variant(), "--check-references"])
    assert rc == 0
    check = json.loads((out / command.REFERENCE_CHECK).read_text())
    names = sorted(check["sequences"])
    assert len(names) == 2 and check["ref_spp"] == 32 and check["min_db"] == min(check["sequences"].values())
    a, b = (read_frame(out / n / frame_name(0), samples=False).reference for n in names)
    assert check["min_db"] > psnr(a, b) + 8.0, (check, psnr(a, b))
    assert "agree to" in capsys.readouterr().out


@pytest.mark.parametrize("name", __import__("mcdenoise.training.testsets").training.testsets.HELD_OUT_SCENES)
def test_the_hand_made_held_out_scenes_render(name, tmp_path):
    """samples/heldout/: Mitsuba loads each scene with its sensor, the renderer's camera drift
    keeps the camera inside (every pixel hits something within the room or, through the
    window, the sky outside it), and its light reaches the image (mostly indirect)."""
    from mcdenoise.training.testsets import HELD_OUT

    ts = HELD_OUT[name]
    scene = ts.flags[ts.flags.index("--scene") + 1]
    out = tmp_path / "o"
    rc = cli_main(["render", "--out", str(out), "--scene", scene, "--scenes", "1", "--frames", "3", "--size", "24x24",
                   "--spp", "2", "--ref-spp", "8", "--seed", str(ts.seed), "--camera-speed", "2", "--variant", render_variant()])
    assert rc == 0
    for t in (0, 2):
        fr = read_frame(next(out.glob("*/")) / frame_name(t))
        assert (fr.depth > 0).all() and fr.depth.max() < 15.0, (t, fr.depth.min(), fr.depth.max())
        assert fr.reference.mean() > 0.02 and np.isfinite(fr.reference).all()


def test_enclosed_rooms_keep_the_scene_and_close_it(tmp_path):
    """--enclosed: the same objects and camera path as the open scene, now inside walls all
    round with a ceiling (no ray leaves: every pixel hits), the environment gone, light through
    a window and from a lamp behind an occluder; probability 0 changes nothing."""
    def objs(spec, prefix=""):
        return json.dumps({k: v for k, v in spec.objects.items() if k.startswith(prefix)}, sort_keys=True)

    a = procedural.generate(21, 64, 64, 4)
    same = procedural.generate(21, 64, 64, 4, enclosed=0.0)
    assert objs(same) == objs(a) and same.path == a.path and same.setting == a.setting
    b = procedural.generate(21, 64, 64, 4, enclosed=1.0)
    assert b.setting == "enclosed" and "environment" not in b.objects and b.path == a.path
    assert objs(a, "obj") == objs(b, "obj")
    for part in ("room_ceiling", "room_lamp", "room_occluder", "room_window_light", "room_bar00"):
        assert part in b.objects, part
    out = tmp_path / "o"
    rc = cli_main(["render", "--out", str(out), "--scenes", "1", "--frames", "2", "--size", "24x24", "--spp", "2",
                   "--ref-spp", "8", "--seed", "21", "--enclosed", "on", "--variant", render_variant()])
    assert rc == 0
    fr = read_frame(next(out.glob("scene_*")) / frame_name(1))
    assert (fr.depth > 0).all() and fr.reference.mean() > 0.01
    assert json.loads((out / MANIFEST).read_text())["settings"]["enclosed_probability"] == 1.0


def test_cuda_variant_without_a_gpu_is_one_line(tmp_path, capsys):
    """--variant cuda_ad_rgb on a machine without an NVIDIA GPU: one line saying so."""
    import shutil

    if shutil.which("nvidia-smi"):
        pytest.skip("a GPU host: the variant may work here")
    rc = cli_main(["render", "--out", str(tmp_path / "o"), "--scenes", "1", "--frames", "1", "--size", "16x16",
                   "--spp", "1", "--ref-spp", "1", "--variant", "cuda_ad_rgb"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2 and "cuda_ad_rgb" in err and err.startswith("mcdenoise render: error:"), err
