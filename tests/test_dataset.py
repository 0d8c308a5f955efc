"""Dataset on the tiny rendered set: seed splits, spp subsets, and augmentation that keeps
normals and motion vectors consistent with the image under all 8 symmetries."""
import os

import numpy as np
import pytest

from mcdenoise.runtime.frames import SAMPLE_FEATURES, SAMPLE_GROUPS, FrameError, read_frame
from mcdenoise.runtime.writers import write_frame
from mcdenoise.runtime.inputs import camera_axes
from mcdenoise.runtime.temporal import reproject
from mcdenoise.training.dataset import (SequenceDataset, cache_dtype_for, collate, dihedral, discover, split,
                                        to_half)

LAYERS = ("color", "albedo", "normal", "depth")


def test_splits_are_by_scene_seed_and_deterministic(tiny_dataset):
    seqs = discover(tiny_dataset)
    assert len(seqs) == 2
    train, val = split(seqs, "train"), split(seqs, "val")
    assert len(train) == 1 and len(val) == 1
    assert {s.seed for s in train}.isdisjoint({s.seed for s in val})
    assert [s.seed for s in split(seqs, "val")] == [s.seed for s in val]
    with pytest.raises(ValueError, match="split must be"):
        split(seqs, "test")


def test_item_shapes_and_spp_subsets(tiny_dataset):
    ds = SequenceDataset(tiny_dataset, "all", LAYERS, crop=32, spp_choices=(1, 2, 4), window=2)
    seen = set()
    for i in range(12):
        item = ds[i]
        seen.add(int(item["spp"]))
        assert item["color"].shape == (2, 3, 32, 32)
        assert item["depth"].shape == (2, 1, 32, 32) and item["motion"].shape == (2, 2, 32, 32)
        assert item["reference"].shape == (2, 3, 32, 32)
    assert seen <= {1, 2, 4} and len(seen) >= 2
    # Deterministic: the same (seed, epoch, index) gives the same item.
    np.testing.assert_array_equal(ds[3]["color"], ds[3]["color"])
    batch = collate([ds[0], ds[1]])
    assert tuple(batch["color"].shape) == (2, 2, 3, 32, 32)


@pytest.mark.parametrize("groups", [(), ("radiance", "normal")])
def test_reading_processes_fill_the_cache_with_what_lazy_reads_give(tiny_dataset, groups):
    lazy = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), crop=32, window=2, sample_groups=groups)
    warm = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), crop=32, window=2, sample_groups=groups)
    frames = [f for s in warm.seqs for f in s.frames]
    assert warm.warm(processes=2) == len(frames) and sorted(warm._cache) == sorted(frames)
    for f in frames:
        a, b = lazy._frame(f), warm._cache[f]
        assert a.samples.shape == b.samples.shape and (a.samples.shape[-1] < len(SAMPLE_FEATURES)) == (not groups)
        np.testing.assert_array_equal(a.samples, b.samples)
        np.testing.assert_array_equal(a.reference, b.reference)
    for i in range(4):
        for k, v in lazy[i].items():
            np.testing.assert_array_equal(v, warm[i][k], err_msg=k)


@pytest.mark.parametrize("groups", [(), ("radiance", "normal")])
def test_validation_caches_only_the_centre_crop_and_gives_the_same_items(tiny_dataset, groups):
    """centre_only keeps a quarter of a frame at half its side (a per-sample model's validation
    set ran out of memory with whole frames) and its items, warmed by processes or read lazily,
    are byte for byte those of the whole-frame cache, at every spp."""
    kw = dict(crop=32, window=2, augment=False, sample_groups=groups)
    whole = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), **kw)
    centre = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), centre_only=True, **kw)
    warm = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), centre_only=True, **kw)
    warm.warm(processes=2)
    for i in range(len(whole)):
        for spp in (None, 1, 4):
            a, b, c = whole[i, spp], centre[i, spp], warm[i, spp]
            assert a["color"].shape[-2:] == (32, 32)
            for k in a:
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
                np.testing.assert_array_equal(a[k], c[k], err_msg=k)
    f = whole.seqs[0].frames[0]
    assert whole._cache[f].samples.shape[1:3] == (64, 64) and centre._cache[f].samples.shape[1:3] == (32, 32)
    assert centre._cache[f].reference.shape[:2] == (32, 32) and centre._cache[f].motion.shape[:2] == (32, 32)
    with pytest.raises(ValueError, match="augment=False"):
        SequenceDataset(tiny_dataset, "all", LAYERS, crop=32, centre_only=True)


@pytest.mark.parametrize("groups", [(), ("radiance", "normal")])
def test_a_float16_cache_halves_the_samples_and_rounds_items_only(tiny_dataset, groups):
    """cache_dtype float16 holds the per-sample array in half the bytes (cache_bytes says so
    before anything is read) and gives float32 items within float16 rounding of the exact ones,
    training items (random crops and sample subsets) included."""
    for augment in (False, True):
        kw = dict(crop=32, window=2, augment=augment, sample_groups=groups)
        exact = SequenceDataset(tiny_dataset, "all", LAYERS, **kw)
        half = SequenceDataset(tiny_dataset, "all", LAYERS, cache_dtype="float16", **kw)
        assert half.cache_bytes() < 0.75 * exact.cache_bytes() and half.cache_bytes() == exact.cache_bytes("float16")
        for i in range(3):
            a, b = exact[i], half[i]
            assert a.keys() == b.keys()
            for k in a:
                assert b[k].dtype == a[k].dtype, k
                if a[k].dtype == np.float32:
                    # 5e-3: an averaged normal is re-normalised, which scales float16's 5e-4
                    # up where the samples' normals disagree (a short mean vector)
                    np.testing.assert_allclose(b[k], a[k], rtol=2e-3, atol=5e-3 if "normal" in k else 1e-3, err_msg=k)
        f = half.seqs[0].frames[0]
        assert half._cache[f].samples.dtype == np.float16 and exact._cache[f].samples.dtype == np.float32
        assert half._cache[f].samples.nbytes * 2 == exact._cache[f].samples.nbytes
    with pytest.raises(ValueError, match="cache_dtype"):
        SequenceDataset(tiny_dataset, "all", LAYERS, cache_dtype="float64")


@pytest.mark.parametrize("groups", [(), ("radiance", "normal")])
def test_a_disk_cache_gives_the_same_items_and_spares_a_later_run_the_reading(tiny_dataset, tmp_path, monkeypatch,
                                                                              groups):
    """cache_dir: items (training crops with fireflies, validation centre crops, float32 and
    float16) equal the in-memory cache's byte for byte, warmed by processes or read lazily;
    the arrays are read-only memory maps (an item that wrote into a cached frame would fail);
    a second data set on the same folder decodes no EXR; a re-rendered frame gets a new entry."""
    import mcdenoise.training.dataset as dataset

    cache = tmp_path / "cache"
    for augment, dtype in ((True, "float32"), (False, "float16")):
        kw = dict(crop=32, window=2, augment=augment, sample_groups=groups, cache_dtype=dtype,
                  fireflies=0.01 if augment else 0.0, centre_only=not augment)
        mem = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), **kw)
        disk = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), cache_dir=cache, **kw)
        lazy = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), cache_dir=cache, **kw)
        disk.warm(processes=2)
        f = disk.seqs[0].frames[0]
        assert isinstance(disk._cache[f].samples, np.memmap) and not disk._cache[f].samples.flags.writeable
        for i in range(4):
            a, b, c = mem[i], disk[i], lazy[i]
            for k in a:
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
                np.testing.assert_array_equal(a[k], c[k], err_msg=k)
    entries = sorted(os.listdir(cache))
    assert entries and not any(".tmp-" in e for e in entries)

    def no_reading(*a, **k):
        raise AssertionError("an EXR was decoded although the disk cache holds the frame")

    monkeypatch.setattr(dataset, "read_frame", no_reading)
    again = SequenceDataset(tiny_dataset, "all", LAYERS + ("emissive",), crop=32, window=2, sample_groups=groups,
                            fireflies=0.01, cache_dir=cache)
    again.warm(processes=1)
    assert again[0]["color"].shape == (2, 3, 32, 32)
    monkeypatch.undo()
    frame = again.seqs[0].frames[0]
    key = dataset.disk_cache_key(frame, again._columns if not again.samples else None, None, "float32")
    st = os.stat(frame)
    os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    try:
        assert dataset.disk_cache_key(frame, again._columns if not again.samples else None, None, "float32") != key
    finally:
        os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns))


@pytest.mark.parametrize("damage", ["truncated", "missing", "meta"])
def test_a_damaged_disk_cache_entry_is_decoded_again_with_a_line_saying_so(tiny_dataset, tmp_path, capsys, damage):
    """An entry that cannot be read back whole is removed, decoded again from the EXR and
    rewritten (one stderr line names it): the frame equals a fresh read, never a frame with a
    layer missing; an entry still unreadable after that is an OSError naming the folder."""
    import mcdenoise.training.dataset as dataset
    from mcdenoise.training.testsets import sequences

    frame = sequences(tiny_dataset)[0][0]
    cache = str(tmp_path / "cache")
    want = dataset._read_for_cache(frame, None, None, "float32")
    folder = dataset._write_disk_cache(frame, None, None, "float32", cache)
    if damage == "truncated":
        p = os.path.join(folder, "samples.npy")
        os.truncate(p, os.path.getsize(p) // 2)
    elif damage == "missing":
        os.remove(os.path.join(folder, "samples.npy"))
    else:
        with open(os.path.join(folder, "meta.json"), "w") as f:
            f.write('{"meta": ')
    got = dataset.disk_cached_frame(frame, None, None, "float32", cache)
    assert "is damaged" in capsys.readouterr().err
    for name in dataset._DISK_FIELDS:
        a, b = getattr(want, name, None), getattr(got, name, None)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=name)
    assert sorted(os.listdir(cache)) == [os.path.basename(folder)]

    real = np.load

    def broken(path, *a, **k):
        if str(path).endswith("samples.npy"):
            raise ValueError("mmap length is greater than file size")
        return real(path, *a, **k)

    import unittest.mock
    with unittest.mock.patch.object(dataset.np, "load", broken), pytest.raises(OSError, match="cannot be read back"):
        dataset.disk_cached_frame(frame, None, None, "float32", cache)


def test_to_half_clips_finite_values_and_keeps_nan_and_inf():
    a = np.array([1.0, 1e5, -1e6, np.inf, -np.inf, np.nan, 0.1], np.float32)
    h = to_half(a)
    assert h.dtype == np.float16
    np.testing.assert_array_equal(h[:6], np.array([1.0, 65504, -65504, np.inf, -np.inf, np.nan], np.float16))
    assert abs(float(h[6]) - 0.1) < 1e-4


def test_the_automatic_cache_precision_fits_the_memory_or_says_what_to_do():
    gb = 2**30
    assert cache_dtype_for(10 * gb, 5 * gb, 20 * gb) == "float32"
    assert cache_dtype_for(20 * gb, 10 * gb, 20 * gb) == "float16"
    assert cache_dtype_for(20 * gb, 10 * gb, None) == "float32"     # unknown memory: as before
    with pytest.raises(MemoryError, match="--max-sequences"):
        cache_dtype_for(40 * gb, 20 * gb, 20 * gb)


def test_one_spp_colour_is_one_of_the_samples(tiny_dataset):
    ds = SequenceDataset(tiny_dataset, "all", LAYERS, crop=64, spp_choices=(1,), window=1, augment=False)
    item = ds.make_item(0, 0, 0, 0, 64, 1, 0)
    fr = read_frame(ds.seqs[0].frames[0])
    np.testing.assert_allclose(item["color"][0].transpose(1, 2, 0), fr.samples[0, ..., 0:3], rtol=1e-6)


def test_firefly_augmentation_adds_outlier_samples_and_leaves_the_rest(tiny_dataset):
    """With ``fireflies`` a training item's colour gets a few outliers far above the crop's
    reference mean (in one sample, so the n-sample mean shows value / n), the reference and
    every other pixel as without the option; validation items and fireflies=0 are unchanged."""
    kw = dict(crop=48, spp_choices=(1, 2, 4), window=3)
    plain = SequenceDataset(tiny_dataset, "all", LAYERS, **kw)
    flies = SequenceDataset(tiny_dataset, "all", LAYERS, fireflies=0.01, **kw)
    per_sample = SequenceDataset(tiny_dataset, "all", (), fireflies=0.01, sample_groups=("radiance",), **kw)
    changed = 0
    for i in range(6):
        a, b = plain[i], flies[i]
        np.testing.assert_array_equal(a["reference"], b["reference"])
        diff = np.abs(b["color"] - a["color"]).max(axis=1)            # (T, c, c)
        hit = diff > 0
        changed += int(hit.sum())
        n = int(a["spp"])
        for t in range(3):
            if hit[t].any():
                # the outlier sample's share of the pixel mean: at least 50x the reference mean
                # over n, less the sample it replaced (well under 10x that mean here)
                assert diff[t][hit[t]].min() >= 40 / n * a["reference"][t].mean()
        np.testing.assert_array_equal(a["albedo"], b["albedo"])
        s = per_sample[i]["samples"]                                   # (T, n, 3, c, c)
        assert s.shape[:2] == (3, int(per_sample[i]["spp"])) and s.max() >= 50 * per_sample[i]["reference"].mean()
    # 6 items x 3 frames x 48² pixels x 0.01 ≈ 415 outliers expected
    assert 200 < changed < 800
    val = SequenceDataset(tiny_dataset, "all", LAYERS, fireflies=0.01, augment=False, **kw)
    ref = SequenceDataset(tiny_dataset, "all", LAYERS, augment=False, **kw)
    np.testing.assert_array_equal(val[0]["color"], ref[0]["color"])
    with pytest.raises(ValueError, match=r"fireflies: a mean count per pixel in \[0, 1\)"):
        SequenceDataset(tiny_dataset, "all", LAYERS, fireflies=2.0, **kw)


def test_the_emissive_layer_is_the_drawn_samples_share_of_lights(tiny_dataset, tmp_path):
    # the tiny set's scenes have no light in view: a copy of one sequence gets some, its
    # per-sample flags set in a corner, one sample in two at the corner's edge
    seq = discover(tiny_dataset)[0]
    out = tmp_path / "data" / os.path.basename(seq.folder)
    out.mkdir(parents=True)
    for path in seq.frames:
        fr = read_frame(path)
        fr.samples[:, :20, :20, SAMPLE_GROUPS["emissive"]] = 1.0
        fr.samples[::2, 20:24, :20, SAMPLE_GROUPS["emissive"]] = 1.0
        fr.emissive = None     # as files from before the layer: read back from the samples
        write_frame(out / os.path.basename(path), fr)
    ds = SequenceDataset(tmp_path / "data", "all", LAYERS + ("emissive",), crop=64, spp_choices=(2,), window=1,
                         augment=False)
    fr = read_frame(ds.seqs[0].frames[0])
    assert fr.emissive[:20, :20].min() == 1 and fr.emissive[20:24, :20].max() == 0.5 and fr.emissive[30:].max() == 0
    item = ds.make_item(0, 0, 0, 0, 64, 2, 0)
    flag = fr.samples[:2, ..., SAMPLE_GROUPS["emissive"]].mean(axis=0)
    assert item["emissive"].shape == (1, 1, 64, 64)
    np.testing.assert_array_equal(item["emissive"][0, 0], flag[..., 0])


def test_dihedral_vector_convention():
    # A vector field pointing right (+x) everywhere; after a horizontal flip it must point left,
    # after a transpose it must point down (+y).
    v = np.zeros((2, 3, 4), np.float32)
    v[0] = 1.0
    assert np.all(dihedral(v, 2, (0, 1))[0] == -1)
    t = dihedral(v, 1, (0, 1))
    assert t.shape == (2, 4, 3) and np.all(t[1] == 1) and np.all(t[0] == 0)


@pytest.mark.parametrize("k", range(8))
def test_augmented_motion_vectors_still_warp_the_geometry(tiny_dataset, k):
    """Under each of the 8 symmetries, frame t-1's first-hit positions warped with frame t's
    (transformed) motion vectors land on frame t's positions. Positions are geometry, not Monte
    Carlo estimates, so the bound holds for any renderer noise (llvm_ad_rgb and scalar_rgb
    draw different samples): only the pixel jitter of the 4 samples and bilinear taps remain,
    where a motion vector left untransformed lands on another surface point altogether.
    (Radiance warps are checked against independent references in test_render.py.)"""
    ds = SequenceDataset(tiny_dataset, "all", LAYERS, crop=64, window=2, augment=False)
    for seq_i in range(len(ds.seqs)):
        it = ds.make_item(seq_i, 1, 0, 0, 64, 4, k)
        cur, prev = {"depth": it["depth"][1][None]}, {"depth": it["depth"][0][None]}
        (warped,), hist = reproject([it["position"][0][None]], it["motion"][1][None], cur, prev)
        valid = it["valid"][1, 0] > 0
        kept = valid & (hist[0, 0] > 0)
        assert valid.mean() > 0.3 and kept.sum() > 0.5 * valid.sum(), (k, valid.mean(), kept.sum() / valid.sum())
        pos = it["position"][1]
        warped_err = np.linalg.norm(warped[0] - pos, axis=0)[kept].mean()
        unwarped_err = np.linalg.norm(it["position"][0] - pos, axis=0)[kept].mean()
        # Measured on the tiny set: 0.10-0.12 with the right transform, 0.43-1.5 with swapped
        # or negated vectors.
        assert warped_err < 0.25 * unwarped_err, (k, seq_i, warped_err, unwarped_err)


@pytest.mark.parametrize("k", range(8))
def test_augmented_normals_agree_with_depth_gradients(tiny_dataset, k):
    """Screen-space normal x (y) is positive where camera depth grows to the right (down):
    check the correlation keeps its sign under every symmetry."""
    ds = SequenceDataset(tiny_dataset, "all", LAYERS, crop=64, window=1, augment=False)
    cx, cy = [], []
    for seq_i in range(len(ds.seqs)):
        meta = read_frame(ds.seqs[seq_i].frames[0], samples=False).meta
        axes = camera_axes(meta)
        origin = np.asarray(meta["camera"]["to_world"])[:3, 3]
        it = ds.make_item(seq_i, 0, 0, 0, 64, 4, k)
        pos = it["position"][0]
        z = np.einsum("c,chw->hw", axes[2], pos - origin[:, None, None])
        hit = it["depth"][0, 0] > 0
        n = it["normal"][0]
        dzdx = z[:, 2:] - z[:, :-2]
        dzdy = z[2:, :] - z[:-2, :]
        okx = hit[:, 2:] & hit[:, :-2] & hit[:, 1:-1] & (np.abs(dzdx) < 0.2 * z[:, 1:-1])
        oky = hit[2:, :] & hit[:-2, :] & hit[1:-1, :] & (np.abs(dzdy) < 0.2 * z[1:-1, :])
        cx.append((n[0][:, 1:-1][okx], dzdx[okx]))
        cy.append((n[1][1:-1, :][oky], dzdy[oky]))
    for pairs in (cx, cy):
        a = np.concatenate([p[0] for p in pairs])
        b = np.concatenate([p[1] for p in pairs])
        assert np.corrcoef(a, b)[0, 1] > 0.2, (k, np.corrcoef(a, b)[0, 1])


def test_shards_side_by_side_merge_and_a_repeated_seed_is_an_error(tiny_dataset, tmp_path):
    """<root>/<shard>/<scene>: shards rendered apart are one data set; the same scene seed in
    two shards (rendered with the same --seed) is refused."""
    import shutil

    seqs = discover(tiny_dataset)
    for i, s in enumerate(seqs):
        shutil.copytree(s.folder, tmp_path / "merged" / f"shard{i}" / os.path.basename(s.folder))
    assert [s.seed for s in discover(tmp_path / "merged")] == [s.seed for s in seqs]
    shutil.copytree(seqs[0].folder, tmp_path / "merged" / "shard9" / os.path.basename(seqs[0].folder))
    with pytest.raises(FrameError, match="same scene seed"):
        discover(tmp_path / "merged")


def test_a_sequence_still_rendering_is_left_out(tiny_dataset, tmp_path):
    """A folder with the renderer's unfinished-sequence marker (being rendered, or interrupted
    and to be resumed) is not part of the data set; once the marker goes, it is."""
    import shutil

    from mcdenoise.training.dataset import PARTIAL

    seqs = discover(tiny_dataset)
    root = tmp_path / "data"
    for s in seqs:
        shutil.copytree(s.folder, root / os.path.basename(s.folder))
    marker = root / os.path.basename(seqs[-1].folder) / PARTIAL
    marker.write_text("{}")
    assert [s.seed for s in discover(root)] == [s.seed for s in seqs[:-1]]
    marker.unlink()
    assert [s.seed for s in discover(root)] == [s.seed for s in seqs]


def test_per_sample_items_share_one_spp_per_batch_and_rotate_normals_with_the_image(tiny_dataset):
    """A per-sample model's items: its ``samples`` input (S, F, c, c) per frame with the S the
    batch drew; under every image symmetry the samples' screen normals stay consistent with
    the item's pixel normal (their renormalised mean)."""
    from mcdenoise.runtime.inputs import sample_channels

    groups = ("diffuse_radiance", "specular_radiance", "normal", "depth")
    ds = SequenceDataset(tiny_dataset, "all", ("color",), crop=32, spp_choices=(1, 2, 4), window=2,
                         sample_groups=groups)
    drawn = {ds.batch_spp(pos) for pos in range(30)}
    assert drawn == {1, 2, 4}
    n = ds.batch_spp(0)
    batch = collate([ds[i, n] for i in range(3)])
    assert batch["samples"].shape == (3, 2, n, 10, 32, 32)
    nx = sample_channels(groups, "screen_xy")[0]
    for k in range(8):
        item = ds.make_item(0, 0, 8, 8, 32, 4, k)
        mean = item["samples"][:, :, nx:nx + 3].mean(axis=1)          # (T, 3, c, c)
        length = np.linalg.norm(mean, axis=1, keepdims=True)
        hit = length[:, 0] > 0.5
        got = (mean / np.maximum(length, 1e-6)).transpose(0, 2, 3, 1)[hit]
        want = item["normal"].transpose(0, 2, 3, 1)[hit]
        np.testing.assert_allclose(got, want, atol=1e-4, err_msg=f"symmetry {k}")
    # the radiance channels sum to the colour: diffuse + specular, averaged over samples
    item = ds.make_item(0, 0, 0, 0, 32, 4, 3)
    np.testing.assert_allclose(item["samples"][:, :, 0:3].mean(1) + item["samples"][:, :, 3:6].mean(1),
                               item["color"], rtol=1e-5, atol=1e-6)
