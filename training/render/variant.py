"""Choosing and initialising the Mitsuba variant.

``llvm_ad_rgb`` renders 5-30x faster than ``scalar_rgb`` here, but Dr.Jit 1.x crashes with
LLVM <= 15, the version many distributions ship as ``libLLVM.so``.  Dr.Jit loads LLVM lazily
on the first use of an LLVM variant and honours ``DRJIT_LIBLLVM_PATH``, so we look for an
LLVM >= 16 shared library and point the variable at it before Mitsuba touches the backend.
"""
from __future__ import annotations

import glob
import os
import re
import sys

VARIANTS = ("auto", "llvm_ad_rgb", "scalar_rgb", "cuda_ad_rgb")
#: Oldest LLVM major version Dr.Jit 1.x runs with (15 segfaults in the first kernel launch).
MIN_LLVM = 16
_ENV = "DRJIT_LIBLLVM_PATH"
_SEARCH = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/local/opt/llvm/lib/libLLVM.dylib",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
)


def llvm_major(path: str) -> int | None:
    """LLVM major version from a library path, e.g. ``libLLVM-19.so`` or ``libLLVM.so.19.1``
    or ``/usr/lib/llvm-17/lib/libLLVM.so`` -> 19, 19, 17; None when the name does not say."""
    name = os.path.basename(path)
    m = re.match(r"libLLVM-(\d+)", name) or re.match(r"libLLVM\.so\.(\d+)", name)
    if m is None:
        m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_llvm(patterns=_SEARCH) -> tuple[str, int] | None:
    """The newest LLVM >= MIN_LLVM shared library on the usual paths, as (path, major)."""
    found = []
    for pattern in patterns:
        for path in glob.glob(pattern):
            major = llvm_major(path)
            if major is not None and major >= MIN_LLVM and os.path.isfile(path):
                found.append((major, len(path), path))
    if not found:
        return None
    major, _, path = max(found, key=lambda f: (f[0], -f[1]))  # newest; shortest name on ties
    return path, major


def choose_variant(requested: str = "auto") -> tuple[str, str]:
    """Resolve ``requested`` (auto | llvm_ad_rgb | scalar_rgb | cuda_ad_rgb) to a variant and a
    reason; auto never picks CUDA (a GPU host renders with it when asked).

    Sets ``DRJIT_LIBLLVM_PATH`` when an LLVM variant is chosen and the variable is unset.
    Raises ValueError for an unknown name, or for llvm_ad_rgb without a usable LLVM.
    """
    if requested not in VARIANTS:
        raise ValueError(f"unknown variant {requested!r}; choose one of {', '.join(VARIANTS)}")
    if requested in ("scalar_rgb", "cuda_ad_rgb"):   # cuda_ad_rgb: an NVIDIA GPU and its driver
        return requested, "requested with --variant"
    env = os.environ.get(_ENV)
    if env:
        major = llvm_major(env)
        if major is not None and major < MIN_LLVM:
            msg = f"{_ENV}={env} is LLVM {major}; Dr.Jit needs LLVM >= {MIN_LLVM}"
            if requested == "llvm_ad_rgb":
                raise ValueError(msg)
            return "scalar_rgb", msg
        return "llvm_ad_rgb", f"{_ENV}={env} is set" + (
            " (requested with --variant)" if requested == "llvm_ad_rgb" else "")
    hit = find_llvm()
    if hit is None:
        msg = (f"no LLVM >= {MIN_LLVM} shared library found (searched {', '.join(_SEARCH[:3])}, ...); "
               f"install one or set {_ENV}")
        if requested == "llvm_ad_rgb":
            raise ValueError(f"llvm_ad_rgb unavailable: {msg}")
        return "scalar_rgb", msg
    path, major = hit
    os.environ[_ENV] = path
    return "llvm_ad_rgb", f"found LLVM {major} at {path} (set {_ENV})"


def init_mitsuba(variant: str):
    """Import Mitsuba, set ``variant`` and return the ``mitsuba`` module.

    Raises ValueError when Mitsuba lacks the variant or cannot initialise it.
    """
    try:
        import mitsuba as mi
    except ModuleNotFoundError:
        raise ValueError("rendering needs Mitsuba 3: pip install 'mitsuba>=3.5'") from None
    if variant not in mi.variants():
        raise ValueError(f"this Mitsuba build has no variant {variant!r} (has {', '.join(mi.variants())})")
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as e:  # Mitsuba raises ImportError/RuntimeError with the backend's message
            raise ValueError(f"cannot initialise Mitsuba variant {variant}: {e}") from None
    return mi


def announce(variant: str, reason: str) -> None:
    """Say on stderr which variant renders and why."""
    print(f"mcdenoise render: Mitsuba variant {variant} ({reason})", file=sys.stderr)
