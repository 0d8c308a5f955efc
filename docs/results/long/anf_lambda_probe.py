"""Which part of anf-s's history lags at 4 spp: the accumulation weight λ (Eq. 3, 5) or the
temporal kernel on the previous output (Eq. 7, 8)?  No retraining: the shipped run is exported
again with the U-Net's λ and temporal-bandwidth outputs overridden before the kernels read them,
and every variant is scored through the runtime driver like the long table (PSNR after 8 warm-up
frames, TRMAE, WTE).

    python docs/results/long/anf_lambda_probe.py > docs/results/long/anf_lambda_probe.txt

Variants: ``base`` (the run as trained, without the spp bound that models/anf-s.onnx has carried
since; docs/results/anf-history), ``cap-C`` (λ <= C), ``no-temporal-kernel`` (temporal bandwidth
so large that every temporal tap's affinity is exp(-AFFINITY_BOUND)), ``no-accumulation`` (λ = 0,
temporal kernel kept), and ``reset`` (the shipped model reset before every frame).
"""
import json
import math
import sys
import tempfile
from pathlib import Path

import torch

from mcdenoise.export.onnx_export import export_model
from mcdenoise.training.evaluate import evaluate
from mcdenoise.training.methods import WithoutHistory
from mcdenoise.training.models import anf
from mcdenoise.training.runs import load_run

RUN = "docs/results/anf/run"
SETS = ["data/heldout-room_window", "data/heldout-lamp_occluder"]
CAPS = [0.8, 0.6, 0.4, 0.25]


def variant(lam_logit_max: float | None = None, lam_zero: bool = False, no_tkernel: bool = False):
    """A Kernels.forward that overrides the U-Net's last two channels (λ logit, sqrt bandwidth)."""
    original = anf.Kernels.forward

    def forward(self, params, *rest):
        p = params
        if lam_logit_max is not None or lam_zero or no_tkernel:
            p = params.clone()
            if lam_logit_max is not None:
                p[:, -1:] = torch.clamp(p[:, -1:], max=lam_logit_max)
            if lam_zero:
                p[:, -1:] = -60.0
            if no_tkernel:
                p[:, -2:-1] = 1e4    # b = x² = 1e8: every affinity hits the bound
        return original(self, p, *rest)
    return forward


def main() -> int:
    spp_list = [int(a) for a in sys.argv[1:]] or [4, 1]
    variants = {"base": {}, **{f"cap-{c}": {"lam_logit_max": math.log(c / (1 - c))} for c in CAPS},
                "no-temporal-kernel": {"no_tkernel": True}, "no-accumulation": {"lam_zero": True}}
    tmp = Path(tempfile.mkdtemp())
    files = []
    original = anf.Kernels.forward
    for name, kw in variants.items():
        spec, model, _ = load_run(RUN)
        anf.Kernels.forward = variant(**kw)
        try:
            export_model(spec, model, tmp / f"anf-s-{name}.onnx")
        finally:
            anf.Kernels.forward = original
        files.append(str(tmp / f"anf-s-{name}.onnx"))
    quiet = lambda *a, **k: None  # noqa: E731
    rows = {}
    for data in SETS:
        for spp in spp_list:
            for name, f in zip(variants, files):
                # methods are named by their spec, so each variant is its own evaluation
                r = evaluate([f], data, spp=spp, oidn=False, warmup=8, log=quiet,
                             no_history=name == "base")
                for m, v in r.items():
                    if m.startswith("_") or m == "noisy":
                        continue
                    w = v["after_warmup"]
                    label = "reset" if WithoutHistory.SUFFIX in m else name
                    rows[(Path(data).name, spp, label)] = (w["psnr"], w["trmae"], w["wte"], v["psnr"])
                    print(Path(data).name, spp, label, rows[(Path(data).name, spp, label)],
                          file=sys.stderr, flush=True)
    print("set | spp | variant | PSNR after warm-up | TRMAE | WTE | PSNR all frames")
    for (data, spp, m), (p, t, e, pa) in rows.items():
        print(f"{data} | {spp} | {m} | {p:.2f} | {t:.3f} | {e:.3f} | {pa:.2f}")
    json.dump({" ".join(map(str, k)): v for k, v in rows.items()},
              open("docs/results/long/anf_lambda_probe.json", "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
