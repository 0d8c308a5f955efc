"""Per-shape material features, read back from a loaded Mitsuba scene.

Mitsuba has no roughness or metallic AOV, but its ``shape_index`` AOV identifies the first-hit
shape exactly, so a table of each shape's material turns every material property into an exact
per-sample feature.  The table is read from the loaded objects (BSDF class and traversed
parameters) rather than from the generator's intentions, so user scenes get the same treatment;
the tests check it against what the generator asked for.

Row layout (:data:`ROW`): roughness, metallic, transmissive, emissive, specular,
specular_color R, G, B; see ``runtime.frames.SAMPLE_FEATURES_DOC`` for meanings and ranges.
"""
from __future__ import annotations

import re
import sys

import numpy as np

#: The per-sample feature groups a table row fills, in row order (names of runtime.frames.SAMPLE_GROUPS).
ROW = ("roughness", "metallic", "transmissive", "emissive", "specular", "specular_color")
ROW_WIDTH = 8
#: Plastic-like coatings without an explicit index of refraction reflect about this much at normal incidence.
DEFAULT_F0 = 0.04


def class_name(text: str) -> str:
    """The class name a Mitsuba object's repr starts with, e.g. "RoughConductor"."""
    m = re.match(r"\s*(\w+)", text)
    return m.group(1) if m else ""


def _value(params, key: str, default):
    """A traversed parameter as a float64 array: plain, ``.value`` (uniform/rgb texture) or
    ``.data`` (bitmap: its mean colour)."""
    for k in (key, key + ".value"):
        if k in params:
            return np.asarray(params[k], np.float64).reshape(-1)
    if key + ".data" in params:
        data = np.asarray(params[key + ".data"], np.float64)
        return data.reshape(-1, data.shape[-1]).mean(axis=0)
    return np.asarray(default, np.float64).reshape(-1)


def _rgb(v) -> np.ndarray:
    v = np.asarray(v, np.float64).reshape(-1)
    return np.broadcast_to(v[:3] if v.size >= 3 else v[:1], (3,)).copy()


def fresnel_dielectric_f0(eta) -> np.ndarray:
    """Normal-incidence reflectance of a dielectric interface with relative index ``eta``."""
    eta = np.asarray(eta, np.float64)
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def fresnel_conductor_f0(eta, k) -> np.ndarray:
    """Normal-incidence reflectance of a conductor with complex index eta + i k (per channel)."""
    eta, k = np.asarray(eta, np.float64), np.asarray(k, np.float64)
    return ((eta - 1.0) ** 2 + k ** 2) / ((eta + 1.0) ** 2 + k ** 2)


def bsdf_row(bsdf_repr: str, params, prefix: str = "") -> tuple[np.ndarray, str]:
    """Feature row (ROW_WIDTH,) for one BSDF given its ``repr`` and ``mi.traverse`` parameters.

    Returns (row, class name).  Unknown BSDF classes get the diffuse row (roughness 1, zeros).
    """
    cls = class_name(bsdf_repr)
    if cls == "TwoSided":  # both sides share brdf[0] unless a second one is given; the front decides
        m = re.search(r"brdf\[0\]\s*=\s*(\w+)", bsdf_repr)
        inner = bsdf_repr[m.start(1):] if m else ""
        return bsdf_row(inner, params, prefix + "brdf_0.")
    p = lambda key, default: _value(params, prefix + key, default)
    row = np.zeros(ROW_WIDTH)
    rough, metallic, transmissive, specular, color = 1.0, 0.0, 0.0, 0.0, np.zeros(3)
    if cls in ("SmoothPlastic", "RoughPlastic"):
        rough = 0.0 if cls == "SmoothPlastic" else float(p("alpha", 0.1).mean())
        color = _rgb(fresnel_dielectric_f0(p("eta", 1.5)))
    elif cls in ("SmoothConductor", "RoughConductor"):
        if cls == "SmoothConductor":
            rough = 0.0
        elif prefix + "alpha_u" in params or prefix + "alpha_u.value" in params:
            rough = float(np.mean([p("alpha_u", 0.1).mean(), p("alpha_v", 0.1).mean()]))
        else:
            rough = float(p("alpha", 0.1).mean())
        metallic, specular = 1.0, 1.0
        color = _rgb(fresnel_conductor_f0(_rgb(p("eta", 0.0)), _rgb(p("k", 1.0)))) * _rgb(p("specular_reflectance", 1.0))
    elif cls in ("SmoothDielectric", "RoughDielectric", "ThinDielectric"):
        rough = float(p("alpha", 0.1).mean()) if cls == "RoughDielectric" else 0.0
        transmissive, specular = 1.0, 1.0
        color = _rgb(fresnel_dielectric_f0(p("eta", 1.5))) * _rgb(p("specular_reflectance", 1.0))
    elif cls == "Principled":
        r = float(p("roughness", 0.5).mean())
        rough = r * r  # Disney roughness -> microfacet alpha
        metallic = float(p("metallic", 0.0).mean() >= 0.5)
        transmissive = float(p("spec_trans", 0.0).mean() >= 0.5)
        specular = float(metallic or transmissive)
        color = _rgb(p("base_color", 0.5)) if metallic else np.full(3, DEFAULT_F0)
    elif cls not in ("SmoothDiffuse", "RoughDiffuse"):
        return _diffuse_row(), cls
    row[:5] = rough, metallic, transmissive, 0.0, specular
    row[5:] = np.clip(color, 0.0, 1.0)
    return row, cls


def _diffuse_row() -> np.ndarray:
    row = np.zeros(ROW_WIDTH)
    row[0] = 1.0
    return row


def shape_ids(mi, scene) -> np.ndarray:
    """The value the ``shape_index`` AOV reports for each of ``scene.shapes()`` (uint32 (n,)).

    LLVM/CUDA variants report the shape's Dr.Jit registry id, which starts at 1 and keeps
    growing across scenes loaded in one process; scalar variants report the position in
    ``scene.shapes()`` plus one.  The renderer checks this mapping against hit positions.
    """
    n = len(scene.shapes())
    if mi.variant().startswith("scalar"):
        return np.arange(1, n + 1, dtype=np.uint32)
    import drjit as dr

    return np.asarray(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), np.uint32).reshape(-1)


def material_table(mi, scene, warn=True) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Lookup table from ``shape_index`` AOV value to feature row.

    Returns (lut (max_id + 1, ROW_WIDTH) float32 with row 0 (a miss) all zero,
    ids (n,) per shape, names (n,) shape ids as in the scene file).
    """
    shapes = scene.shapes()
    ids = shape_ids(mi, scene)
    lut = np.zeros((int(ids.max(initial=0)) + 1, ROW_WIDTH), np.float32)
    unknown = set()
    names = []
    for shape, sid in zip(shapes, ids):
        bsdf = shape.bsdf()
        if bsdf is None:
            row, cls = _diffuse_row(), "SmoothDiffuse"
        else:
            row, cls = bsdf_row(repr(bsdf), mi.traverse(bsdf))
            if cls not in KNOWN_CLASSES:
                unknown.add(cls)
        row[3] = 1.0 if shape.is_emitter() else 0.0
        lut[sid] = row
        names.append(shape.id())
    if unknown and warn:
        print(f"mcdenoise render: no material features for BSDF type(s) {', '.join(sorted(unknown))}; "
              f"treated as diffuse", file=sys.stderr)
    return lut, ids, names


KNOWN_CLASSES = {"TwoSided", "SmoothDiffuse", "RoughDiffuse", "SmoothPlastic", "RoughPlastic",
                 "SmoothConductor", "RoughConductor", "SmoothDielectric", "RoughDielectric",
                 "ThinDielectric", "Principled"}
