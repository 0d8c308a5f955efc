"""The frame format: channel table, in-memory :class:`Frame`, and the OpenEXR reader.

One frame of a sequence is one OpenEXR file.  This module is the single definition of its
layout; the renderer writes through :func:`runtime.writers.write_frame` (apart from the core,
which only reads), and training, export tests and the runtime read through :func:`read_frame`
(or :func:`read_plain` for the colour/albedo/normal EXR triple other denoisers use).  numpy +
OpenEXR only: no torch here.

Conventions (all layers):
  * images are ``float32`` arrays of shape ``(H, W, C)``; samples ``(S, H, W, F)``;
  * pixel (x, y): x to the right, y down, pixel centres at integer + 0.5;
  * world space is the scene's (Mitsuba: right-handed, the scene file's units);
  * radiance is linear HDR in the renderer's units (W·sr⁻¹·m⁻² per channel).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Iterable, Optional

import numpy as np

FORMAT_VERSION = 1
#: Header attribute holding the frame's JSON metadata.
META_KEY = "mcdenoise"


@dataclass(frozen=True)
class Layer:
    """One documented layer: EXR channels ``<name>.<c>`` for c in ``channels``."""

    name: str
    channels: tuple[str, ...]
    meaning: str
    units: str
    frame: str
    miss: str


#: Pixel layers, in file order.  ``color`` is the only one every frame must have.
PIXEL_LAYERS: tuple[Layer, ...] = (
    Layer("color", ("R", "G", "B"), "mean of the S per-sample radiance values (the noisy image)",
          "linear HDR radiance", "-", "environment radiance (0 without one)"),
    Layer("albedo", ("R", "G", "B"), "mean first-hit albedo (Mitsuba `albedo` AOV)",
          "[0, 1]; >1 possible on roughconductor; 0 on delta BSDFs", "-", "0"),
    Layer("normal", ("X", "Y", "Z"), "mean first-hit shading normal, renormalised",
          "unit vector", "world", "0"),
    Layer("depth", ("Z",), "mean distance from the camera (lens) centre to the first hit (the ray "
          "distance for a pinhole; differs from it by at most the aperture radius for a thin lens)",
          "scene units", "-", "0"),
    Layer("emissive", ("E",), "fraction of the samples whose first hit is an area emitter (the light "
          "itself in view): lets a model demodulate lights by 1, not by their albedo of 0", "[0, 1]", "-", "0"),
    Layer("position", ("X", "Y", "Z"), "mean first-hit position", "scene units", "world", "0"),
    Layer("motion", ("X", "Y"),
          "where this pixel's surface point was in frame t-1, as an offset: prev = (x, y) + motion",
          "pixels", "screen (x right, y down)", "0"),
    Layer("valid", ("V",),
          "1 where the point was visible at prev in frame t-1 (same surface, on screen), else 0 "
          "(disocclusion, off-screen, miss, first frame, camera cut)", "{0, 1}", "-", "0"),
    Layer("reference", ("R", "G", "B"), "radiance at ref_spp with an independent seed",
          "linear HDR radiance", "-", "environment radiance"),
)

#: Per-sample features, in order; EXR channel ``sample<i>.<feature>``; array (S, H, W, F).
#: (name, meaning, units / range, frame, value on a miss)
SAMPLE_FEATURES_DOC: tuple[tuple[str, str, str, str, str], ...] = (
    ("radiance.R", "sample radiance", "linear HDR", "-", "environment"),
    ("radiance.G", "", "", "", ""),
    ("radiance.B", "", "", "", ""),
    ("albedo.R", "first-hit albedo", "[0,1] (>1 roughconductor, 0 delta)", "-", "0"),
    ("albedo.G", "", "", "", ""),
    ("albedo.B", "", "", "", ""),
    ("normal.X", "first-hit shading normal", "unit", "world", "0"),
    ("normal.Y", "", "", "", ""),
    ("normal.Z", "", "", "", ""),
    ("depth", "distance from the camera (lens) centre to the first hit (the ray distance for a "
     "pinhole; differs from it by at most the aperture radius for a thin lens)", "scene units", "-", "0"),
    ("position.X", "first-hit position", "scene units", "world", "0"),
    ("position.Y", "", "", "", ""),
    ("position.Z", "", "", "", ""),
    ("roughness", "first-hit material roughness (alpha); 1 for diffuse, 0 for smooth",
     "[0, 1]", "-", "0"),
    ("metallic", "1 if the first-hit material is a conductor", "{0, 1}", "-", "0"),
    ("transmissive", "1 if the first-hit material is a dielectric", "{0, 1}", "-", "0"),
    ("emissive", "1 if the first-hit shape is an area emitter", "{0, 1}", "-", "0"),
    ("specular", "1 if the first-hit material is specular-dominated "
     "(conductor, roughconductor, dielectric); splits radiance into ANF's diffuse/specular",
     "{0, 1}", "-", "0"),
    ("specular_color.R", "first-hit reflectance at normal incidence: conductors from their optical "
     "constants times specular_reflectance; plastic and dielectric from the IOR (0.04 at 1.5)",
     "[0, 1]", "-", "0"),
    ("specular_color.G", "", "", "", ""),
    ("specular_color.B", "", "", "", ""),
    ("motion.X", "offset to this sample's hit point projected into frame t-1",
     "pixels", "screen", "0"),
    ("motion.Y", "", "", "", ""),
    ("coc", "thin-lens circle of confusion diameter at the hit depth (0 for pinhole)",
     "pixels", "-", "0"),
    ("time", "shutter time of this sample within the frame (0 without motion blur)",
     "[0, 1) of the frame interval", "-", "as hit"),
)
SAMPLE_FEATURES: tuple[str, ...] = tuple(f[0] for f in SAMPLE_FEATURES_DOC)
#: Index of the first channel of each per-sample feature group, e.g. "radiance" -> 0.
SAMPLE_GROUPS: dict[str, slice] = {}
for _i, _n in enumerate(SAMPLE_FEATURES):
    _g = _n.split(".")[0]
    _s = SAMPLE_GROUPS.get(_g)
    SAMPLE_GROUPS[_g] = slice(_i, _i + 1) if _s is None else slice(_s.start, _i + 1)
del _i, _n, _g, _s

_LAYER_BY_NAME = {layer.name: layer for layer in PIXEL_LAYERS}


def _split_radiance(samples: np.ndarray, specular: bool) -> np.ndarray:
    rad = samples[..., SAMPLE_GROUPS["radiance"]]
    flag = samples[..., SAMPLE_GROUPS["specular"]]
    return rad * flag if specular else rad * (1.0 - flag)


#: Per-sample groups computed from stored ones.  ANF (§4.1) splits radiance into diffuse and
#: specular by the first-hit material: a sample whose first hit is specular-dominated (the
#: ``specular`` flag) counts as specular, any other as diffuse; the two sum to ``radiance``.
DERIVED_SAMPLE_GROUPS = {
    "diffuse_radiance": lambda s: _split_radiance(s, specular=False),
    "specular_radiance": lambda s: _split_radiance(s, specular=True),
}


class FrameError(ValueError):
    """A frame file or array is missing, unreadable, or lacks / mis-shapes a channel."""


@dataclass
class Frame:
    """One frame. Arrays are float32; absent layers are ``None``.

    color, albedo, normal, position, reference: (H, W, 3); depth, emissive, valid: (H, W, 1);
    motion: (H, W, 2); samples: (S, H, W, len(SAMPLE_FEATURES)).
    ``meta``: JSON-able dict (spp, frame index, scene seed, camera, cut flag, ...).
    """

    color: np.ndarray
    albedo: Optional[np.ndarray] = None
    normal: Optional[np.ndarray] = None
    depth: Optional[np.ndarray] = None
    emissive: Optional[np.ndarray] = None
    position: Optional[np.ndarray] = None
    motion: Optional[np.ndarray] = None
    valid: Optional[np.ndarray] = None
    reference: Optional[np.ndarray] = None
    samples: Optional[np.ndarray] = None
    meta: dict = field(default_factory=dict)
    path: Optional[str] = None

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return int(self.color.shape[0]), int(self.color.shape[1])

    @property
    def spp(self) -> int:
        """Samples per pixel stored per-sample (0 if none stored)."""
        return 0 if self.samples is None else int(self.samples.shape[0])

    @property
    def color_spp(self) -> int:
        """Samples per pixel behind ``color``: the stored samples, else the metadata's ``spp``
        (a renderer's own frames), else 0 (unknown)."""
        if self.samples is not None:
            return self.spp
        n = (self.meta or {}).get("spp", 0)
        return n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else 0

    def layer(self, name: str) -> np.ndarray:
        """A pixel layer by name, or a :class:`FrameError` naming the frame and layer."""
        if name not in _LAYER_BY_NAME:
            raise FrameError(f"unknown layer {name!r}; known: {[l.name for l in PIXEL_LAYERS]}")
        arr = getattr(self, name)
        if arr is None:
            raise FrameError(f"{self.path or 'frame'}: missing layer {name!r} "
                             f"(channels {', '.join(name + '.' + c for c in _LAYER_BY_NAME[name].channels)})")
        return arr

    def sample_feature(self, group: str) -> np.ndarray:
        """Per-sample feature group (e.g. "radiance", "depth") as (S, H, W, C), or a derived
        group of :data:`DERIVED_SAMPLE_GROUPS` (ANF's diffuse/specular radiance split)."""
        if self.samples is None:
            raise FrameError(f"{self.path or 'frame'}: has no per-sample layers (sample<i>.*)")
        if group in DERIVED_SAMPLE_GROUPS:
            return DERIVED_SAMPLE_GROUPS[group](self.samples)
        if group not in SAMPLE_GROUPS:
            raise FrameError(f"unknown sample feature {group!r}; known: "
                             f"{list(SAMPLE_GROUPS) + list(DERIVED_SAMPLE_GROUPS)}")
        return self.samples[..., SAMPLE_GROUPS[group]]

    def validate(self) -> None:
        """Check every present layer has shape (H, W, C) of its table entry; raise FrameError."""
        h, w = self.size
        for layer in PIXEL_LAYERS:
            arr = getattr(self, layer.name)
            if arr is None:
                continue
            want = (h, w, len(layer.channels))
            if arr.shape != want:
                raise FrameError(f"{self.path or 'frame'}: layer {layer.name!r} has shape "
                                 f"{arr.shape}, expected {want}")
        if self.samples is not None and self.samples.shape[1:] != (h, w, len(SAMPLE_FEATURES)):
            raise FrameError(f"{self.path or 'frame'}: samples have shape {self.samples.shape}, "
                             f"expected (S, {h}, {w}, {len(SAMPLE_FEATURES)})")


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------

def _open(path: str, header_only: bool = False):
    import OpenEXR

    if not os.path.exists(path):
        raise FrameError(f"{path}: no such file")
    if os.path.isdir(path):
        raise FrameError(f"{path}: is a directory, expected an OpenEXR file")
    try:
        return OpenEXR.File(path, separate_channels=True, header_only=header_only)
    except Exception as e:  # OpenEXR raises bare RuntimeError/Exception with C++ messages
        raise FrameError(f"{path}: not a readable OpenEXR file ({e})") from None


def _channel_names(f) -> list[str]:
    return [c.name for c in f.header()["channels"]]


def _as_float32(path: str, name: str, arr: np.ndarray) -> np.ndarray:
    if arr.dtype == np.float32:
        return arr
    if arr.dtype == np.float16:
        return arr.astype(np.float32)
    raise FrameError(f"{path}: channel {name!r} has dtype {arr.dtype}, expected float32 or half")


def read_meta(path: str | os.PathLike, f=None) -> dict:
    """The frame's JSON metadata (header only; cheap); ``f``: the file, when open already."""
    path = os.fspath(path)
    raw = (f or _open(path, header_only=True)).header().get(META_KEY)
    try:
        return json.loads(raw) if raw else {}
    except json.JSONDecodeError as e:
        raise FrameError(f"{path}: header attribute {META_KEY!r} is not valid JSON ({e})") from None


def read_frame(path: str | os.PathLike, layers: Optional[Iterable[str]] = None,
               require: Iterable[str] = ("color",), samples: bool | int = True) -> Frame:
    """Read a frame file written by :func:`write_frame`.

    Args:
      layers: pixel layers to load (default: all present).
      require: layers that must be present; a missing channel raises :class:`FrameError`
        naming the file and the channel.  Use ``"samples"`` to require per-sample layers.
      samples: load per-sample layers (``True``), none (``False``), or only the first N.
    """
    path = os.fspath(path)
    f = _open(path)
    try:
        chans = f.channels()
    except Exception as e:
        raise FrameError(f"{path}: pixel data cannot be decoded, file truncated or corrupt ({e})") from None
    meta = read_meta(path, f)

    def get(name: str) -> np.ndarray:
        if name not in chans:
            raise FrameError(f"{path}: missing channel {name!r}")
        return _as_float32(path, name, chans[name].pixels)

    require = set(require)
    want = [l.name for l in PIXEL_LAYERS] if layers is None else list(layers)
    out: dict[str, np.ndarray] = {}
    for name in set(want) | (require - {"samples"}):
        if name not in _LAYER_BY_NAME:
            raise FrameError(f"unknown layer {name!r}; known: {list(_LAYER_BY_NAME)}")
        layer = _LAYER_BY_NAME[name]
        present = [f"{name}.{c}" in chans for c in layer.channels]
        if not any(present) and name not in require:
            continue
        out[name] = np.stack([get(f"{name}.{c}") for c in layer.channels], axis=-1)
    if "color" not in out:
        raise FrameError(f"{path}: missing channel 'color.R'")

    sample_arr = None
    n_stored = 0
    while f"sample{n_stored}.radiance.R" in chans:
        n_stored += 1
    if "samples" in require and n_stored == 0:
        raise FrameError(f"{path}: missing channel 'sample0.radiance.R' (no per-sample layers)")
    n_load = n_stored if samples is True else (0 if samples is False else min(int(samples), n_stored))
    if n_load:
        sample_arr = np.empty((n_load, *out["color"].shape[:2], len(SAMPLE_FEATURES)), np.float32)
        for s in range(n_load):
            for i, fname in enumerate(SAMPLE_FEATURES):
                sample_arr[s, ..., i] = get(f"sample{s}.{fname}")
        if "emissive" in want and "emissive" not in out and n_load == n_stored:   # written before the layer
            out["emissive"] = pixel_means(sample_arr)["emissive"]
    frame = Frame(samples=sample_arr, meta=meta, path=path, **out)
    frame.validate()
    return frame


def _read_pfm(path: str) -> np.ndarray:
    with open(path, "rb") as fh:
        kind = fh.readline().strip()
        if kind not in (b"PF", b"Pf"):
            raise FrameError(f"{path}: not a PFM file (magic {kind!r})")
        try:
            w, h = (int(v) for v in fh.readline().split())
            scale = float(fh.readline())
        except ValueError:
            raise FrameError(f"{path}: malformed PFM header") from None
        c = 3 if kind == b"PF" else 1
        data = np.frombuffer(fh.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h * c:
        raise FrameError(f"{path}: PFM truncated ({data.size} of {w * h * c} floats)")
    img = data.reshape(h, w, c)[::-1].astype(np.float32)
    return np.repeat(img, 3, axis=-1) if c == 1 else img


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """A plain RGB image (EXR with R,G,B or <layer>.R,G,B channels, or PFM) as (H, W, 3)."""
    path = os.fspath(path)
    if path.lower().endswith(".pfm"):
        if not os.path.exists(path):
            raise FrameError(f"{path}: no such file")
        return _read_pfm(path)
    f = _open(path)
    try:
        chans = f.channels()
    except Exception as e:
        raise FrameError(f"{path}: pixel data cannot be decoded, file truncated or corrupt ({e})") from None
    for prefix in ("", "color.", "rgb.", "albedo.", "normal."):
        names = [prefix + c for c in "RGB"]
        if all(n in chans for n in names):
            return np.stack([_as_float32(path, n, chans[n].pixels) for n in names], axis=-1)
    if all(n in chans for n in ("X", "Y", "Z")):
        return np.stack([_as_float32(path, n, chans[n].pixels) for n in "XYZ"], axis=-1)
    raise FrameError(f"{path}: missing channel 'R' (found {sorted(chans)[:8]})")


def read_gray(path: str | os.PathLike) -> np.ndarray:
    """A one-channel image as (H, W, 1) float32: a greyscale PFM (``Pf``), or an EXR with a
    ``Z``, ``depth.Z``, ``Y`` or ``E`` (our frames' emissive layer) channel, or R, G, B channels that are equal (a grey image
    written as RGB)."""
    path = os.fspath(path)
    if path.lower().endswith(".pfm"):
        if not os.path.exists(path):
            raise FrameError(f"{path}: no such file")
        with open(path, "rb") as fh:
            if fh.readline().strip() != b"Pf":
                raise FrameError(f"{path}: a one-channel image must be a greyscale PFM ('Pf')")
        return _read_pfm(path)[..., :1]
    f = _open(path)
    try:
        chans = f.channels()
    except Exception as e:
        raise FrameError(f"{path}: pixel data cannot be decoded, file truncated or corrupt ({e})") from None
    for n in ("Z", "depth.Z", "Y", "E"):
        if n in chans:
            return _as_float32(path, n, chans[n].pixels)[..., None]
    rgb = read_rgb(path)
    if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
        raise FrameError(f"{path}: expected one channel (Z, depth.Z, Y or E, or equal R, G, B), "
                         f"found different R, G, B")
    return rgb[..., :1].copy()


def read_plain(color: str | os.PathLike, albedo: str | os.PathLike | None = None,
               normal: str | os.PathLike | None = None, depth: str | os.PathLike | None = None,
               emissive: str | os.PathLike | None = None) -> Frame:
    """The Open Image Denoise input convention: a colour image plus optional albedo/normal
    images of the same size (EXR or PFM), and one-channel images (:func:`read_gray`) of depth
    (any unit: models see depth / its maximum; 0 on a miss) and emissive (the fraction of
    samples that hit a light, in [0, 1]).  A pixel-only :class:`Frame` (no motion, no history)."""
    c = read_rgb(color)
    fr = Frame(color=c, path=os.fspath(color), meta={"source": "plain"})
    for name, p in (("albedo", albedo), ("normal", normal), ("depth", depth), ("emissive", emissive)):
        if p is None:
            continue
        arr = read_gray(p) if name in ("depth", "emissive") else read_rgb(p)
        if arr.shape[:2] != c.shape[:2]:
            raise FrameError(f"{p}: {name} image is {arr.shape[1]}x{arr.shape[0]}, colour "
                             f"{color} is {c.shape[1]}x{c.shape[0]}")
        if (bad := arr[~((arr >= 0) & (arr <= 1))] if name == "emissive" else arr[:0]).size:
            raise FrameError(f"{p}: the emissive image holds the fraction of each pixel's samples that hit "
                             f"a light, in [0, 1]; found {bad.size} pixel(s) outside it (e.g. {float(bad[0]):g})")
        setattr(fr, name, arr)
    return fr


def pixel_means(samples: np.ndarray) -> dict[str, np.ndarray]:
    """Pixel layers implied by per-sample data (S, H, W, F): the mean of radiance (``color``),
    albedo, depth, the emissive flag and position, and the renormalised mean normal (0 where all
    samples miss); a dict of :class:`Frame` fields (no emissive from fewer features than that
    flag's index: a cache that dropped the later ones).
    The one definition of how samples become pixels; the renderer and the dataset's spp
    subsets both use it."""
    m = samples.mean(axis=0)
    g = SAMPLE_GROUPS
    nrm = m[..., g["normal"]]
    length = np.linalg.norm(nrm, axis=-1, keepdims=True)
    nrm = np.where(length > 1e-6, nrm / np.maximum(length, 1e-6), 0.0).astype(np.float32)
    return {"color": m[..., g["radiance"]], "albedo": m[..., g["albedo"]], "normal": nrm,
            "depth": m[..., g["depth"]], "position": m[..., g["position"]],
            **({"emissive": m[..., g["emissive"]]} if m.shape[-1] >= g["emissive"].stop else {})}


#: Sequence layout on disk: <root>/<scene dir>/frame_<t:04d>.exr, one folder per sequence,
#: plus <root>/manifest.json written by the renderer (scene seeds, render settings).
MANIFEST = "manifest.json"


def frame_name(t: int) -> str:
    """File name of frame ``t`` inside a sequence folder."""
    return f"frame_{t:04d}.exr"


def frame_paths(directory: str | os.PathLike) -> list[str]:
    """Sorted frame files (``frame_*.exr``, as :func:`frame_name` writes them) directly in
    ``directory``; other EXR files there (textures, outputs) are not frames."""
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise FrameError(f"{directory}: not a directory")
    return sorted(os.path.join(directory, n) for n in os.listdir(directory)
                  if n.startswith("frame_") and n.endswith(".exr"))

