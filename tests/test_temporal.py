"""Reprojection with the consistency test: exact shifts, disocclusion, borders, torch parity."""
import numpy as np
import pytest
import torch

from mcdenoise.runtime.temporal import THREADED_BAND_ROWS as BAND, accumulate, reproject


def _scene(h=6, w=8, shift=1.0):
    """A fronto-parallel plane whose world x equals the pixel x of frame t-1; the camera moved so
    pixel x of frame t shows what pixel x + shift showed in t-1."""
    xs = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))
    pos_prev = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 10)])[None]
    pos_cur = pos_prev.copy()
    pos_cur[:, 0] += shift
    nrm = np.zeros((1, 3, h, w), np.float32)
    nrm[:, 2] = -1
    depth = np.full((1, 1, h, w), 10.0, np.float32)
    motion = np.zeros((1, 2, h, w), np.float32)
    motion[:, 0] = shift
    prev = {"position": pos_prev, "normal": nrm, "depth": depth}
    cur = {"position": pos_cur, "normal": nrm.copy(), "depth": depth.copy()}
    return motion, cur, prev


def test_integer_shift_is_exact_and_border_has_no_history():
    motion, cur, prev = _scene()
    state = np.random.default_rng(0).random((1, 3, 6, 8), dtype=np.float32)
    (warped,), hist = reproject([state], motion, cur, prev)
    np.testing.assert_array_equal(hist[0, 0, :, :-1], 1)
    np.testing.assert_array_equal(hist[0, 0, :, -1], 0)  # came from off-screen
    np.testing.assert_allclose(warped[..., :-1], state[..., 1:], rtol=1e-6)
    assert np.all(warped[..., -1] == 0)


def test_half_pixel_shift_is_bilinear():
    motion, cur, prev = _scene(shift=0.5)
    state = np.random.default_rng(1).random((1, 1, 6, 8), dtype=np.float32)
    (warped,), hist = reproject([state], motion, cur, prev)
    np.testing.assert_allclose(warped[..., :-1], 0.5 * (state[..., :-1] + state[..., 1:]), rtol=1e-5)


def test_disocclusion_rejected_by_position_and_normal():
    motion, cur, prev = _scene()
    cur["position"][:, 2, 2, 3] = 5.0  # a different surface now in front
    cur["normal"][0, :, 4, 4] = np.array([1.0, 0, 0])  # a surface facing elsewhere
    _, hist = reproject([np.ones((1, 1, 6, 8), np.float32)], motion, cur, prev)
    assert hist[0, 0, 2, 3] == 0 and hist[0, 0, 4, 4] == 0 and hist[0, 0, 1, 1] == 1


def test_miss_has_no_history_and_depth_fallback():
    motion, cur, prev = _scene()
    cur["depth"][:, :, 0, 0] = 0
    _, hist = reproject([np.ones((1, 1, 6, 8), np.float32)], motion, cur, prev)
    assert hist[0, 0, 0, 0] == 0
    no_pos_cur = {k: v for k, v in cur.items() if k != "position"}
    no_pos_prev = {k: v for k, v in prev.items() if k != "position"}
    no_pos_cur["depth"][:, :, 3, 3] = 20.0  # depth jumps: rejected without positions too
    _, hist = reproject([np.ones((1, 1, 6, 8), np.float32)], motion, no_pos_cur, no_pos_prev)
    assert hist[0, 0, 3, 3] == 0 and hist[0, 0, 3, 2] == 1


def test_torch_matches_numpy_and_is_differentiable():
    motion, cur, prev = _scene(shift=0.3)
    state = np.random.default_rng(2).random((1, 2, 6, 8), dtype=np.float32)
    (wn,), hn = reproject([state], motion, cur, prev)
    ts = torch.tensor(state, requires_grad=True)
    (wt,), ht = reproject([ts], torch.tensor(motion), {k: torch.tensor(v) for k, v in cur.items()},
                          {k: torch.tensor(v) for k, v in prev.items()})
    np.testing.assert_allclose(wt.detach().numpy(), wn, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(ht.numpy(), hn)
    wt.sum().backward()
    assert ts.grad is not None and float(ts.grad.abs().sum()) > 0


def test_numpy_bands_match_torch_whole_frame():
    """numpy processes rows in bands (runtime.temporal.BAND_ROWS); band seams must not show."""
    from mcdenoise.runtime import temporal

    h, w = 2 * temporal.BAND_ROWS + 7, 9
    rng = np.random.default_rng(3)
    motion = (rng.random((1, 2, h, w), dtype=np.float32) - 0.5) * 6
    depth = np.full((1, 1, h, w), 10.0, np.float32)
    nrm = np.zeros((1, 3, h, w), np.float32)
    nrm[:, 2] = -1
    pos = rng.random((1, 3, h, w), dtype=np.float32) * 0.1
    cur = {"depth": depth, "position": pos, "normal": nrm}
    prev = {"depth": depth.copy(), "position": pos + 0.05, "normal": nrm.copy()}
    state = rng.random((1, 4, h, w), dtype=np.float32)
    (wn,), hn = reproject([state], motion, cur, prev)
    (wt,), ht = reproject([torch.tensor(state)], torch.tensor(motion), {k: torch.tensor(v) for k, v in cur.items()},
                          {k: torch.tensor(v) for k, v in prev.items()})
    assert 0.2 < hn.mean() < 1.0
    np.testing.assert_array_equal(ht.numpy(), hn)
    np.testing.assert_allclose(wt.numpy(), wn, rtol=1e-5, atol=1e-6)


def _random_guides(rng, n, h, w, keys):
    depth = rng.uniform(5, 6, (n, 1, h, w)).astype(np.float32)
    depth[:, :, :2, :3] = 0                                      # misses
    nrm = rng.normal(size=(n, 3, h, w)).astype(np.float32) * 0.3
    nrm[:, 2] -= 1
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    g = {"depth": depth, "position": rng.random((n, 3, h, w), dtype=np.float32) * 0.4, "normal": nrm}
    return {k: g[k] for k in keys}


def _torch_reproject(states, motion, cur, prev):
    t = lambda d: {k: torch.tensor(v) for k, v in d.items()}  # noqa: E731
    return reproject([torch.tensor(s) for s in states], torch.tensor(motion), t(cur), t(prev))


@pytest.mark.parametrize("keys", [("depth",), ("depth", "normal"), ("depth", "position"),
                                  ("depth", "position", "normal")])
def test_numpy_fast_path_matches_torch_for_every_guide_set_and_batch(keys):
    """The driver's numpy path (planar gathers, bands, zero-weight taps skipped) against the
    torch path on random guides, two states, a batch of 2, motion pointing off-screen too."""
    from mcdenoise.runtime import temporal

    rng = np.random.default_rng(len(keys))
    n, h, w = 2, temporal.BAND_ROWS + 5, 11
    motion = ((rng.random((n, 2, h, w)) - 0.5) * 5).astype(np.float32)
    cur, prev = _random_guides(rng, n, h, w, keys), _random_guides(rng, n, h, w, keys)
    if "position" in keys:     # half the pixels consistent with their source
        prev["position"] = cur["position"] + rng.normal(0, 0.2, cur["position"].shape).astype(np.float32)
    else:
        prev["depth"] = np.where(rng.random(prev["depth"].shape) < 0.5, cur["depth"], prev["depth"] * 1.5)
    states = [rng.random((n, 3, h, w), dtype=np.float32), rng.random((n, 1, h, w), dtype=np.float32)]
    wn, hn = reproject(states, motion, cur, prev)
    wt, ht = _torch_reproject(states, motion, cur, prev)
    assert 0.1 < hn.mean() < 0.95
    np.testing.assert_array_equal(ht.numpy(), hn)
    for a, b in zip(wn, wt):
        assert a.shape == b.shape
        np.testing.assert_allclose(b.numpy(), a, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("threads", [2, 3])
@pytest.mark.parametrize("h", [5, 2 * BAND + 1, 3 * BAND + 17])
def test_threads_split_rows_without_changing_the_result(threads, h):
    """numpy with worker threads (each an equal share of the rows, in bands) equals one
    thread to the bit, for heights below one band, one row past two bands and uneven shares;
    batch of 2, integer motion on part of the frame (skipped taps in some bands only)."""
    rng = np.random.default_rng(h)
    n, w = 2, 7
    keys = ("depth", "position", "normal")
    motion = ((rng.random((n, 2, h, w)) - 0.5) * 5).astype(np.float32)
    motion[:, :, : h // 2] = 1.0
    cur, prev = _random_guides(rng, n, h, w, keys), _random_guides(rng, n, h, w, keys)
    prev["position"] = cur["position"] + rng.normal(0, 0.1, cur["position"].shape).astype(np.float32)
    states = [rng.random((n, 3, h, w), dtype=np.float32), rng.random((n, 1, h, w), dtype=np.float32)]
    w1, h1 = reproject(states, motion, cur, prev)
    wt, ht = reproject(states, motion, cur, prev, threads=threads)
    assert 0.1 < h1.mean() < 0.95
    np.testing.assert_array_equal(ht, h1)
    for a, b in zip(w1, wt):
        np.testing.assert_array_equal(b, a)


@pytest.mark.parametrize("threads", [1, 2])
def test_blend_is_accumulate_of_the_warped_state_to_the_bit(threads):
    """reproject(blend=...) returns accumulate(current, warped, history, alpha): numpy (blended
    band by band) to the bit, torch to float rounding; unblended states are untouched."""
    rng = np.random.default_rng(11)
    n, h, w = 2, 2 * BAND + 3, 9
    keys = ("depth", "position", "normal")
    motion = ((rng.random((n, 2, h, w)) - 0.5) * 5).astype(np.float32)
    cur, prev = _random_guides(rng, n, h, w, keys), _random_guides(rng, n, h, w, keys)
    prev["position"] = cur["position"] + rng.normal(0, 0.1, cur["position"].shape).astype(np.float32)
    states = [rng.random((n, 3, h, w), dtype=np.float32), rng.random((n, 1, h, w), dtype=np.float32)]
    current = rng.random((n, 3, h, w), dtype=np.float32) * 4
    (wa, wb), hist = reproject(states, motion, cur, prev, threads=threads, blend=[(current, 0.2), None])
    (pa, pb), hp = reproject(states, motion, cur, prev)
    assert 0.1 < hist.mean() < 0.95
    np.testing.assert_array_equal(hist, hp)
    np.testing.assert_array_equal(wb, pb)
    np.testing.assert_array_equal(wa, accumulate(current, pa, hp, 0.2))
    none = np.broadcast_to(hp == 0, wa.shape)
    np.testing.assert_array_equal(wa[none], current[none])      # no history: the frame itself
    t = lambda d: {k: torch.tensor(v) for k, v in d.items()}  # noqa: E731
    (ta, tb), th = reproject([torch.tensor(s) for s in states], torch.tensor(motion), t(cur), t(prev),
                             blend=[(torch.tensor(current), 0.2), None])
    np.testing.assert_allclose(ta.numpy(), wa, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="blend: 1 entries for 2 states"):
        reproject(states, motion, cur, prev, blend=[None])


@pytest.mark.parametrize("shift", [0.0, 2.0, -1.0])
def test_integer_motion_skips_taps_without_changing_the_result(shift):
    """With integer motion three bilinear taps have weight 0 and the numpy path skips them."""
    rng = np.random.default_rng(7)
    h, w = 9, 13
    motion = np.full((1, 2, h, w), shift, np.float32)
    keys = ("depth", "position", "normal")
    cur = _random_guides(rng, 1, h, w, keys)
    prev = {k: v.copy() for k, v in cur.items()}
    state = rng.random((1, 3, h, w), dtype=np.float32)
    (wn,), hn = reproject([state], motion, cur, prev)
    (wt,), ht = _torch_reproject([state], motion, cur, prev)
    np.testing.assert_array_equal(ht.numpy(), hn)
    np.testing.assert_allclose(wt.numpy(), wn, rtol=1e-6, atol=1e-7)
    if shift == 0.0:   # static camera: every hit keeps its own state exactly
        hit = cur["depth"] > 0
        np.testing.assert_array_equal(hn, hit.astype(np.float32))
        np.testing.assert_array_equal(wn * hit, state * hit)


def test_huge_and_nan_motion_is_off_screen_not_a_hang():
    """Motion vectors far off-screen, at float32's limits, infinite or NaN: those pixels get no
    history (their source is off-screen); numpy and torch agree; nothing hangs or warns."""
    import warnings

    h, w = 20, 24
    motion = np.zeros((1, 2, h, w), np.float32)
    motion[0, 0, 3, 4] = 1e30
    motion[0, 1, 5, 5] = -3e38
    motion[0, 0, 7, 7] = np.inf
    motion[0, 1, 8, 8] = np.nan
    g = {"depth": np.ones((1, 1, h, w), np.float32)}
    prev = {k: v.copy() for k, v in g.items()}
    state = np.ones((1, 3, h, w), np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (wn,), hn = reproject([state], motion, g, prev)
    for y, x in ((3, 4), (5, 5), (7, 7), (8, 8)):
        assert hn[0, 0, y, x] == 0 and (wn[0, :, y, x] == 0).all()
    assert hn.sum() == h * w - 4
    (wt,), ht = _torch_reproject([state], motion, g, prev)
    np.testing.assert_array_equal(ht.numpy(), hn)
    np.testing.assert_array_equal(wt.numpy(), wn)


# ----------------------------------------------------------------------------------------------
# The protocol: one definition of a history for the driver and the trainer
# ----------------------------------------------------------------------------------------------

def _spec_names():
    from mcdenoise.training.specs import list_specs

    return list_specs()


@pytest.mark.parametrize("name", _spec_names())
def test_protocol_runs_the_same_on_numpy_and_torch(name):
    """start -> update -> follow over two frames: the feeds the model would get and the history
    kept are the same for numpy arrays (the driver) and torch tensors (the trainer)."""
    from mcdenoise.training.specs import load_spec

    proto = load_spec(name).protocol
    rng = np.random.default_rng(3)
    motion, cur, prev = _scene(h=7, w=9, shift=0.4)
    frames = [{layer: rng.random((1, 3 if layer != "depth" else 1, 7, 9), dtype=np.float32)
               for layer in ("color", "albedo", "normal", "depth")} for _ in range(2)]
    outputs = {out: rng.random((1, ch, 7, 9), dtype=np.float32) for _, _, out, ch in proto.state}
    got = {}
    for lib, conv in (("numpy", lambda a: a.copy()), ("torch", torch.from_numpy)):
        wrap = lambda d: {k: conv(v) for k, v in d.items()}  # noqa: E731
        f0, f1 = wrap(frames[0]), wrap(frames[1])
        acc = proto.start(f0, f0["color"])
        assert set(f0) == set(frames[0]) | set(proto.inputs)
        for inp in proto.inputs:     # zero state and mask; a state's blend weight is its alpha
            weight = {w[0]: w[1] for w in proto.weights}.get(inp, 0.0)
            assert np.allclose(np.asarray(f0[inp]), weight), inp
        kept = proto.update(acc, wrap(outputs))
        acc = proto.follow(f1, kept, conv(motion), wrap(cur), wrap(prev))
        kept = proto.update(acc, wrap(outputs))
        got[lib] = {"feeds": {k: np.asarray(v) for k, v in f1.items()}, "kept": {k: np.asarray(v) for k, v in kept.items()}}
    for part in ("feeds", "kept"):
        assert got["numpy"][part].keys() == got["torch"][part].keys()
        for k in got["numpy"][part]:
            np.testing.assert_allclose(got["numpy"][part][k], got["torch"][part][k], rtol=1e-6, atol=1e-6, err_msg=k)
    for layer, inp, _, _ in proto.accumulate:   # each accumulated layer fed is the accumulation, not the frame's own
        assert not np.allclose(got["numpy"]["feeds"][inp], frames[1][layer]), inp
    for layer in set(frames[1]) - {a[0] for a in proto.accumulate}:   # and nothing else is blended
        np.testing.assert_array_equal(got["numpy"]["feeds"][layer], frames[1][layer], err_msg=layer)
    assert set(got["numpy"]["kept"]) == {s[0] for s in proto.state} | {proto.accum_key(a[1]) for a in proto.accumulate}


def test_shipped_files_and_their_specs_declare_the_same_protocol():
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.methods import shipped_models
    from mcdenoise.training.specs import parse_spec

    for path in shipped_models():
        den = Denoiser.load(path, log=lambda m: None)
        spec = parse_spec(den.contract.spec_toml)
        assert den.protocol == spec.protocol, path
        # temporal exactly when the spec keeps a state or accumulates (NDLE is per frame)
        assert den.protocol.temporal == bool(spec.state or spec.accumulate), path
    assert any(Denoiser.load(p, log=lambda m: None).protocol.temporal for p in shipped_models())


def test_accumulation_weight_follows_the_frames_spp():
    """history_spp = k: a frame of n samples per pixel gets weight n / (n + k); a frame of
    unknown spp (0 or None) and an entry without k get the fixed alpha; per batch item for
    numpy and torch alike."""
    from mcdenoise.runtime.temporal import Protocol

    entry = ("color", "color", 0.2, 1.0)
    assert Protocol.alpha(entry, 1) == 0.5 and Protocol.alpha(entry, 3) == 0.75
    assert Protocol.alpha(entry, np.int64(4)) == 0.8
    assert Protocol.alpha(entry, 0) == 0.2 and Protocol.alpha(entry, None) == 0.2
    assert Protocol.alpha(("color", "color", 0.2, 0.0), 8) == 0.2
    for lib in (np.array, torch.tensor):
        w = Protocol.alpha(entry, lib([1, 3, 0]))
        assert tuple(w.shape) == (3, 1, 1, 1)
        np.testing.assert_allclose(np.asarray(w, dtype=np.float64).reshape(-1), [0.5, 0.75, 0.2], rtol=1e-6)


def test_a_batch_blends_each_item_with_its_own_spp():
    """The trainer's batches mix spp: follow(spp=(N,)) blends every item with its own weight,
    as the driver blends a frame of that spp alone."""
    from mcdenoise.runtime.temporal import Protocol

    proto = Protocol((), (("color", "color", 0.2, 2.0),), "")
    motion, cur, prev = _scene(h=6, w=8, shift=0.5)
    two = lambda a: torch.from_numpy(np.concatenate([a, a]))  # noqa: E731
    rng = np.random.default_rng(0)
    current = torch.from_numpy(rng.random((2, 3, 6, 8), dtype=np.float32))
    state = torch.from_numpy(rng.random((2, 3, 6, 8), dtype=np.float32))
    feeds = {"color": current}
    proto.follow(feeds, {proto.accum_key("color"): state}, two(motion), {k: two(v) for k, v in cur.items()},
                 {k: two(v) for k, v in prev.items()}, spp=torch.tensor([1, 6]))
    for i, n in enumerate((1, 6)):
        alone = {"color": current[i:i + 1].numpy()}
        proto.follow(alone, {proto.accum_key("color"): state[i:i + 1].numpy()}, motion, cur, prev, spp=n)
        np.testing.assert_allclose(feeds["color"][i:i + 1].numpy(), alone["color"], rtol=1e-6, atol=1e-6)
    assert not np.allclose(feeds["color"][0].numpy(), feeds["color"][1].numpy())


def test_a_method_fed_the_albedo_history_sees_the_drivers_accumulation():
    """training.methods.AlbedoHistory (oidn-high-aa): a static camera, an albedo that changes
    each frame; the wrapped method sees the frame's albedo first, then the driver's blend
    alpha * new + (1 - alpha) * kept, alpha by wskpn-6e-aa's rule for the frame's spp by default;
    a camera cut, a frame without motion, a new size and reset() restart it; a NaN never enters
    the history."""
    from mcdenoise.runtime.frames import Frame
    from mcdenoise.training.harness import synthetic_frame
    from mcdenoise.training.methods import AlbedoHistory
    from mcdenoise.training.specs import load_spec

    class Spy:
        name = "spy"

        def __init__(self):
            self.seen, self.resets = [], 0

        def __call__(self, fr):
            self.seen.append(fr.albedo.copy())
            return fr.color

        def reset(self):
            self.resets += 1

    def frame(scale, **kw):
        f = synthetic_frame(16, 12, 0)
        f["motion"][:] = 0       # a static camera: every pixel keeps its history
        f["albedo"] = f["albedo"] * scale
        f.update(kw)
        return Frame(**f)

    spy = Spy()
    m = AlbedoHistory(spy, alpha=0.25, history_spp=0)
    assert m.name == "spy-aa"
    a0 = frame(1.0).albedo
    m(frame(1.0))
    m(frame(0.5))
    np.testing.assert_array_equal(spy.seen[0], a0)
    np.testing.assert_allclose(spy.seen[1], a0 * (0.25 * 0.5 + 0.75), rtol=1e-6)
    bad = frame(0.5)
    bad.albedo[3, 4] = np.nan
    m(bad)
    assert np.isfinite(spy.seen[2]).all() and np.isfinite(m._albedo).all()
    for restart in (dict(meta={"cut": True}), dict(motion=None)):
        m(frame(0.5, **restart))
        np.testing.assert_array_equal(spy.seen[-1], a0 * 0.5)
    small = synthetic_frame(8, 6, 0)
    m(Frame(**small))
    np.testing.assert_array_equal(spy.seen[-1], small["albedo"])
    m.reset()
    m(frame(0.5))
    np.testing.assert_array_equal(spy.seen[-1], a0 * 0.5)
    assert spy.resets == 2       # at construction and at reset()
    with pytest.raises(ValueError, match="alpha"):
        AlbedoHistory(spy, alpha=0)
    entry = next(a for a in load_spec("wskpn-6e-aa").accumulate if a.layer == "albedo")
    spec_rule = AlbedoHistory(spy)
    assert (spec_rule.alpha, spec_rule.history_spp) == (entry.alpha, entry.history_spp) and entry.history_spp > 0
    for spp, weight in ((None, entry.alpha), (8, 8 / (8 + entry.history_spp))):
        spec_rule.reset()
        meta = {} if spp is None else {"spp": spp}
        spec_rule(frame(1.0, meta=meta))
        spec_rule(frame(0.5, meta=meta))
        np.testing.assert_allclose(spy.seen[-1], a0 * (weight * 0.5 + 1 - weight), rtol=1e-6)
