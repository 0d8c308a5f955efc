"""Give a run folder trained before `train --precise-bn` BatchNorm statistics estimated afresh.

    python docs/results/scale/recalibrate.py RUN OUT [--data DIR] [--windows N]

Copies RUN to OUT and stores in OUT's checkpoint the statistics of
:func:`mcdenoise.training.train.precise_bn` over N windows (default: a new run's) drawn as RUN's
training drew them (its crop, spp, window and seed) from the training split of DIR (default:
RUN's own data folder). `mcdenoise export OUT` then ships them; RUN is left as it was. Why:
mr-e sitting 4's last batches left its first layer's running variance 12-23x sitting 3's
(README, "mr-e sitting 4").
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import torch

from mcdenoise.training import runs
from mcdenoise.training.train import BN_STATS, PRECISE_BN_WINDOWS, _datasets, precise_bn


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("out")
    p.add_argument("--data", default=None, help="folder of training sequences (default: the run's)")
    p.add_argument("--windows", type=int, default=PRECISE_BN_WINDOWS)
    a = p.parse_args(argv)
    src, out = Path(a.run), Path(a.out)
    if out.exists():
        print(f"recalibrate: {out} exists; give a new folder", file=sys.stderr)
        return 2
    spec, model, _ = runs.load_run(src)
    config = json.loads((src / runs.CONFIG_FILE).read_text())
    if a.data:
        config["data"] = a.data
    train_set = _datasets({**config, "test_data": None}, spec, config.get("cache_dtype", "float32"))[0]
    net = precise_bn(model, train_set, spec.protocol, a.windows, config["batch_size"])
    # the scores in RUN are of its own statistics: OUT gets its own from the same commands
    shutil.copytree(src, out, ignore=shutil.ignore_patterns("*curves-test*.json"))
    ckpt = torch.load(out / runs.CHECKPOINT_FILE, weights_only=False)
    ckpt["bn"] = {k: v.detach().clone() for k, v in net.state_dict().items() if k.endswith(BN_STATS)}
    runs.save_checkpoint(out, ckpt)
    (out / "recalibrated.json").write_text(json.dumps(
        {"from": str(src), "data": config["data"], "windows": a.windows,
         "sequences": len(train_set.seqs)}, indent=1) + "\n")
    print(f"{out}: BatchNorm statistics over {a.windows} windows of {len(train_set.seqs)} training sequences in {config['data']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
