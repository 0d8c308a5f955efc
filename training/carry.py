"""Wheels to carry to a machine without network (a lent GPU host has torch, onnx and numpy,
but not Mitsuba, OpenEXR or tqdm), small enough for its carry limit.

    python -m mcdenoise.training.carry --out .gpu/wheels     # here, where PyPI is reachable

Downloads the wheels (no dependencies: the host has numpy) for this Python, and strips
Mitsuba's wheel to the variants given (default: cuda_ad_rgb, for rendering on the GPU, and
scalar_rgb), dropping the others' modules from the archive and from its RECORD; what is left
installs with ``pip install --no-index --no-deps``. Mitsuba 3.9.1 is 62.7 MB whole.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import zipfile
from pathlib import Path

#: What the render and train commands need beyond torch, onnx and numpy.
PACKAGES = ("mitsuba", "drjit", "OpenEXR", "tqdm")
KEEP_VARIANTS = ("cuda_ad_rgb", "scalar_rgb")
#: A variant module inside the Mitsuba wheel: mitsuba/<variant>.cpython-....so
_VARIANT_MODULE = re.compile(r"^mitsuba/((?:scalar|llvm|cuda)_[a-z_]+)\.cpython-[^/]*\.so$")


def strip_wheel(src: Path, dst: Path, keep=KEEP_VARIANTS) -> list[str]:
    """Copy the Mitsuba wheel ``src`` to ``dst`` without the variant modules not in ``keep``
    (and their RECORD lines). Returns the variants dropped."""
    dropped, names = set(), set()
    with zipfile.ZipFile(src) as zin:
        for info in zin.infolist():
            m = _VARIANT_MODULE.match(info.filename)
            if m and m.group(1) not in keep:
                dropped.add(m.group(1))
                names.add(info.filename)
        with zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                if info.filename in names:
                    continue
                data = zin.read(info.filename)
                if info.filename.endswith(".dist-info/RECORD"):
                    data = "".join(line for line in data.decode().splitlines(keepends=True)
                                   if line.split(",")[0] not in names).encode()
                zout.writestr(info, data)
    return sorted(dropped)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m mcdenoise.training.carry", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for the wheels")
    p.add_argument("--variants", nargs="+", default=list(KEEP_VARIANTS), help="Mitsuba variants to keep")
    a = p.parse_args(argv)
    out = Path(a.out)
    raw = out / "download"
    raw.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "-d", str(raw), *PACKAGES], check=True)
    for whl in sorted(raw.glob("*.whl")):
        target = out / whl.name
        if whl.name.startswith("mitsuba-"):
            dropped = strip_wheel(whl, target, a.variants)
            print(f"{target.name}: {whl.stat().st_size / 1e6:.1f} -> {target.stat().st_size / 1e6:.1f} MB "
                  f"(dropped {', '.join(dropped)})")
        else:
            target.write_bytes(whl.read_bytes())
            print(f"{target.name}: {target.stat().st_size / 1e6:.1f} MB")
    total = sum(w.stat().st_size for w in out.glob("*.whl"))
    print(f"{total / 1e6:.1f} MB in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
