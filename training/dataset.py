"""Training/evaluation dataset over sequences written by ``mcdenoise render``.

An item is a window of T consecutive frames of one sequence, cropped at one location, with a
random subset of n samples per pixel (n drawn from ``spp_choices``, at most what was stored)
and one of the 8 image symmetries (flips, 90° rotations) applied consistently to every
channel: screen-space normals and motion vectors have their x/y components negated and
swapped with the image, world-space guides (position, world normal) are left alone because
they are only compared with each other.  Splits are by scene seed, never by frame.

Item tensors, float32, leading time axis T:
  every input layer the spec names, e.g. color (T, 3, c, c) linear HDR, albedo (T, 3, c, c),
  normal (T, 3, c, c) screen space, depth (T, 1, c, c);
  reference (T, 3, c, c); motion (T, 2, c, c) pixels; position (T, 3, c, c) and
  normal_world (T, 3, c, c) world-space guides for :func:`runtime.temporal.reproject`;
  samples (T, n, F, c, c): for a per-sample model (``sample_groups``) its ``samples`` input,
  :func:`runtime.inputs.sample_inputs` of the crop (sanitised, normals in screen space, the
  groups' channels only); with ``samples=True`` instead the raw stored features.
Every item of one batch must have the same n to stack: :meth:`SequenceDataset.batch_spp`
draws it per batch and ``dataset[index, n]`` makes an item with it.

Firefly augmentation (``fireflies`` > 0, training items only): each frame of an item gets a
Poisson number (mean ``fireflies`` per pixel of the crop) of outlier samples whose radiance is
a log-uniform :data:`FIREFLY_RANGE` multiple of the crop's reference mean, in every channel,
with the reference left as it is: the outliers ``mcdenoise stress`` injects (ANF Fig. 3,
:func:`add_fireflies` is the one definition of both), taught as noise to remove.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from mcdenoise.runtime.frames import (MANIFEST, PIXEL_LAYERS, SAMPLE_FEATURES, SAMPLE_GROUPS, Frame, FrameError, frame_paths,
                            pixel_means, read_frame, read_meta)
from mcdenoise.runtime.inputs import SanitizeReport, frame_inputs, sample_channels, sample_inputs

#: Firefly augmentation: the outlier's radiance over the crop's reference mean, drawn
#: log-uniformly (the stress test's 500x lies inside).
FIREFLY_RANGE = (50.0, 1000.0)

#: Channels holding screen-space (x right, y down) vector components, per item key.
SCREEN_VECTORS = {"normal": (0, 1), "motion": (0, 1),
                  "samples": (SAMPLE_GROUPS["motion"].start, SAMPLE_GROUPS["motion"].start + 1)}


@dataclass(frozen=True)
class SequenceInfo:
    folder: str
    seed: int
    frames: tuple[str, ...]
    spp: int


#: The marker ``mcdenoise render`` keeps in a sequence folder while the sequence is unfinished
#: (training.render.command: being rendered, or interrupted and to be resumed).
PARTIAL = ".partial.json"


def discover(root: str | os.PathLike) -> list[SequenceInfo]:
    """All sequences under ``root``, sorted by scene seed: folders holding frame_*.exr, in
    ``root`` or one level down, so that shards rendered apart (each ``mcdenoise render --out
    <root>/<shard> --seed <its own>``, on one machine or several) merge by sitting side by side.
    A scene seed found twice is an error (two shards rendered with the same --seed).  A
    sequence still being rendered (its folder holds :data:`PARTIAL`) is left out, so training
    can read the finished part of a data set while the rest renders."""
    root = os.fspath(root)
    if not os.path.isdir(root):
        raise FrameError(f"{root}: dataset folder does not exist")

    def folders(d):
        return [os.path.join(d, n) for n in sorted(os.listdir(d)) if os.path.isdir(os.path.join(d, n))]

    candidates = folders(root)
    if not any(frame_paths(f) for f in candidates):
        candidates = [g for f in candidates for g in folders(f)]     # <root>/<shard>/<scene>
    seqs, seen = [], {}
    for folder in candidates:
        paths = frame_paths(folder)
        if not paths or os.path.exists(os.path.join(folder, PARTIAL)):
            continue
        meta = read_meta(paths[0])
        seed = meta.get("scene_seed", meta.get("seed"))
        if seed is None:
            raise FrameError(f"{paths[0]}: metadata has no scene_seed")
        if int(seed) in seen:
            raise FrameError(f"{folder} and {seen[int(seed)]} hold the same scene seed {seed} "
                             "(shards rendered with the same --seed?)")
        seen[int(seed)] = folder
        seqs.append(SequenceInfo(folder, int(seed), tuple(paths), int(meta.get("spp", 0))))
    if not seqs:
        raise FrameError(f"{root}: no sequences (expected <root>/<scene>/frame_0000.exr or "
                         f"<root>/<shard>/<scene>/frame_0000.exr, see {MANIFEST})")
    return sorted(seqs, key=lambda s: s.seed)


def _seed_hash(seed: int) -> int:
    return int.from_bytes(hashlib.sha256(f"scene-{seed}".encode()).digest()[:4], "little")


def split(seqs: Sequence[SequenceInfo], part: str, val_fraction: float = 0.2) -> list[SequenceInfo]:
    """Deterministic split by scene seed: a seed is in "val" when its hash falls in the lowest
    ``val_fraction`` (at least one sequence when there are two or more), else "train".
    ``part="all"`` returns everything (for a separately rendered test set)."""
    if part == "all":
        return list(seqs)
    if part not in ("train", "val"):
        raise ValueError(f"split must be train, val or all, got {part!r}")
    ranked = sorted(seqs, key=lambda s: _seed_hash(s.seed))
    n_val = int(round(val_fraction * len(ranked)))
    if len(ranked) >= 2:
        n_val = min(max(n_val, 1), len(ranked) - 1)
    else:
        n_val = 0
    val = {s.seed for s in ranked[:n_val]}
    return [s for s in seqs if (s.seed in val) == (part == "val")]


def add_fireflies(samples: np.ndarray, rng: np.random.Generator, value: float, count: int) -> np.ndarray:
    """In place: ``count`` distinct pixels of ``samples`` (S, H, W, F), the frame format's
    per-sample features, each get radiance ``value`` (linear HDR, every channel) in one sample
    drawn uniformly. Returns the (count, 3) (sample, y, x) changed."""
    n, h, w = samples.shape[:3]
    flat = rng.choice(h * w, size=min(count, h * w), replace=False)
    s, y, x = rng.integers(0, n, size=len(flat)), flat // w, flat % w
    samples[s, y, x, SAMPLE_GROUPS["radiance"]] = value
    return np.stack([s, y, x], 1)


def dihedral(arr: np.ndarray, k: int, vector: tuple[int, int] | None = None) -> np.ndarray:
    """Apply image symmetry k in 0..7 to a (..., C, H, W) array: bit 0 transposes (swap x, y),
    bit 1 flips x, bit 2 flips y.  ``vector`` names the channels (cx, cy) holding screen
    (x, y) vector components; they are swapped/negated to match, so a vector still points
    at the same image content after the transform."""
    out = arr
    if k & 1:
        out = np.swapaxes(out, -1, -2).copy()
        if vector:
            cx, cy = vector
            out[..., [cx, cy], :, :] = out[..., [cy, cx], :, :]
    if k & 2:
        out = out[..., ::-1].copy()
        if vector:
            out[..., vector[0], :, :] *= -1
    if k & 4:
        out = out[..., ::-1, :].copy()
        if vector:
            out[..., vector[1], :, :] *= -1
    return np.ascontiguousarray(out)


class SequenceDataset:
    """Random windows of a split of a rendered dataset (see module docstring).

    Args:
      root: folder written by ``mcdenoise render``.
      part: "train", "val" or "all".
      layers: model input layers (e.g. ("color", "albedo", "normal", "depth")).
      crop: crop side in pixels (clamped to the frame size).
      spp_choices: candidate samples per pixel; each item draws one (<= stored spp).
      window: frames per item (T).
      length: items per epoch (default: one per frame of the split).
      augment: random crops and symmetries; False gives deterministic centre crops, all
        stored samples, identity symmetry (validation).
      samples: also return the per-sample array.
      seed: base seed; item i of epoch e is a pure function of (seed, e, i).
      max_sequences: keep only the first N sequences of the split (sorted by scene seed).
      sample_groups: a per-sample model's groups (names, in order): items carry its
        ``samples`` input.
      fireflies: mean outlier samples per pixel per frame (module docstring; 0: none); only
        with ``augment``.
      centre_only: (only without ``augment``) cache just each frame's centre crop, the only
        part its items read: a quarter of a 256x256 frame at crop 128. A per-sample model's
        validation set cached whole frames (52 MB each at 8 spp) and, beside its training set,
        ran a 12 GB process out of memory. :meth:`make_item`'s coordinates are then in the crop.
      cache_dtype: "float32" (exact) or "float16": the cached per-sample array in half precision,
        half the memory (a pixel model's 14 columns x 8 spp: 29 MB a 256x256 frame in float32).
        Values are rounded to 11 significant bits and finite ones beyond +-65504 clipped (NaN and
        Inf kept); items are float32 either way. See :func:`cache_dtype_for`.
      cache_dir: a folder where each frame's cached arrays are kept as .npy files and read back
        memory-mapped (:func:`disk_cached_frame`), instead of held in this process: the page
        cache then holds what fits in memory and the rest is read from disk, and a later run on
        the same frames (the next sitting, the other arm of an A/B) starts without decoding a
        single EXR. The items are the same as without it (tested).
    """

    def __init__(self, root, part="train", layers=("color", "albedo", "normal", "depth"),
                 crop=128, spp_choices=(1, 2, 4, 8), window=2, length=None, augment=True,
                 samples=False, seed=0, val_fraction=0.2, max_sequences=None, sample_groups=(), fireflies=0.0,
                 centre_only=False, cache_dtype="float32", cache_dir=None):
        if cache_dtype not in CACHE_DTYPES:
            raise ValueError(f"cache_dtype must be one of {CACHE_DTYPES}, got {cache_dtype!r}")
        if centre_only and augment:
            raise ValueError("centre_only caches centre crops: it needs augment=False")
        self.seqs = split(discover(root), part, val_fraction)
        if max_sequences is not None:
            if max_sequences < 1:
                raise ValueError(f"max_sequences must be >= 1, got {max_sequences}")
            self.seqs = self.seqs[:max_sequences]       # by scene seed: smaller sets nest in larger
        if not self.seqs:
            raise FrameError(f"{root}: split {part!r} is empty ({len(discover(root))} sequences)")
        self.layers = tuple(layers)
        self.crop = int(crop)
        self.spp_choices = tuple(int(s) for s in spp_choices)
        self.window = int(window)
        for s in self.seqs:
            if len(s.frames) < self.window:
                raise FrameError(f"{s.folder}: {len(s.frames)} frames, window needs {self.window}")
        self.starts = [(i, t) for i, s in enumerate(self.seqs) for t in range(len(s.frames) - self.window + 1)]
        self.length = int(length) if length else len(self.starts)
        self.augment = augment
        self.sample_groups = tuple(sample_groups)
        self.samples = samples or bool(self.sample_groups)
        groups = ("radiance", "albedo", "normal", "depth", "position") + (("emissive",) if "emissive" in self.layers else ())
        #: the per-sample features a pixel model's cache keeps, by index into SAMPLE_FEATURES
        self._columns = [i for g in groups for i in range(SAMPLE_GROUPS[g].start, SAMPLE_GROUPS[g].stop)]
        #: those columns as runs (first, stop in the frame's layout; first in the cache's): slice
        #: copies, where an index array on the last axis was most of an item's time
        self._runs = []
        for j, col in enumerate(self._columns):
            if self._runs and self._runs[-1][1] == col:
                self._runs[-1][1] += 1
            else:
                self._runs.append([col, col + 1, j])
        if not 0.0 <= fireflies < 1.0:
            raise ValueError(f"fireflies: a mean count per pixel in [0, 1), got {fireflies}")
        self.fireflies = float(fireflies)
        #: the side of the centre crop the cache keeps (None: whole frames)
        self._keep = self.crop if centre_only else None
        self.cache_dtype = cache_dtype
        self.cache_dir = None if cache_dir is None else os.fspath(cache_dir)
        self.seed = int(seed)
        self.epoch = 0
        self._cache: dict[str, Frame] = {}

    def __len__(self) -> int:
        return self.length

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def _frame(self, path: str) -> Frame:
        fr = self._cache.get(path)
        if fr is None:
            args = (path, None if self.samples else self._columns, self._keep, self.cache_dtype)
            fr = self._cache[path] = (disk_cached_frame(*args, self.cache_dir) if self.cache_dir
                                      else _read_for_cache(*args))
        return fr

    def cache_bytes(self, cache_dtype: str | None = None) -> int:
        """Bytes the cache holds once every frame of the split is read (with ``cache_dtype``,
        default the set's own), estimated from the first frame's (read, not cached) and the
        frame count: sequences of one data set share size and spp."""
        dtype = cache_dtype or self.cache_dtype
        fr = _read_for_cache(self.seqs[0].frames[0], None if self.samples else self._columns, self._keep, dtype)
        per = fr.samples.nbytes + sum(a.nbytes for layer in PIXEL_LAYERS
                                      if (a := getattr(fr, layer.name, None)) is not None)
        return per * sum(len(s.frames) for s in self.seqs)

    def warm(self, processes: int = 1) -> int:
        """Read every frame of the split into the cache, with that many reading processes;
        returns how many frames there are. Before batch-building processes fork (``train
        --loader-workers``), so they share the frames (copy-on-write) instead of each reading and
        holding its own copy. Decoding is most of a read (0.3-1 s a frame of 256x256 x 8 spp
        here: docs/results/scale/batch_time.py), hence the processes."""
        todo = [f for s in self.seqs for f in s.frames if f not in self._cache]
        columns = None if self.samples else self._columns
        if processes > 1 and len(todo) > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # fork, as the loader's workers: the readers need nothing the parent has not imported
            ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
            with ProcessPoolExecutor(min(processes, len(todo)), mp_context=ctx) as pool:
                n = len(todo)
                if self.cache_dir:
                    # the readers write the files; this process maps them (a returned array
                    # would be pickled into this process's memory, which the disk cache avoids)
                    list(pool.map(_write_disk_cache, todo, [columns] * n, [self._keep] * n,
                                  [self.cache_dtype] * n, [self.cache_dir] * n))
                else:
                    for path, fr in zip(todo, pool.map(_read_for_cache, todo, [columns] * n,
                                                       [self._keep] * n, [self.cache_dtype] * n)):
                        self._cache[path] = fr
        for path in todo:
            self._frame(path)
        return sum(len(s.frames) for s in self.seqs)

    def batch_spp(self, pos: int) -> int:
        """Samples per pixel of every item of step ``pos`` of the current epoch (per-sample
        models stack S): drawn from ``spp_choices`` (those the data holds), a pure function of
        (seed, epoch, pos)."""
        stored = min(s.spp for s in self.seqs)
        choices = [n for n in self.spp_choices if n <= stored] or [stored]
        return int(np.random.default_rng([self.seed, self.epoch, int(pos), 1]).choice(choices))

    def __getitem__(self, index) -> dict:
        index, spp = index if isinstance(index, tuple) else (index, None)
        rng = np.random.default_rng([self.seed, self.epoch, int(index)])
        if self.augment:
            seq_i, t0 = self.starts[rng.integers(len(self.starts))]
        else:
            seq_i, t0 = self.starts[index % len(self.starts)]
        first = self._frame(self.seqs[seq_i].frames[t0])
        h, w = first.size
        c = min(self.crop, h, w)
        if self.augment:
            y0, x0 = int(rng.integers(h - c + 1)), int(rng.integers(w - c + 1))
            choices = [n for n in self.spp_choices if n <= first.spp] or [first.spp]
            n = int(rng.choice(choices))
            k = int(rng.integers(8))
            n = n if spp is None else min(spp, first.spp)
        else:
            y0, x0 = (h - c) // 2, (w - c) // 2
            n = min(max(self.spp_choices) if spp is None else spp, first.spp)
            k = 0
        return self.make_item(seq_i, t0, y0, x0, c, n, k, rng if self.augment else None)

    def make_item(self, seq_i: int, t0: int, y0: int, x0: int, c: int, n: int, k: int,
                  rng: np.random.Generator | None = None) -> dict:
        """The item for sequence ``seq_i`` frames t0..t0+T-1, crop (y0, x0, c), ``n`` samples
        per pixel (a random subset drawn from ``rng``, else the first n) and symmetry ``k``."""
        seq = self.seqs[seq_i]
        h, w = self._frame(seq.frames[t0]).size
        out: dict[str, list] = {}
        # its own stream (not drawn from rng), so all else in the item is as without fireflies
        flies = np.random.default_rng([self.seed, self.epoch, seq_i, t0, y0, x0, n, k, 3]) \
            if self.fireflies and rng is not None else None
        for t in range(t0, t0 + self.window):
            fr = self._frame(seq.frames[t])
            if fr.size != (h, w):
                raise FrameError(f"{fr.path}: size {fr.size} differs from {seq.frames[t0]} {(h, w)}")
            idx = np.sort(rng.choice(fr.spp, size=n, replace=False)) if rng is not None else np.arange(n)
            sub = fr.samples[idx, y0:y0 + c, x0:x0 + c].astype(np.float32, copy=False)     # a copy (index array)
            if not self.samples:    # the cached columns back in the frame format's layout
                full = np.zeros(sub.shape[:-1] + (len(SAMPLE_FEATURES),), np.float32)
                for first, stop, at in self._runs:
                    full[..., first:stop] = sub[..., at:at + stop - first]
                sub = full
            win = (slice(y0, y0 + c), slice(x0, x0 + c))
            if flies is not None and (count := int(flies.poisson(self.fireflies * c * c))):
                value = float(np.mean(fr.reference[win], dtype=np.float64)) * float(np.exp(flies.uniform(*np.log(FIREFLY_RANGE))))
                add_fireflies(sub, flies, value, count)     # sub is this item's copy
            px = pixel_means(sub)
            crop = Frame(**px, motion=fr.motion[win],
                         valid=None if fr.valid is None else fr.valid[win],
                         reference=fr.reference[win], meta=fr.meta, path=fr.path)
            report = SanitizeReport()
            # colour always: the unroll's auto-exposure reads it, also for a model of samples only
            names = ("color",) + self.layers + ("reference", "motion", "position", "normal", "depth")
            if crop.valid is not None:
                names += ("valid",)
            arrays = frame_inputs(crop, tuple(dict.fromkeys(names)), report)
            arrays["normal_world"] = np.ascontiguousarray(px["normal"].transpose(2, 0, 1)[None])
            if self.sample_groups:
                arrays["samples"] = sample_inputs(replace(crop, samples=sub), self.sample_groups, report)
            elif self.samples:
                arrays["samples"] = np.ascontiguousarray(sub.transpose(0, 3, 1, 2))[None]
            for key, arr in arrays.items():
                vec = tuple(sample_channels(self.sample_groups, "screen_xy")) or None \
                    if key == "samples" and self.sample_groups else SCREEN_VECTORS.get(key)
                out.setdefault(key, []).append(dihedral(arr[0], k, vec))
        item = {key: np.stack(v) for key, v in out.items()}
        item["spp"] = np.int64(n)
        return item


def _read_for_cache(path: str, columns: list[int] | None, keep: int | None = None,
                    cache_dtype: str = "float32") -> Frame:
    """Frame ``path`` as a data set caches it: whole for a per-sample model (``columns``
    None), else only the per-sample ``columns`` a pixel model's items are made from; with
    ``keep``, only the centre crop of that side (clamped to the frame) a validation item reads;
    the per-sample array in ``cache_dtype`` (see :class:`SequenceDataset`)."""
    fr = read_frame(path, require=("color", "reference", "motion", "samples"))
    if keep is not None:
        h, w = fr.size
        c = min(keep, h, w)
        y0, x0 = (h - c) // 2, (w - c) // 2     # as SequenceDataset.__getitem__ without augment
        for layer in PIXEL_LAYERS:
            if (arr := getattr(fr, layer.name)) is not None:
                setattr(fr, layer.name, np.ascontiguousarray(arr[y0:y0 + c, x0:x0 + c]))
        fr.samples = np.ascontiguousarray(fr.samples[:, y0:y0 + c, x0:x0 + c])
    if columns is not None:
        # A pixel model's items are made from the features pixel_means() reads (14 or 15 of 25)
        # and the motion, valid and reference layers: the cache keeps just those (under a third
        # of the frame: wskpn-6e's 448 frames at 256x256 x 8 spp took 15 GB).
        fr.samples = np.ascontiguousarray(fr.samples[..., columns])
        fr.albedo = fr.normal = fr.depth = fr.position = fr.emissive = None
    if cache_dtype == "float16":
        fr.samples = to_half(fr.samples)
    return fr


#: Version of the disk cache's layout; a change of what :func:`_read_for_cache` keeps bumps it,
#: so files of an older layout are never read as the new one.
DISK_CACHE_VERSION = 1
#: The arrays of a cached frame kept on disk (Frame fields; absent ones are not written).
_DISK_FIELDS = tuple(layer.name for layer in PIXEL_LAYERS) + ("samples",)


def disk_cache_key(path: str, columns: list[int] | None, keep: int | None, cache_dtype: str) -> str:
    """Name of frame ``path``'s folder in a disk cache: a hash of the file (absolute path, size,
    modification time), what is kept of it and :data:`DISK_CACHE_VERSION`, so a re-rendered
    frame or another model's columns never read stale arrays."""
    st = os.stat(path)
    what = repr((os.path.abspath(path), st.st_size, st.st_mtime_ns, columns, keep, cache_dtype, DISK_CACHE_VERSION))
    return hashlib.sha256(what.encode()).hexdigest()[:24]


def _write_disk_cache(path: str, columns: list[int] | None, keep: int | None, cache_dtype: str,
                      cache_dir: str) -> str:
    """Frame ``path`` as :func:`_read_for_cache` keeps it, written under ``cache_dir`` once
    (skipped where its folder exists); returns the folder. Written to a private folder and
    renamed into place, so a reader (another run, a killed writer's next start) sees a complete
    folder or none."""
    import json

    folder = os.path.join(cache_dir, disk_cache_key(path, columns, keep, cache_dtype))
    if os.path.isdir(folder):
        return folder
    fr = _read_for_cache(path, columns, keep, cache_dtype)
    os.makedirs(cache_dir, exist_ok=True)
    tmp = f"{folder}.tmp-{os.getpid()}"
    os.makedirs(tmp, exist_ok=True)
    for name in _DISK_FIELDS:
        if (arr := getattr(fr, name, None)) is not None:
            np.save(os.path.join(tmp, name + ".npy"), np.ascontiguousarray(arr))
    with open(os.path.join(tmp, "meta.json"), "w") as f:
        # "fields": what a later read must find (a lost .npy would otherwise read as a frame
        # without that layer)
        json.dump({"meta": fr.meta, "path": fr.path,
                   "fields": [n for n in _DISK_FIELDS if getattr(fr, n, None) is not None]}, f)
    try:
        os.rename(tmp, folder)
    except OSError:     # another process wrote it first: theirs is the same
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def disk_cached_frame(path: str, columns: list[int] | None, keep: int | None, cache_dtype: str,
                      cache_dir: str) -> Frame:
    """Frame ``path`` as :func:`_read_for_cache` gives it, from ``cache_dir`` (written there
    first if missing), its arrays memory-mapped read-only; equal to the in-memory frame.

    An entry that cannot be read back whole (a truncated or missing .npy, a broken meta.json:
    a full or failing disk after the rename, or a hand edit) is removed, decoded again from the
    EXR and written anew, with one line on stderr naming it; a second failure raises
    :class:`OSError` naming the folder."""
    import shutil
    import sys

    folder = _write_disk_cache(path, columns, keep, cache_dtype, cache_dir)
    try:
        return _read_disk_cache(folder)
    except (OSError, ValueError, KeyError) as e:   # json.JSONDecodeError is a ValueError
        print(f"mcdenoise train: the disk cache entry {folder} is damaged ({e}); "
              f"decoding {path} again", file=sys.stderr)
        shutil.rmtree(folder, ignore_errors=True)
    folder = _write_disk_cache(path, columns, keep, cache_dtype, cache_dir)
    try:
        return _read_disk_cache(folder)
    except (OSError, ValueError, KeyError) as e:
        raise OSError(f"the disk cache entry {folder} cannot be read back after writing it again "
                      f"({e}): check the disk, or train without --cache-dir") from e


def _read_disk_cache(folder: str) -> Frame:
    """The frame a :func:`_write_disk_cache` folder holds, memory-mapped; ValueError or OSError
    where a file is missing, truncated or not what meta.json lists."""
    import json

    with open(os.path.join(folder, "meta.json")) as f:
        info = json.load(f)
    fields = info.get("fields")     # absent in entries written before it was recorded
    if fields is None:
        fields = [n for n in _DISK_FIELDS if os.path.exists(os.path.join(folder, n + ".npy"))]
    arrays = {name: np.load(os.path.join(folder, name + ".npy"), mmap_mode="r") for name in fields}
    return Frame(**arrays, meta=info["meta"], path=info["path"])


#: the per-sample cache's precisions (SequenceDataset cache_dtype)
CACHE_DTYPES = ("float32", "float16")
#: The share of the available memory a run's cached frames may take (cache_dtype_for): the rest
#: is the trainer's own (torch, the model, a batch's activations: 1-2 GB for wskpn-6e here).
CACHE_MEMORY_FRACTION = 0.85
_HALF_MAX = float(np.finfo(np.float16).max)


def to_half(arr: np.ndarray) -> np.ndarray:
    """``arr`` in float16: finite values beyond +-65504 clipped there (a plain cast makes them
    Inf, which the sanitiser would then zero), NaN and Inf kept as they are."""
    out = np.clip(arr, -_HALF_MAX, _HALF_MAX).astype(np.float16)
    bad = ~np.isfinite(arr)
    out[bad] = arr[bad]
    return out


def cache_dtype_for(need_float32: int, need_float16: int, available: int | None, fraction: float = CACHE_MEMORY_FRACTION) -> str:
    """The cache precision ``train --cache-dtype auto`` picks: float32 when ``need_float32``
    bytes fit in ``fraction`` of ``available``, else float16 when ``need_float16`` does (or
    float32 when the available memory is unknown); a :class:`MemoryError` naming the sizes and
    the ways out when neither does (a run killed by the kernel part-way loses its sitting)."""
    if available is None or need_float32 <= fraction * available:
        return "float32"
    if need_float16 <= fraction * available:
        return "float16"
    raise MemoryError(f"the training frames need {need_float16 / 2**30:.1f} GB even with a float16 cache, "
                      f"{fraction:.0%} of the {available / 2**30:.1f} GB available is the limit: train on fewer "
                      f"sequences (--max-sequences N) or on a machine with more memory")


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux's MemAvailable), None elsewhere."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def collate(items: list[dict]):
    """Stack items into torch tensors: (B, T, C, H, W) per key."""
    import torch

    return {k: torch.from_numpy(np.stack([it[k] for it in items])) for k in items[0]}
