"""Seconds per ANF training step with the kernels' taps run eagerly (what training does) or as
TorchScript (what it did before 2026-12-06), on one machine in one run, alternating:

    python docs/results/anf-demod/step_time.py --data data/curves-test --steps 4 --threads 2

Each trains anf-sd from scratch for --steps steps of its spec's [train] (batch 4 of 8-frame
windows, 64x64 crops, S from 1-8) into a temporary folder; prints the training loop's elapsed
seconds over steps (the frames are decoded in the first steps, alike in both)."""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from mcdenoise.training import runs
from mcdenoise.training.models import anf
from mcdenoise.training.train import train


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--spec", default="anf-sd")
    p.add_argument("--steps", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=1)
    a = p.parse_args()
    eager = anf.affinity_sums_eager
    for r in range(a.repeats):
        for mode in ("script", "eager"):
            anf.affinity_sums_eager = anf.affinity_sums if mode == "script" else eager
            with tempfile.TemporaryDirectory() as tmp:
                train(a.spec, a.data, str(Path(tmp) / "run"), steps=a.steps, threads=a.threads, quiet=True,
                      val_every=10 ** 9)
                rows = [json.loads(x) for x in (Path(tmp) / "run" / runs.METRICS_FILE).read_text().splitlines()]
            print(f"{mode}: {rows[-1]['elapsed_s'] / a.steps:.1f} s a step ({a.steps} steps, {a.threads} threads)", flush=True)
    anf.affinity_sums_eager = eager


if __name__ == "__main__":
    main()
