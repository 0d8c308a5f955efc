"""The scale sittings as one learning curve: each run's scores against the steps and scenes its
chain had seen when it ended, beside Open Image Denoise high (issue 15: "the learning curve says
what more budget would buy").

    python docs/results/scale/chain.py    # writes chain.md and chain.png beside this file

A sitting's run starts from the one before (``train --init``), so a run's *chain steps* are its
own final step plus the chain steps of its source (config.json ``init.chain_steps``), and its
*chain scenes* the distinct scene seeds of every data set on the way (data.json, written by
sitting.sh; training and validation splits together, as data.json records them). Scores: the
run's own curves-test evaluation (sitting.sh) and, where docs/results/long/eval.sh scored it, the
hand-made room ``heldout-room_window``, both at 1 and 4 spp after warm-up, with history.
Run folders are read here and in docs/results/mr (the A/B arms that start the wskpn-mr-e chain),
and every spec's longest chain is charted. Every number is read from committed files; nothing is
trained or evaluated here."""
import json
import math
from pathlib import Path

HERE = Path(__file__).resolve().parent
LONG = HERE.parent / "long"
#: where run folders are read from: the sittings here, and the multi-resolution A/B's arms
#: (docs/results/mr), which started the wskpn-mr-e chain
ROOTS = (HERE, HERE.parent / "mr")
#: the held-out hand-made scene the chart shows beside curves-test (docs/results/long)
ROOM = "heldout-room_window"
SPPS = (1, 4)


def _after_warmup(path: Path, method: str | None = None) -> dict | None:
    """The after-warm-up scores of ``method`` (default: the file's one model) in an ``mcdenoise
    evaluate --json`` file, or None where the file is missing."""
    if not path.exists():
        return None
    d = json.loads(path.read_text())
    if method is None:
        names = [m for m in d if m not in ("_setup", "noisy") and "(no history)" not in m]
        if len(names) != 1:
            raise ValueError(f"{path}: expected one model, found {names}")
        method = names[0]
    return d[method]["after_warmup"]


def runs() -> list[dict]:
    """Every run folder here whose config has a final metrics row, with its chain position."""
    by_path: dict[str, dict] = {}
    for cfg_path in sorted(p for root in ROOTS for p in root.glob("*/config.json")):
        run = cfg_path.parent
        rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if x.strip()] \
            if (run / "metrics.jsonl").exists() else []
        if not rows or not rows[-1].get("final"):
            continue
        cfg = json.loads(cfg_path.read_text())
        data = json.loads((run / "data.json").read_text()) if (run / "data.json").exists() else {}
        if run.name in by_path:     # --init names its source by folder name
            raise ValueError(f"two run folders are named {run.name}: {by_path[run.name]['dir']} and {run}")
        by_path[run.name] = {"name": run.name, "dir": run, "spec": cfg["spec"], "steps": rows[-1]["step"],
                             "init": Path(cfg["init"]["run"]).name if cfg.get("init") else None,
                             "seeds": set(data.get("scene_seeds", []))}
    for r in by_path.values():
        chain, seen, node = [], set(), r
        while node is not None and node["name"] not in seen:     # a loop would be a broken record
            seen.add(node["name"])
            chain.append(node)
            node = by_path.get(node["init"]) if node["init"] else None
        r["chain"] = [n["name"] for n in reversed(chain)]
        r["label"] = r["name"] if r["dir"].parent == HERE else f"{r['dir'].parent.name}/{r['name']}"
        r["chain_steps"] = sum(n["steps"] for n in chain)
        r["chain_scenes"] = len(set().union(*(n["seeds"] for n in chain)))
        for spp in SPPS:
            r[f"curves_{spp}"] = _after_warmup(run_dir(r) / f"curves-test-{spp}spp.json")
            # eval.sh's file, else the run's own (the mr A/B scored its arms into their folders)
            room = LONG / ROOM / f"{r['name']}-{spp}spp.json"
            r[f"room_{spp}"] = _after_warmup(room if room.exists() else run_dir(r) / f"{ROOM}-{spp}spp.json")
    return sorted(by_path.values(), key=lambda r: r["chain_steps"])


def run_dir(r: dict) -> Path:
    return r["dir"]


def oidn() -> dict:
    """Open Image Denoise high's after-warm-up scores: curves-test (baseline.sh) and the room."""
    out = {}
    for spp in SPPS:
        out[f"curves_{spp}"] = _after_warmup(HERE / "baseline" / f"curves-test-{spp}spp.json", "oidn-high")
        out[f"room_{spp}"] = _after_warmup(LONG / ROOM / f"baseline-{spp}spp.json", "oidn-high")
    return out


def _cell(s: dict | None, key: str, fmt: str) -> str:
    return "-" if s is None else format(s[key], fmt)


def markdown(rs: list[dict], ref: dict) -> str:
    lines = ["# The scale chain as a learning curve", "",
             "Written by `python docs/results/scale/chain.py` from the committed run folders and evaluations "
             "(module docstring). Chain steps and scenes: what the run's chain of `--init` sittings had trained on "
             "when it ended (scenes: distinct scene seeds, training and validation splits). PSNR dB / TRMAE after "
             f"warm-up, with history: curves-test (procedural, 128x128) and {ROOM} (hand-made, never trained on).", "",
             "| run | chain | chain steps | chain scenes | curves 1 spp | curves 4 spp | room 1 spp | room 4 spp |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rs:
        cells = [f"{_cell(r[f'{k}_{spp}'], 'psnr', '.2f')} / {_cell(r[f'{k}_{spp}'], 'trmae', '.3f')}"
                 for k in ("curves", "room") for spp in SPPS]
        lines.append(f"| {r['label']} | {' → '.join(r['chain'])} | {r['chain_steps']} | {r['chain_scenes']} | "
                     + " | ".join(cells) + " |")
    cells = [f"{_cell(ref[f'{k}_{spp}'], 'psnr', '.2f')} / {_cell(ref[f'{k}_{spp}'], 'trmae', '.3f')}"
             for k in ("curves", "room") for spp in SPPS]
    lines.append("| oidn-high | - | - | - | " + " | ".join(cells) + " |")
    for chain in main_chains(rs):
        lines += ["", f"What the {chain[-1]['spec']} chain ({' → '.join(r['name'] for r in chain)}) bought, first to "
                  "last scored run (a rate read off two ends of a noisy chain, not a law):", ""]
        for k in ("curves", "room"):
            for spp in SPPS:
                t = trend(chain, f"{k}_{spp}", ref[f"{k}_{spp}"])
                if t:
                    lines.append(f"- {k} {spp} spp: {t}")
    lines += ["", "![chain](chain.png)"]
    return "\n".join(lines) + "\n"


def main_chains(rs: list[dict]) -> list[list[dict]]:
    """Per spec, the runs of its longest chain (the ancestry of its run with the most chain
    steps), in order; only chains of two runs or more, the longest first."""
    by_name = {r["name"]: r for r in rs}
    out = []
    for spec in {r["spec"] for r in rs}:
        last = max((r for r in rs if r["spec"] == spec), key=lambda r: r["chain_steps"])
        if len(last["chain"]) > 1:
            out.append([by_name[n] for n in last["chain"]])
    return sorted(out, key=lambda c: -c[-1]["chain_steps"])


def trend(chain: list[dict], key: str, ref: dict | None) -> str:
    """What the chain bought from its first to its last scored run: dB per doubling of chain
    steps, and, at that rate, how many more doublings the gap to Open Image Denoise high
    (``ref``, after-warm-up scores) needs. A rate read off two ends of a noisy chain, not a
    law: the next sittings test it."""
    pts = [r for r in chain if r[key] is not None]
    if len(pts) < 2:
        return ""
    a, b = pts[0], pts[-1]
    doublings = math.log2(b["chain_steps"] / a["chain_steps"])
    gain = b[key]["psnr"] - a[key]["psnr"]
    rate = gain / doublings
    text = f"{a['name']} → {b['name']}: {gain:+.2f} dB over {doublings:.1f} doublings of chain steps " \
           f"({rate:+.2f} dB a doubling)"
    if ref is not None:
        gap = ref["psnr"] - b[key]["psnr"]
        text += f"; {gap:.2f} dB below oidn-high"
        if gap > 0 and rate > 0:
            text += f", {gap / rate:.0f} more doublings ({2 ** (gap / rate):.0f}x the steps) at that rate"
    return text


def chart(rs: list[dict], ref: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chains = main_chains(rs)
    on_chain = {r["name"] for c in chains for r in c}
    others = [r for r in rs if r["name"] not in on_chain and r["spec"] in {c[-1]["spec"] for c in chains}]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, key, title in ((axes[0], "curves", "curves-test (procedural, held out)"),
                           (axes[1], "room", f"{ROOM} (hand-made, held out)")):
        for spp, colour in zip(SPPS, ("tab:blue", "tab:orange")):
            for chain, style in zip(chains, ("o-", "s--", "^:")):
                spec = chain[-1]["spec"]
                pts = [(r["chain_steps"], r[f"{key}_{spp}"]["psnr"], r["name"]) for r in chain
                       if r[f"{key}_{spp}"] is not None]
                if pts:
                    xs, ys, names = zip(*pts)
                    ax.plot(xs, ys, style, color=colour, label=f"{spec} chain, {spp} spp")
                    for x, y, n in zip(xs, ys, names):
                        ax.annotate(n.replace(spec + "-", ""), (x, y), textcoords="offset points",
                                    xytext=(3, 3), fontsize=7)
            side = [(r["chain_steps"], r[f"{key}_{spp}"]["psnr"]) for r in others if r[f"{key}_{spp}"] is not None]
            if side:
                ax.plot(*zip(*side), "o", mfc="none", color=colour, label=f"runs off the chains, {spp} spp")
            if ref[f"{key}_{spp}"] is not None:
                ax.axhline(ref[f"{key}_{spp}"]["psnr"], color=colour, ls="--", lw=1, label=f"oidn-high, {spp} spp")
        ax.set_xlabel("chain steps (batch 8, 8-frame windows)")
        ax.set_ylabel("PSNR dB after warm-up")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    rs, ref = runs(), oidn()
    (HERE / "chain.md").write_text(markdown(rs, ref))
    chart(rs, ref, HERE / "chain.png")


if __name__ == "__main__":
    main()
