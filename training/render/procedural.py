"""Procedural training scenes, numpy only and deterministic from one integer seed.

Modelled on the generators of NDLE §4 / ANF §4.1 (after Gharbi et al. 2019), with built-in
shapes and numpy-generated meshes and textures instead of ShapeNet models and photographs:

* geometry: 8-24 objects (sphere, cube, open cylinder, rectangle, disk, and generated meshes:
  noise-displaced spheres, tori, twisted tapered prisms) scattered in a disc of radius 3
  around the origin, resting on or floating above a large floor; indoor scenes add backdrop
  walls behind the objects;
* materials: diffuse, plastic, roughplastic, conductor, roughconductor (metal presets,
  sometimes tinted) and dielectric, with uniform colours, checkerboards at random frequencies
  or numpy noise bitmaps (value noise, marble, spots) at random scales;
* lights: outdoor scenes get a procedural sky (gradient plus a sun blob) as an ``envmap``;
  indoor scenes get 1-3 emissive rectangles, 0-2 point lights and a dim constant or sky
  environment; either may get small emissive spheres;
* camera: random field of view (30-70°), a fly-through that orbits, dollies, rises and pans
  (:class:`camera.FlyThrough`), and a thin lens focused on a random object when defocus is on.

A scene is a :class:`SceneSpec`: a JSON-able Mitsuba scene dict whose meshes and bitmaps are
files (PLY, EXR) written next to it, plus the camera and per-shape material records.  The
renderer loads exactly what it exports, so the exported ``scene.xml`` re-renders the frames.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from mcdenoise.runtime.writers import write_rgb
from mcdenoise.training.render.camera import FlyThrough, Intrinsics, look_at, rotation, translation

#: Path tracing depth: five bounces after the primary hit, as NDLE §4 renders its training set.
MAX_DEPTH = 6
#: Objects are placed within this radius (scene units) of the orbit centre.
OBJECT_RADIUS = 3.0
#: Metal presets Mitsuba knows (``conductor``'s ``material``).
METALS = ("Au", "Ag", "Al", "Cu", "Cr", "W", "Rh", "Ni_palik")
#: Material kinds and their probabilities for objects.
MATERIAL_KINDS = ("diffuse", "plastic", "roughplastic", "conductor", "roughconductor", "dielectric")
MATERIAL_WEIGHTS = (0.28, 0.14, 0.2, 0.1, 0.16, 0.12)
SHAPE_KINDS = ("sphere", "cube", "cylinder", "rectangle", "disk", "blob", "torus", "twisted")
SHAPE_WEIGHTS = (0.16, 0.14, 0.08, 0.08, 0.06, 0.18, 0.15, 0.15)
#: Shapes with an inside and an outside: the only ones that may be glass.
CLOSED_SHAPES = {"sphere", "cube", "blob", "torus", "twisted"}
#: ``floor`` overrides of :func:`generate`: the scene's own floor, or a silver floor that is
#: glossy (GGX alpha :data:`GLOSSY_FLOOR_ALPHA`) or a perfect mirror.  A large reflective
#: area whose reflections move unlike the surface (motion vectors follow the first hit).
FLOOR_KINDS = ("scene", "glossy", "mirror")
GLOSSY_FLOOR_ALPHA = 0.05


@dataclass
class SceneSpec:
    """One procedural scene.

    seed: the scene seed; name: folder name; objects: Mitsuba scene dict entries (shapes and
    emitters, JSON-able: transforms are 4x4 nested lists under ``to_world``/``to_uv``, meshes and
    bitmaps are file names relative to the scene folder); assets: file name -> numpy data to
    write there (``write_assets``); intrinsics, path: the camera; materials: shape id -> the
    material record the generator intended (kind, alpha, ior, metal, emissive); defocus,
    motion_blur: per-scene effect flags; setting: "indoor" or "outdoor".
    """

    seed: int
    name: str
    objects: dict
    assets: dict
    intrinsics: Intrinsics
    path: FlyThrough
    materials: dict
    defocus: bool
    motion_blur: bool
    setting: str


def scene_name(seed: int) -> str:
    return f"scene_{seed:07d}"


# ----------------------------------------------------------------------------------------------
# Meshes (unit size, centred at the origin)
# ----------------------------------------------------------------------------------------------

def _grid_faces(rows: int, cols: int, wrap_cols: bool) -> np.ndarray:
    """Two triangles per cell of a (rows x cols) vertex grid, counter-clockwise seen from +normal
    when rows run along the surface's first parameter and cols along its second."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols if wrap_cols else cols - 1), indexing="ij")
    c1 = (c + 1) % cols if wrap_cols else c + 1
    a, b, cc, d = r * cols + c, r * cols + c1, (r + 1) * cols + c, (r + 1) * cols + c1
    return np.concatenate([np.stack([a, cc, b], -1).reshape(-1, 3),
                           np.stack([b, cc, d], -1).reshape(-1, 3)]).astype(np.int32)


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (n, 3), averaged over vertices at the same position so
    UV seams and poles do not show as creases."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    _, inv = np.unique(np.round(v, 6), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    welded = np.zeros((inv.max() + 1, 3))
    np.add.at(welded, inv, n)
    n = welded[inv]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _orient_outward(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Flip the winding when the signed volume is negative, so normals point outward."""
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum()
    return f[:, ::-1].copy() if vol < 0 else f


def _mesh(v, f, uv) -> dict:
    v = np.asarray(v, np.float64)
    f = _orient_outward(v, np.asarray(f, np.int32))
    return {"vertices": v.astype(np.float32), "normals": vertex_normals(v, f).astype(np.float32),
            "uv": np.asarray(uv, np.float32), "faces": f.astype(np.int32)}


def blob_mesh(rng: np.random.Generator, rows: int = 40, cols: int = 72) -> dict:
    """A unit sphere displaced along its normal by 2-5 random plane waves (0.03-0.12 each).
    Returns dict of vertices (n,3), normals (n,3), uv (n,2) in [0,1], faces (m,3) int32."""
    th = np.linspace(0, math.pi, rows)[:, None]
    ph = np.linspace(0, 2 * math.pi, cols + 1)[None, :]
    d = np.stack([np.sin(th) * np.cos(ph), np.cos(th) * np.ones_like(ph), np.sin(th) * np.sin(ph)], -1)
    disp = np.zeros(d.shape[:2])
    for _ in range(int(rng.integers(2, 6))):
        k = rng.normal(size=3)
        k *= rng.uniform(1.5, 6.0) / np.linalg.norm(k)
        disp += rng.uniform(0.03, 0.12) * np.sin(d @ k + rng.uniform(0, 2 * math.pi))
    v = d * (1.0 + disp)[..., None]
    uv = np.stack(np.meshgrid(np.linspace(0, 1, rows), np.linspace(0, 1, cols + 1), indexing="ij")[::-1], -1)
    return _mesh(v.reshape(-1, 3), _grid_faces(rows, cols + 1, False), uv.reshape(-1, 2))


def torus_mesh(rng: np.random.Generator, rows: int = 32, cols: int = 64) -> dict:
    """A torus in the xz plane, major radius 1, minor radius 0.15-0.45 (same dict as blob_mesh)."""
    minor = rng.uniform(0.15, 0.45)
    a = np.linspace(0, 2 * math.pi, rows + 1)[:, None]   # around the tube
    b = np.linspace(0, 2 * math.pi, cols + 1)[None, :]   # around the ring
    ring = 1.0 + minor * np.cos(a)
    v = np.stack([ring * np.cos(b), minor * np.sin(a) * np.ones_like(b), ring * np.sin(b)], -1)
    v /= 1.0 + minor
    uv = np.stack(np.meshgrid(np.linspace(0, 1, rows + 1), np.linspace(0, 1, cols + 1), indexing="ij")[::-1], -1)
    return _mesh(v.reshape(-1, 3), _grid_faces(rows + 1, cols + 1, False), uv.reshape(-1, 2))


def twisted_mesh(rng: np.random.Generator, rings: int = 32, around: int = 64) -> dict:
    """A capped prism along y (height 2) with a superellipse cross-section (square to round),
    twisted by up to 180° and tapered (same dict as blob_mesh)."""
    p = rng.uniform(2.0, 8.0)               # superellipse exponent: 2 round ... 8 nearly square
    twist = math.radians(rng.uniform(-180, 180))
    taper = rng.uniform(0.3, 1.0)
    y = np.linspace(-1, 1, rings)[:, None]
    a = np.linspace(0, 2 * math.pi, around + 1)[None, :]
    c, s = np.cos(a), np.sin(a)
    r = (np.abs(c) ** p + np.abs(s) ** p) ** (-1.0 / p) * 0.6
    scale = 1.0 - (1.0 - taper) * (y + 1) / 2
    ang = a + twist * (y + 1) / 2
    rr = r * scale
    side = np.stack([rr * np.cos(ang), y * np.ones_like(a), rr * np.sin(ang)], -1).reshape(-1, 3)
    uv_side = np.stack([np.broadcast_to(a / (2 * math.pi), (rings, around + 1)),
                        np.broadcast_to((y + 1) / 2, (rings, around + 1))], -1).reshape(-1, 2)
    faces = [_grid_faces(rings, around + 1, False)]
    verts, uvs = [side], [uv_side]
    base = len(side)
    for ring_idx in (0, rings - 1):  # caps: a fan around a centre vertex, own vertices for flat normals
        ring = side.reshape(rings, around + 1, 3)[ring_idx]
        centre = np.array([[0.0, ring[0, 1], 0.0]])
        verts += [centre, ring]
        uvs += [np.array([[0.5, 0.5]]), 0.5 + 0.5 * np.stack([np.cos(a[0]), np.sin(a[0])], -1)]
        k = np.arange(around)
        fan = np.stack([np.full(around, base), base + 1 + k, base + 2 + k], -1)  # faces -y
        faces.append(fan if ring_idx == 0 else fan[:, ::-1])
        base += 1 + around + 1
    v = np.concatenate(verts)
    f = np.concatenate(faces).astype(np.int32)
    # cap vertices duplicate side positions; keep them separate so the edge stays sharp
    f = _orient_outward(v, f)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    n_side = vertex_normals(side, f[: len(faces[0])])  # oriented side faces; welds the u seam
    n[: len(side)] = n_side
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return {"vertices": v.astype(np.float32), "normals": n.astype(np.float32),
            "uv": np.concatenate(uvs).astype(np.float32), "faces": f}


def write_ply(path: str | os.PathLike, mesh: dict) -> None:
    """Binary little-endian PLY with float x,y,z,nx,ny,nz,u,v and uint32 triangle indices."""
    v, n, uv, f = mesh["vertices"], mesh["normals"], mesh["uv"], mesh["faces"]
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
              + "".join(f"property float {p}\n" for p in ("x", "y", "z", "nx", "ny", "nz", "u", "v"))
              + f"element face {len(f)}\nproperty list uchar uint vertex_indices\nend_header\n")
    vert = np.concatenate([v, n, uv], axis=1).astype("<f4")
    face = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    face["n"], face["i"] = 3, f
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())


# ----------------------------------------------------------------------------------------------
# Textures and the sky
# ----------------------------------------------------------------------------------------------

def _periodic_noise(rng: np.random.Generator, size: int, octaves: int = 5, base: int = 4) -> np.ndarray:
    """Tileable fractal value noise (size, size) in [0, 1]: octaves of random lattices,
    bilinearly interpolated with wrap-around so the texture repeats seamlessly."""
    out = np.zeros((size, size))
    amp_total = 0.0
    for o in range(octaves):
        g = base * 2 ** o
        lattice = rng.random((g, g))
        x = np.arange(size) * g / size
        i0 = np.floor(x).astype(int)
        fr = x - i0
        fr = fr * fr * (3 - 2 * fr)  # smoothstep hides the lattice
        i1 = (i0 + 1) % g
        rows = lattice[i0] * (1 - fr)[:, None] + lattice[i1] * fr[:, None]
        layer = rows[:, i0] * (1 - fr)[None, :] + rows[:, i1] * fr[None, :]
        amp = 0.5 ** o
        out += amp * layer
        amp_total += amp
    out /= amp_total
    return (out - out.min()) / max(out.max() - out.min(), 1e-9)


def random_color(rng: np.random.Generator, lo: float = 0.05, hi: float = 0.85) -> list[float]:
    """A linear RGB reflectance: random hue, saturation 0-0.9, value lo-hi."""
    h, s, v = rng.random(), rng.uniform(0, 0.9), rng.uniform(lo, hi)
    k = (np.array([5, 3, 1]) + h * 6) % 6
    rgb = v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1)
    return [float(c) for c in rgb]


def noise_texture(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """A colour texture (size, size, 3) float32 in [0, 1]: value noise, marble or spots
    between two random colours."""
    n = _periodic_noise(rng, size)
    style = rng.integers(3)
    if style == 1:  # marble: stripes bent by the noise
        x = np.arange(size)[None, :] / size
        n = 0.5 + 0.5 * np.sin(2 * math.pi * (rng.integers(1, 6) * x + rng.uniform(1, 4) * n))
    elif style == 2:  # spots: thresholded noise
        n = (n > rng.uniform(0.4, 0.65)).astype(np.float64)
    c0, c1 = np.array(random_color(rng)), np.array(random_color(rng))
    return (c0 + (c1 - c0) * n[..., None]).astype(np.float32)


def sky_texture(rng: np.random.Generator, width: int = 256, height: int = 128) -> np.ndarray:
    """Equirectangular sky (height, width, 3) float32 linear radiance in Mitsuba's ``envmap``
    layout (top row is +y): a horizon-to-zenith gradient, a darker ground, and a Gaussian sun
    blob 1.5-4° wide, 10-65° above the horizon."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    th, ph = np.meshgrid(v * math.pi, u * 2 * math.pi, indexing="ij")
    d = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1)  # Mitsuba's uv -> dir
    elev = d[..., 1]
    zenith = np.array([0.15, 0.3, 0.8]) * rng.uniform(0.5, 1.5)
    horizon = np.array([0.8, 0.85, 0.95]) * rng.uniform(0.6, 1.4)
    if rng.random() < 0.3:  # sunset or overcast tint
        tint = np.array(random_color(rng, 0.6, 1.0))
        zenith, horizon = zenith * tint, horizon * tint
    t = np.sqrt(np.clip(elev, 0, 1))[..., None]
    img = horizon * (1 - t) + zenith * t
    ground = np.array(random_color(rng, 0.05, 0.3))
    img = np.where(elev[..., None] < 0, ground * (0.3 + 0.7 * np.exp(8 * elev[..., None])), img)
    sun_el, sun_az = math.radians(rng.uniform(10, 65)), rng.uniform(0, 2 * math.pi)
    sun = np.array([math.cos(sun_el) * math.sin(sun_az), math.sin(sun_el), -math.cos(sun_el) * math.cos(sun_az)])
    sigma = math.radians(rng.uniform(1.5, 4.0))
    ang = np.arccos(np.clip(d @ sun, -1, 1))
    strength = rng.uniform(200, 3000) * (math.radians(2.5) / sigma) ** 2  # keep the sun's power comparable
    img = img + strength * np.exp(-(ang / sigma) ** 2)[..., None] * np.array(random_color(rng, 0.9, 1.0))
    return img.astype(np.float32)


def write_assets(spec: SceneSpec, folder: str | os.PathLike) -> None:
    """Write the scene's meshes (PLY) and bitmaps (EXR) into ``folder``."""
    os.makedirs(folder, exist_ok=True)
    for name, data in spec.assets.items():
        path = os.path.join(folder, name)
        if name.endswith(".ply"):
            write_ply(path, data)
        elif name.endswith(".exr"):
            write_rgb(path, data)
        else:
            raise ValueError(f"unknown asset type for {name!r}")


# ----------------------------------------------------------------------------------------------
# Scene assembly
# ----------------------------------------------------------------------------------------------

def _rgb(c) -> dict:
    return {"type": "rgb", "value": [float(x) for x in c]}


def _matrix(m: np.ndarray) -> list:
    return np.asarray(m, np.float64).tolist()


def _scale(sx, sy, sz) -> np.ndarray:
    return np.diag([sx, sy, sz, 1.0])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return rotation(axis, rng.uniform(0, 360))


def _reflectance(rng: np.random.Generator, bitmaps: list[str], uv_scale: float = 1.0) -> dict:
    """A reflectance texture: uniform colour, checkerboard (2-24 checks per uv unit), or one
    of the scene's noise bitmaps repeated 1-4 times per uv unit; ``uv_scale`` multiplies the
    frequency for large shapes (floor, walls) whose uv range spans many scene units."""
    r = rng.random()
    if r < 0.4:
        return _rgb(random_color(rng))
    freq = uv_scale * float(rng.uniform(2, 24) if r < 0.7 else rng.uniform(1, 4))
    to_uv = _matrix(_scale(freq, freq, 1.0) @ rotation((0, 0, 1), rng.uniform(0, 90)))
    if r < 0.7:
        return {"type": "checkerboard", "color0": _rgb(random_color(rng)),
                "color1": _rgb(random_color(rng)), "to_uv": to_uv}
    return {"type": "bitmap", "filename": bitmaps[int(rng.integers(len(bitmaps)))], "to_uv": to_uv}


def _material(rng: np.random.Generator, kind: str, bitmaps: list[str], uv_scale: float = 1.0) -> tuple[dict, dict]:
    """(Mitsuba bsdf dict, material record) for a material kind.  Everything but glass is
    two-sided, so open shapes (rectangles, disks, cylinders) look the same from both sides."""
    rec: dict = {"kind": kind}
    if kind == "diffuse":
        bsdf = {"type": "diffuse", "reflectance": _reflectance(rng, bitmaps, uv_scale)}
    elif kind in ("plastic", "roughplastic"):
        ior = float(rng.uniform(1.4, 1.7))
        bsdf = {"type": kind, "diffuse_reflectance": _reflectance(rng, bitmaps, uv_scale), "int_ior": ior,
                "ext_ior": 1.0, "nonlinear": bool(rng.random() < 0.5)}
        rec["ior"] = ior
        if kind == "roughplastic":
            alpha = float(rng.uniform(0.03, 0.5))
            bsdf.update(distribution="ggx", alpha=alpha)
            rec["alpha"] = alpha
    elif kind in ("conductor", "roughconductor"):
        metal = METALS[int(rng.integers(len(METALS)))]
        bsdf = {"type": kind, "material": metal}
        rec["metal"] = metal
        if rng.random() < 0.3:
            tint = random_color(rng, 0.5, 1.0)
            bsdf["specular_reflectance"] = _rgb(tint)
            rec["tint"] = tint
        if kind == "roughconductor":
            alpha = float(rng.uniform(0.03, 0.5))
            bsdf.update(distribution="ggx", alpha=alpha)
            rec["alpha"] = alpha
    elif kind == "dielectric":
        ior = float(rng.uniform(1.3, 1.8))
        return {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}, {"kind": kind, "ior": ior}
    else:
        raise ValueError(f"unknown material kind {kind!r}")
    return {"type": "twosided", "bsdf": bsdf}, rec


def _emitter_bsdf() -> dict:
    # Lights are black apart from their emission, so a sample on one has exactly its radiance.
    return {"type": "diffuse", "reflectance": _rgb([0.0, 0.0, 0.0])}


def scene_flags(seed: int, defocus: float, motion_blur: float) -> tuple[bool, bool]:
    """(thin lens?, motion blur?) for scene ``seed`` given the two probabilities, from a random
    stream of their own so the probabilities never change a scene's content."""
    flags = np.random.default_rng([seed, 1])
    return bool(flags.random() < defocus), bool(flags.random() < motion_blur)


def enclosed_flag(seed: int, enclosed: float) -> bool:
    """Whether scene ``seed`` becomes an enclosed room (:func:`enclose`), from a stream of its
    own, so that the probability never changes the rest of a scene."""
    return bool(np.random.default_rng([seed, 10]).random() < enclosed)


def enclose(objects: dict, materials: dict, bitmaps: list[str], path, frames: int, seed: int,
            glossy_floor: bool = True) -> None:
    """Close the scene into a room around its objects and the whole camera path (walls all
    round and a ceiling, so no sky is seen), lit mostly indirectly: the environment goes, a
    window opening in one wall lets in the light of a bright panel outside, a lamp stands
    behind an occluder near a corner, a row of thin bars stands inside the objects' reach of
    the camera, and the floor is often glossy. From a random stream of its own ([seed, 11]),
    after every other draw, so the objects and the camera path stay those of the open scene."""
    rng = np.random.default_rng([seed, 11])
    pos = np.array([path.position(u) for u in np.linspace(-1, frames + 1, 4 * frames + 9)])
    half = float(max(np.abs(pos[:, [0, 2]]).max(), OBJECT_RADIUS + 1.0) + rng.uniform(1.0, 2.5))
    height = float(max(pos[:, 1].max() + rng.uniform(1.0, 2.5), 3.5))
    for name in [k for k in objects if k.startswith(("wall_", "environment"))]:
        objects.pop(name)
        materials.pop(name, None)

    def rect(name, centre, normal, hw, hh, bsdf, rec, up=(0.0, 1.0, 0.0)):
        centre = np.asarray(centre, np.float64)
        objects[name] = {"type": "rectangle", "bsdf": bsdf,
                         "to_world": _matrix(look_at(centre, centre + np.asarray(normal), up) @ _scale(hw, hh, 1))}
        materials[name] = rec

    window_wall = int(rng.integers(4))
    for k in range(4):
        normal = np.array([(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0)][k], np.float64)
        centre = -normal * half + np.array([0.0, height / 2, 0.0])
        bsdf, rec = _material(rng, "diffuse" if rng.random() < 0.7 else "roughplastic", bitmaps, uv_scale=half / 2)
        if k != window_wall:
            rect(f"room_wall{k}", centre, normal, half, height / 2, bsdf, rec)
            continue
        # an opening in this wall: four panels around it, a bright panel outside
        along = look_at(centre, centre + normal)[:3, 0]
        w = float(rng.uniform(0.15, 0.35)) * half
        c = float(rng.uniform(-0.5, 0.5)) * (half - w)
        y0, y1 = float(rng.uniform(0.6, 1.2)), float(min(height - 0.4, rng.uniform(2.2, 3.2)))
        base = -normal * half
        for j, (a0, a1, b0, b1) in enumerate(((-half, half, 0.0, y0), (-half, half, y1, height),
                                              (-half, c - w, y0, y1), (c + w, half, y0, y1))):
            rect(f"room_wall{k}_{j}", base + along * (a0 + a1) / 2 + np.array([0, (b0 + b1) / 2, 0]), normal,
                 (a1 - a0) / 2, (b1 - b0) / 2, bsdf, rec)
        outside = base - normal * float(rng.uniform(2.0, 4.0)) + along * c + np.array([0, (y0 + y1) / 2, 0])
        radiance = np.array(random_color(rng, 0.7, 1.0)) * float(rng.uniform(5, 20))
        rect("room_window_light", outside, normal, 4 * w, 3 * (y1 - y0), _emitter_bsdf(), {"kind": "emitter"})
        objects["room_window_light"]["emitter"] = {"type": "area", "radiance": _rgb(radiance)}
    bsdf = {"type": "diffuse", "reflectance": _rgb(np.full(3, float(rng.uniform(0.6, 0.85))))}
    rect("room_ceiling", (0.0, height, 0.0), (0, -1, 0), half, half, bsdf, {"kind": "diffuse"}, up=(0.0, 0.0, 1.0))
    # a lamp behind an occluder, near a corner
    corner = np.array([rng.choice([-1, 1]) * (half - 0.6), 0.0, rng.choice([-1, 1]) * (half - 0.6)])
    lamp_r = float(rng.uniform(0.15, 0.35))
    lamp = corner + np.array([0.0, float(rng.uniform(0.5, 1.5)), 0.0])
    objects["room_lamp"] = {"type": "sphere", "center": lamp.tolist(), "radius": lamp_r, "bsdf": _emitter_bsdf(),
                            "emitter": {"type": "area", "radiance": _rgb(
                                np.array(random_color(rng, 0.8, 1.0)) * float(rng.uniform(5, 15)) * (0.3 / lamp_r) ** 2)}}
    materials["room_lamp"] = {"kind": "emitter"}
    towards = -corner / max(np.linalg.norm(corner), 1e-9)
    screen = corner + towards * (lamp_r + 0.5)
    size = np.array([0.8, lamp[1] + lamp_r + 0.4, 0.8])
    objects["room_occluder"] = {"type": "cube", "to_world": _matrix(
        translation(screen + np.array([0, size[1] / 2, 0])) @ _scale(*(size / 2)))}
    objects["room_occluder"]["bsdf"], materials["room_occluder"] = _material(rng, "diffuse", bitmaps)
    # thin bars: a railing between the objects and the camera's closest approach
    n_bars = int(rng.integers(4, 13))
    a = float(rng.uniform(0, 2 * math.pi))
    r = OBJECT_RADIUS + float(rng.uniform(0.3, 1.0))
    tangent = np.array([-math.sin(a), 0.0, math.cos(a)])
    start = np.array([r * math.cos(a), 0.0, r * math.sin(a)])
    gap, radius, tall = float(rng.uniform(0.15, 0.35)), float(rng.uniform(0.008, 0.03)), float(rng.uniform(0.8, 2.5))
    bsdf, rec = _material(rng, "roughconductor" if rng.random() < 0.6 else "diffuse", bitmaps)
    for i in range(n_bars):
        p = start + tangent * (i - n_bars / 2) * gap
        objects[f"room_bar{i:02d}"] = {"type": "cylinder", "bsdf": bsdf,
                                       "to_world": _matrix(translation(p) @ rotation((1, 0, 0), -90)
                                                           @ _scale(radius, radius, tall))}
        materials[f"room_bar{i:02d}"] = rec
    if glossy_floor and rng.random() < 0.5:
        alpha = float(rng.uniform(0.02, 0.15))
        objects["floor"]["bsdf"] = {"type": "twosided", "bsdf": {"type": "roughconductor", "material": "Ag",
                                                                 "distribution": "ggx", "alpha": alpha}}
        materials["floor"] = {"kind": "roughconductor", "metal": "Ag", "alpha": alpha}


def generate(seed: int, width: int, height: int, frames: int = 8, defocus: float = 0.5,
             motion_blur: float = 0.0, speed: float = 1.0, aperture_scale: float = 1.0,
             floor: str = "scene", enclosed: float = 0.0) -> SceneSpec:
    """The procedural scene for ``seed`` (any int >= 0), for a ``width`` x ``height`` film.

    ``frames`` bounds the camera path check (the camera stays above the floor and outside the
    objects' disc for u in [-1, frames + 1]).  ``defocus`` and ``motion_blur`` are the
    probabilities that the scene gets a thin lens / per-sample shutter times, drawn from a
    stream of their own so changing them never changes the scene content.  ``speed`` scales
    the camera's motion per frame (1: about 0.5-3° of rotation and up to 0.25 units of travel).
    ``aperture_scale`` multiplies the thin lens's aperture radius (stronger defocus) and
    ``floor`` (:data:`FLOOR_KINDS`) replaces the floor's material; both act after every random
    draw, so the rest of the scene stays the same. ``enclosed`` is the probability that the
    scene becomes an enclosed room lit mostly indirectly (:func:`enclose`; its own stream, also
    after every other draw).
    """
    if seed < 0:
        raise ValueError(f"scene seed must be >= 0, got {seed}")
    if floor not in FLOOR_KINDS:
        raise ValueError(f"floor must be one of {', '.join(FLOOR_KINDS)}, got {floor!r}")
    if not aperture_scale > 0:
        raise ValueError(f"aperture scale must be > 0, got {aperture_scale}")
    rng = np.random.default_rng([seed, 0])
    use_defocus, use_blur = scene_flags(seed, defocus, motion_blur)

    objects: dict = {}
    assets: dict = {}
    materials: dict = {}
    bitmaps = []
    for i in range(int(rng.integers(2, 4))):
        name = f"tex{i}.exr"
        assets[name] = noise_texture(rng)
        bitmaps.append(name)

    setting = "indoor" if rng.random() < 0.5 else "outdoor"
    azimuth = float(rng.uniform(0, 360))           # where the camera starts, seen from the centre
    back = -np.array([math.sin(math.radians(azimuth)), 0.0, math.cos(math.radians(azimuth))])
    side = np.array([-back[2], 0.0, back[0]])

    # floor: large enough to reach the horizon from every camera position
    floor_kind = "diffuse" if rng.random() < 0.6 else "roughplastic"
    bsdf, rec = _material(rng, floor_kind, bitmaps, uv_scale=20.0)
    if floor == "glossy":
        bsdf = {"type": "twosided", "bsdf": {"type": "roughconductor", "material": "Ag",
                                             "distribution": "ggx", "alpha": GLOSSY_FLOOR_ALPHA}}
        rec = {"kind": "roughconductor", "metal": "Ag", "alpha": GLOSSY_FLOOR_ALPHA}
    elif floor == "mirror":
        bsdf = {"type": "twosided", "bsdf": {"type": "conductor", "material": "Ag"}}
        rec = {"kind": "conductor", "metal": "Ag"}
    objects["floor"] = {"type": "rectangle", "bsdf": bsdf,
                        "to_world": _matrix(look_at((0, 0, 0), (0, 1, 0), up=(0, 0, 1)) @ _scale(40, 40, 1))}
    materials["floor"] = rec

    if setting == "indoor":
        dist = float(rng.uniform(5, 8))
        walls = [("wall_back", back * dist, -back, float(rng.uniform(8, 14)))]
        for sgn, nm in ((1, "wall_left"), (-1, "wall_right")):
            if rng.random() < 0.6:
                w_dist = float(rng.uniform(5, 8))
                walls.append((nm, side * sgn * w_dist + back * dist / 2, -side * sgn, dist))
        height_w = float(rng.uniform(3, 6))
        for nm, centre, normal, half_width in walls:
            c = np.array([centre[0], height_w, centre[2]])
            bsdf, rec = _material(rng, "diffuse" if rng.random() < 0.7 else "roughplastic", bitmaps,
                                  uv_scale=half_width / 2)
            objects[nm] = {"type": "rectangle", "bsdf": bsdf,
                           "to_world": _matrix(look_at(c, c + normal) @ _scale(half_width, height_w, 1))}
            materials[nm] = rec

    n_obj = int(rng.integers(8, 25))
    for i in range(n_obj):
        kind = SHAPE_KINDS[int(rng.choice(len(SHAPE_KINDS), p=SHAPE_WEIGHTS))]
        size = float(rng.uniform(0.25, 1.0))
        r = OBJECT_RADIUS * math.sqrt(rng.random())
        a = rng.uniform(0, 2 * math.pi)
        on_floor = rng.random() < 0.65
        y = size * rng.uniform(0.6, 1.0) if on_floor else size + float(rng.uniform(0, 2.0))
        pos = np.array([r * math.cos(a), y, r * math.sin(a)])
        rot = _random_rotation(rng)
        name = f"obj{i:02d}_{kind}"
        if kind == "sphere":
            shape = {"type": "sphere", "to_world": _matrix(translation(pos) @ _scale(size, size, size))}
        elif kind == "cube":
            s = size * rng.uniform(0.5, 1.0, 3) / math.sqrt(3) * 1.4
            shape = {"type": "cube", "to_world": _matrix(translation(pos) @ rot @ _scale(*s))}
        elif kind == "cylinder":
            rad, h = size * rng.uniform(0.3, 0.7), size * rng.uniform(1.0, 2.0)
            shape = {"type": "cylinder", "to_world": _matrix(
                translation(pos) @ rot @ _scale(rad, rad, h) @ translation((0, 0, -0.5)))}
        elif kind in ("rectangle", "disk"):
            s = size * rng.uniform(0.6, 1.2, 2)
            shape = {"type": kind, "to_world": _matrix(translation(pos) @ rot @ _scale(s[0], s[1], 1))}
        else:
            mesh = {"blob": blob_mesh, "torus": torus_mesh, "twisted": twisted_mesh}[kind](rng)
            fname = f"{name}.ply"
            assets[fname] = mesh
            shape = {"type": "ply", "filename": fname, "to_world": _matrix(translation(pos) @ rot @ _scale(size, size, size))}
        allowed = MATERIAL_KINDS if kind in CLOSED_SHAPES else MATERIAL_KINDS[:-1]
        w = np.array([MATERIAL_WEIGHTS[MATERIAL_KINDS.index(k)] for k in allowed])
        mkind = allowed[int(rng.choice(len(allowed), p=w / w.sum()))]
        shape["bsdf"], materials[name] = _material(rng, mkind, bitmaps)
        objects[name] = shape

    centre = np.array([0.0, float(rng.uniform(0.3, 1.2)), 0.0])

    # lights
    n_emissive_spheres = int(rng.random() < 0.35) + int(rng.random() < 0.15)
    if setting == "outdoor":
        assets["sky.exr"] = sky_texture(rng)
        objects["environment"] = {"type": "envmap", "filename": "sky.exr", "scale": float(rng.uniform(0.5, 2.0)),
                                  "to_world": _matrix(rotation((0, 1, 0), rng.uniform(0, 360)))}
        n_area, n_point = int(rng.random() < 0.2), int(rng.random() < 0.3)
    else:
        if rng.random() < 0.5:
            objects["environment"] = {"type": "constant", "radiance": _rgb(np.array(random_color(rng, 0.6, 1.0)) * rng.uniform(0.05, 0.4))}
        else:
            assets["sky.exr"] = sky_texture(rng)
            objects["environment"] = {"type": "envmap", "filename": "sky.exr", "scale": float(rng.uniform(0.1, 0.4))}
        n_area, n_point = int(rng.integers(1, 4)), int(rng.integers(0, 3))
    for i in range(n_area):
        p = np.array([rng.uniform(-4, 4), rng.uniform(3, 5.5), rng.uniform(-4, 4)])
        aim = centre + rng.normal(size=3) * np.array([1.5, 0.3, 1.5])
        s = rng.uniform(0.3, 1.2, 2)
        radiance = np.array(random_color(rng, 0.8, 1.0)) * rng.uniform(3, 20) / (s[0] * s[1])
        objects[f"light{i}_area"] = {"type": "rectangle", "to_world": _matrix(look_at(p, aim) @ _scale(s[0], s[1], 1)),
                                     "emitter": {"type": "area", "radiance": _rgb(radiance)}, "bsdf": _emitter_bsdf()}
        materials[f"light{i}_area"] = {"kind": "emitter"}
    for i in range(n_emissive_spheres):
        r = OBJECT_RADIUS * math.sqrt(rng.random())
        a = rng.uniform(0, 2 * math.pi)
        rad = float(rng.uniform(0.08, 0.3))
        pos = [r * math.cos(a), float(rng.uniform(rad, 2.5)), r * math.sin(a)]
        radiance = np.array(random_color(rng, 0.8, 1.0)) * rng.uniform(2, 12) * (0.2 / rad) ** 2
        objects[f"light{i}_sphere"] = {"type": "sphere", "center": pos, "radius": rad,
                                       "emitter": {"type": "area", "radiance": _rgb(radiance)}, "bsdf": _emitter_bsdf()}
        materials[f"light{i}_sphere"] = {"kind": "emitter"}
    for i in range(n_point):
        p = [float(rng.uniform(-4, 4)), float(rng.uniform(1, 5)), float(rng.uniform(-4, 4))]
        objects[f"light{i}_point"] = {"type": "point", "position": p,
                                      "intensity": _rgb(np.array(random_color(rng, 0.8, 1.0)) * rng.uniform(5, 40))}

    # camera
    x_fov = float(rng.uniform(30, 70))
    path = _fly_through(rng, centre, azimuth, frames, speed)
    obj_names = [k for k in objects if k.startswith("obj")]
    focus_obj = objects[obj_names[int(rng.integers(len(obj_names)))]]
    focus_point = np.asarray(focus_obj["to_world"])[:3, 3]
    cam0 = path.to_world(0.0)
    focus = float(max((focus_point - cam0[:3, 3]) @ cam0[:3, 2], 1.0))
    aperture = float(rng.uniform(0.02, 0.15) * focus / 7.0) * aperture_scale
    intr = Intrinsics(width, height, x_fov, aperture_radius=aperture if use_defocus else 0.0,
                      focus_distance=focus, near_clip=0.01, far_clip=1000.0)
    if enclosed_flag(seed, enclosed):
        enclose(objects, materials, bitmaps, path, frames, seed, glossy_floor=floor == "scene")
        setting = "enclosed"
        assets.pop("sky.exr", None)
    return SceneSpec(seed=seed, name=scene_name(seed), objects=objects, assets=assets, intrinsics=intr,
                     path=path, materials=materials, defocus=use_defocus, motion_blur=use_blur,
                     setting=setting)


def _fly_through(rng: np.random.Generator, centre: np.ndarray, azimuth: float, frames: int,
                 speed: float) -> FlyThrough:
    """A random fly-through starting at ``azimuth`` that stays above the floor and out of the
    objects' disc for u in [-1, frames + 1]."""
    sgn = 1.0 if rng.random() < 0.5 else -1.0
    radius = float(rng.uniform(5.5, 8.5))
    elevation = float(rng.uniform(8.0, 35.0))
    omega = sgn * float(rng.uniform(0.5, 3.0)) * speed
    radial = float(rng.uniform(-0.25, 0.25)) * speed
    rise = float(rng.uniform(-0.06, 0.06)) * speed
    target = centre + rng.normal(size=3) * np.array([0.6, 0.2, 0.6])
    drift = rng.normal(size=3) * np.array([1.0, 0.2, 1.0])
    drift *= float(rng.uniform(0.0, 0.12)) * speed / max(np.linalg.norm(drift), 1e-9)
    # objects reach 1.0 beyond OBJECT_RADIUS; at the steepest elevation (35°) this keeps the
    # camera's horizontal distance above 4.2
    lo = OBJECT_RADIUS + 2.2
    path = FlyThrough(center=tuple(centre), radius=radius, elevation=elevation, azimuth=azimuth,
                      omega=omega, radial=radial, rise=rise, target=tuple(target), drift=tuple(drift),
                      radius_range=(lo, 10.0))
    lowest = min(path.position(u)[1] for u in np.linspace(-1, frames + 1, 4 * frames + 9))
    if lowest < 0.4:  # rising instead of sinking keeps the camera above the floor
        path = FlyThrough(**{**path.__dict__, "rise": abs(rise)})
    return path


def scene_description(spec: SceneSpec, to_world, spp: int = 1) -> dict:
    """The complete JSON-able Mitsuba scene dict: integrator, the sensor at ``to_world``
    (4x4 list) and the scene's objects."""
    return {"type": "scene",
            "integrator": {"type": "path", "max_depth": MAX_DEPTH},
            "sensor": spec.intrinsics.sensor_dict(_matrix(to_world), spp),
            **spec.objects}
