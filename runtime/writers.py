"""Writing frame files (:func:`write_frame`, the layout runtime/frames.py defines and reads), plain
RGB EXRs (:func:`write_rgb`, what :func:`runtime.frames.read_rgb` reads) and 8-bit PNGs: what a renderer, the denoise command and the reports do, apart from the deployable
core, which only reads frames."""
from __future__ import annotations

import json
import os

import numpy as np

from mcdenoise.runtime.frames import FORMAT_VERSION, META_KEY, PIXEL_LAYERS, SAMPLE_FEATURES, Frame, FrameError


def write_frame(path: str | os.PathLike, frame: Frame) -> None:
    """Write ``frame`` as one ZIP-compressed float32 OpenEXR file with the documented layout."""
    import OpenEXR

    frame.validate()
    channels: dict[str, np.ndarray] = {}
    for layer in PIXEL_LAYERS:
        arr = getattr(frame, layer.name)
        if arr is None:
            continue
        for c, cname in enumerate(layer.channels):
            channels[f"{layer.name}.{cname}"] = np.ascontiguousarray(arr[..., c], dtype=np.float32)
    if frame.samples is not None:
        for s in range(frame.samples.shape[0]):
            for f, fname in enumerate(SAMPLE_FEATURES):
                channels[f"sample{s}.{fname}"] = np.ascontiguousarray(frame.samples[s, ..., f],
                                                                      dtype=np.float32)
    meta = dict(frame.meta)
    meta["format_version"] = FORMAT_VERSION
    meta["spp"] = frame.spp if frame.samples is not None else meta.get("spp", 0)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              META_KEY: json.dumps(meta, sort_keys=True)}
    tmp = f"{os.fspath(path)}.tmp"
    OpenEXR.File(header, channels).write(tmp)
    os.replace(tmp, path)  # a crash mid-write never leaves a truncated frame behind


def write_rgb(path: str | os.PathLike, image: np.ndarray, meta: dict | None = None) -> None:
    """Write an (H, W, 3) image as a plain R,G,B float32 EXR (readable by any EXR tool and by
    :func:`runtime.frames.read_rgb`)."""
    import OpenEXR

    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] != 3:
        raise FrameError(f"{path}: expected an (H, W, 3) image, got {image.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if meta:
        header[META_KEY] = json.dumps(meta, sort_keys=True)
    chans = {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
    tmp = f"{os.fspath(path)}.tmp"
    OpenEXR.File(header, chans).write(tmp)
    os.replace(tmp, path)


def write_png(path: str | os.PathLike, image01: np.ndarray) -> None:
    """Write an (H, W, 3) image with values in [0, 1] as an 8-bit PNG (no imaging library)."""
    import struct
    import zlib

    img = (np.clip(np.nan_to_num(image01), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    h, w = img.shape[:2]
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as fh:
        fh.write(png)
