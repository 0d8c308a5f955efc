"""Shared fixtures.

``tiny_dataset``: 2 procedural scenes x 3 frames at 64x64, 4 spp, 64 reference spp, rendered
once per session by ``mcdenoise render`` in a subprocess (so Dr.Jit's LLVM set-up never
depends on what the test process imported first).  ``MCDENOISE_TEST_VARIANT`` (auto,
llvm_ad_rgb, scalar_rgb) picks the Mitsuba variant; without Mitsuba the fixture fails.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The command line of the tiny dataset; tests may rely on every value here.
TINY_ARGS = ("--scenes", "2", "--frames", "3", "--spp", "4", "--ref-spp", "64", "--size", "64x64",
             "--seed", "0", "--defocus", "off", "--camera-speed", "3")


def render_variant() -> str:
    """The Mitsuba variant the render tests ask for (auto unless MCDENOISE_TEST_VARIANT says)."""
    return os.environ.get("MCDENOISE_TEST_VARIANT", "auto")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> str:
    """Folder of the tiny rendered dataset (see module docstring)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError as e:  # a missing renderer is an install error, never a silent skip
        raise RuntimeError("the tests render data: pip install -e '.[all]' (Mitsuba 3)") from e
    out = str(tmp_path_factory.mktemp("tiny") / "data")
    cmd = [sys.executable, "-m", "mcdenoise.runtime.cli", "render", "--out", out, *TINY_ARGS, "--variant", render_variant()]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"tiny render failed ({' '.join(cmd)}):\n{proc.stderr[-4000:]}")
    return out


# MCDENOISE_TEST_MEMORY=1 python -m pytest: after the run, the tests that raised the peak
# resident memory of the test process (or of any one child it ran) by over 100 MB, largest
# first. CI runs the suite on small machines; this finds what to make smaller.
_MEMORY = os.environ.get("MCDENOISE_TEST_MEMORY") == "1"
_peaks: list[tuple[float, str]] = []


def _maxrss_mb() -> tuple[float, float]:
    import resource

    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not _MEMORY:
        yield
        return
    before = _maxrss_mb()
    yield
    after = _maxrss_mb()
    for kind, b, a in (("self", before[0], after[0]), ("child", before[1], after[1])):
        if a - b > 100:
            _peaks.append((a - b, f"{item.nodeid} ({kind}: peak {a:.0f} MB, +{a - b:.0f})"))


def pytest_terminal_summary(terminalreporter):
    if _MEMORY:
        terminalreporter.write_line("tests that raised the peak resident memory by over 100 MB:")
        for _, line in sorted(_peaks, reverse=True):
            terminalreporter.write_line("  " + line)
