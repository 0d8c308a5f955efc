"""Every denoising method the measuring commands compare, behind one interface.

A *method* is an object with

``name: str``
    the label in tables and charts (an ONNX model's spec name, ``oidn-high``, ``svgf``...);
``__call__(frame) -> (H, W, 3) float32``
    denoise one frame of the current sequence (a :class:`runtime.frames.Frame` or a dict of
    (H, W, C) layers), linear HDR radiance;
``reset()``
    forget temporal state (start of an unrelated sequence).

:func:`load_method` builds one from a name: a path to an mcdenoise ``.onnx`` file (the
runtime driver, :class:`runtime.denoiser.Denoiser`), ``noisy`` (the input itself),
``oidn-high`` / ``oidn-fast`` (Intel Open Image Denoise via ``pyoidn`` with albedo and normal,
HDR), ``oidn-high-aa`` / ``oidn-fast-aa`` (the same fed the albedo accumulated over frames, as
the driver accumulates it for a model whose spec asks: :class:`AlbedoHistory`), or ``svgf``
(the classical non-neural temporal filter, :mod:`training.svgf`).
``evaluate``, ``bench`` and ``stress`` all go through here, so a method is run the same way
everywhere.  Only the runtime stack is needed (no torch); ``pyoidn`` only for OIDN.
"""
from __future__ import annotations

import os

import numpy as np

from mcdenoise.runtime.frames import Frame, FrameError

#: Built-in method names (besides ONNX file paths).
BUILTIN = ("noisy", "oidn-high", "oidn-fast", "oidn-high-aa", "oidn-fast-aa", "svgf")


def _frame(frame) -> Frame:
    from mcdenoise.runtime.denoiser import _as_frame

    return _as_frame(frame)


class Noisy:
    """The noisy input itself (the lower bound every denoiser must beat)."""

    name = "noisy"

    def __call__(self, frame) -> np.ndarray:
        return np.asarray(_frame(frame).color, dtype=np.float32)

    def reset(self) -> None:
        pass


class OIDN:
    """Intel Open Image Denoise (``pyoidn``): colour + albedo + normal, HDR, one frame at a time.

    OIDN has no temporal state and no input sanitising of its own: what it does with NaN or
    huge input is what users get, so the measuring commands feed it the frame as is.
    """

    def __init__(self, quality: str = "high"):
        try:
            import pyoidn
        except ImportError as e:
            raise FrameError("Open Image Denoise needs the 'pyoidn' package: pip install pyoidn "
                             "(or the project's [bench] extra)") from e
        if quality not in ("high", "balanced", "fast"):
            raise ValueError(f"OIDN quality must be high, balanced or fast, got {quality!r}")
        self._oidn = pyoidn
        self.quality = quality
        self.name = f"oidn-{quality}"

    def __call__(self, frame) -> np.ndarray:
        fr = _frame(frame)
        aux = {}
        if fr.albedo is not None:
            aux["albedo"] = np.ascontiguousarray(fr.albedo, dtype=np.float32)
        if fr.normal is not None:
            aux["normal"] = np.ascontiguousarray(fr.normal, dtype=np.float32)
        if "normal" in aux and "albedo" not in aux:
            aux.pop("normal")  # OIDN accepts a normal only together with an albedo
        out = self._oidn.denoise(self._array(np.ascontiguousarray(fr.color, dtype=np.float32)), hdr=True,
                                 quality=self.quality, **{k: self._array(v) for k, v in aux.items()})
        return self._numpy(out)

    def _array(self, a: np.ndarray):
        """The array type pyoidn runs on (numpy: its CPU device; subclasses may move it)."""
        return a

    def _numpy(self, out) -> np.ndarray:
        return np.asarray(out, dtype=np.float32)

    def reset(self) -> None:
        pass


class AlbedoHistory:
    """``method`` fed each frame's albedo accumulated over the sequence, as the driver
    accumulates an ``[[accumulate]]`` layer (wskpn-6e-aa's albedo): the kept albedo reprojected
    along the motion vectors with the driver's consistency test
    (:func:`runtime.temporal.reproject` on depth, position and normal), blended with the
    frame's at the weight of :meth:`runtime.temporal.Protocol.alpha` (spp / (spp + history_spp)
    for a frame of known spp when history_spp > 0, else ``alpha``; by default wskpn-6e-aa's
    albedo entry), restarted where the test keeps
    no history, on a camera cut, a resolution change, a frame without motion, and at
    :meth:`reset`. A comparison with such a model then gives the other method the same cleaner
    albedo. The albedo is (H, W, 3) in [0, 1]-ish units; a non-finite value is kept out of the
    history (0 there), the frame's own value is what the method sees where it has no history."""

    SUFFIX = "-aa"

    def __init__(self, method, alpha: float | None = None, history_spp: float | None = None):
        if alpha is None or history_spp is None:
            from mcdenoise.training.specs import load_spec

            entry = next(a for a in load_spec("wskpn-6e-aa").accumulate if a.layer == "albedo")
            alpha = entry.alpha if alpha is None else alpha
            history_spp = entry.history_spp if history_spp is None else history_spp
        if not 0 < alpha <= 1 or not history_spp >= 0:
            raise ValueError(f"alpha must be in (0, 1] and history_spp >= 0, got {alpha}, {history_spp}")
        self.method, self.alpha, self.history_spp = method, float(alpha), float(history_spp)
        self.name = method.name + self.SUFFIX
        self.reset()

    def reset(self) -> None:
        self.method.reset()
        self._albedo = self._guides = None

    def __call__(self, frame) -> np.ndarray:
        from dataclasses import replace

        from mcdenoise.runtime.temporal import Protocol, accumulate, reproject

        fr = _frame(frame)
        if fr.albedo is None:
            return self.method(fr)

        def planes(a):      # (H, W, C) -> (1, C, H, W), finite
            a = np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 0, 1)[None])
            return np.where(np.isfinite(a), a, np.float32(0))

        albedo = planes(fr.albedo)
        guides = {n: planes(getattr(fr, n)) for n in ("depth", "position", "normal") if getattr(fr, n) is not None}
        fresh = (self._albedo is None or self._albedo.shape != albedo.shape or fr.motion is None
                 or "depth" not in guides or fr.meta.get("cut"))
        if not fresh:
            (warped,), history = reproject([self._albedo], planes(fr.motion), guides, self._guides)
            alpha = Protocol.alpha(("albedo", "albedo", self.alpha, self.history_spp), fr.color_spp)
            albedo = accumulate(albedo, warped, history, alpha).astype(np.float32, copy=False)
        self._albedo, self._guides = albedo, guides
        return self.method(replace(fr, albedo=albedo[0].transpose(1, 2, 0).copy()))


class ONNXModel:
    """An mcdenoise ONNX file run by the runtime driver (temporal state included)."""

    def __init__(self, path: str, threads: int = 0, providers=None, profile: bool = False, log=None,
                 accumulate_alpha: float | None = None, history_spp: float | None = None):
        from mcdenoise.runtime.denoiser import Denoiser

        self.denoiser = Denoiser.load(path, providers=providers, threads=threads, profile=profile,
                                      log=log or (lambda m: None), accumulate_alpha=accumulate_alpha,
                                      history_spp=history_spp)
        self.path = str(path)
        self.name = self.denoiser.contract.spec_name

    def __call__(self, frame) -> np.ndarray:
        return self.denoiser(frame)

    def reset(self) -> None:
        self.denoiser.reset()


class WithoutHistory:
    """A temporal method reset before every frame: what its history earns is its score minus
    this one's (a history must never make a sequence worse than none)."""

    SUFFIX = " (no history)"

    def __init__(self, method):
        self.method = method
        self.name = method.name + self.SUFFIX

    def __call__(self, frame) -> np.ndarray:
        self.method.reset()
        return self.method(frame)

    def reset(self) -> None:
        self.method.reset()


#: onnxruntime execution providers per ``device`` argument.
PROVIDERS = {"cpu": ["CPUExecutionProvider"], "cuda": ["CUDAExecutionProvider", "CPUExecutionProvider"]}


def load_method(name: str, threads: int = 0, providers=None, profile: bool = False, log=None,
                device: str = "cpu", accumulate_alpha: float | None = None, history_spp: float | None = None):
    """A method object for ``name``: an ``.onnx`` path or one of :data:`BUILTIN`.

    ``device`` ("cpu" or "cuda") picks onnxruntime's execution provider (unless ``providers``
    is given); Open Image Denoise, SVGF and the noisy input run on the CPU here (pyoidn's CUDA
    device needs torch tensors: ``training.bench`` wraps it, keeping this module torch-free).
    ``accumulate_alpha`` and ``history_spp`` override a model file's accumulation weight
    (:meth:`runtime.denoiser.Denoiser.load`).
    """
    if device not in PROVIDERS:
        raise ValueError(f"device must be one of {', '.join(PROVIDERS)}, got {device!r}")
    if name.endswith(".onnx") or os.path.sep in name:
        return ONNXModel(name, threads=threads, providers=providers or PROVIDERS[device], profile=profile, log=log,
                         accumulate_alpha=accumulate_alpha, history_spp=history_spp)
    if name == "noisy":
        return Noisy()
    if name.startswith("oidn-") and name.endswith(AlbedoHistory.SUFFIX):
        return AlbedoHistory(OIDN(name[len("oidn-"):-len(AlbedoHistory.SUFFIX)]))
    if name.startswith("oidn-"):
        return OIDN(name[len("oidn-"):])
    if name == "svgf":
        from mcdenoise.training.svgf import SVGF

        return SVGF()
    raise ValueError(f"unknown method {name!r}: give an .onnx file or one of {', '.join(BUILTIN)}")


def check_distinct(names: dict[str, str]) -> None:
    """Raise ValueError when two methods share a name: ``names`` maps each source (a file or a
    built-in method) to the name its results are reported under, and results are keyed by
    that name (two exports of one spec would otherwise be pooled into one row)."""
    seen: dict[str, str] = {}
    for source, name in names.items():
        if name in seen:
            raise ValueError(f"{seen[name]} and {source} are both reported as {name!r} (methods are "
                             "named by their spec): compare them in separate runs")
        seen[name] = source


def shipped_models(root: str | os.PathLike | None = None) -> list[str]:
    """Paths of the ONNX models shipped in the repository's ``models/`` folder, sorted."""
    from pathlib import Path

    from mcdenoise.runtime import data_path

    base = Path(root) if root else data_path("models")
    return sorted(str(p) for p in base.glob("*.onnx"))
