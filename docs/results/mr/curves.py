"""The multi-resolution A/B (ab.sh) as a table and a chart: both arms' validation scores against
steps (their learning curves, from metrics.jsonl) and their final evaluations.

    python docs/results/mr/curves.py    # writes curves.md and curves.png beside this file

Validation: the run's own split of data/train-256 (scene seeds held out by the seed hash) and
data/curves-test (``train --test``), centre crops, all stored spp, PSNR dB. Final evaluations:
``mcdenoise evaluate`` files written by ab.sh (sequences after warm-up with history; stills, the
first frames). Every number is read from committed files; nothing is trained or evaluated here."""
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
ARMS = ("wskpn-6e", "wskpn-mr-e")
SETS = ("heldout-room_window", "heldout-lamp_occluder", "long-slow")


def rows(arm: str) -> list[dict]:
    return [json.loads(line) for line in (HERE / arm / "metrics.jsonl").read_text().splitlines() if line.strip()]


def score(arm: str, name: str, stills: bool = False) -> dict | None:
    p = HERE / arm / f"{name}.json"
    if not p.exists():
        return None
    d = json.loads(p.read_text())
    r = next(v for k, v in d.items() if k not in ("_setup", "noisy") and "(no history)" not in k)
    return r if stills else r["after_warmup"]


def fmt(r: dict | None, trmae: bool = True) -> str:
    if r is None:
        return "-"
    t = r.get("trmae")
    return f"{r['psnr']:.2f}" + (f" / {t:.3f}" if trmae and t is not None else "")


def main() -> None:
    out = ["# wskpn-6e against wskpn-mr-e, from scratch (issue 15)", "",
           "Made by `python docs/results/mr/curves.py` from the arms' committed files (ab.sh).", "",
           "## Learning curves (validation during training, PSNR dB)", "",
           "| step | " + " | ".join(f"{a} val | {a} curves-test" for a in ARMS) + " |",
           "|---:|" + "---:|---:|" * len(ARMS)]
    by_step: dict = {}
    for a in ARMS:
        for r in rows(a):
            by_step.setdefault(r["step"], {})[a] = r
    for step in sorted(by_step):
        cells = []
        for a in ARMS:
            r = by_step[step].get(a)
            cells += [f"{r['val_psnr']:.2f}" if r else "-", f"{r['test_psnr']:.2f}" if r and r.get("test_psnr") else "-"]
        out.append(f"| {step} | " + " | ".join(cells) + " |")
    final = {a: rows(a)[-1] for a in ARMS}
    out += ["", "Time: " + "; ".join(f"{a} {final[a]['step']} steps in {final[a]['elapsed_s'] / 60:.1f} min"
                                     for a in ARMS) + " (one thread each, side by side).", "",
            "## Final evaluations (PSNR dB / TRMAE, after warm-up, with history)", "",
            "| arm | curves-test 1 spp | 4 spp | stills 1 | 2 | 4 | 8 spp | "
            + " | ".join(f"{s} {n}" for s in SETS for n in (1, 4)) + " |",
            "|---|" + "---:|" * (6 + 2 * len(SETS))]
    for a in ARMS:
        cells = [fmt(score(a, f"curves-test-{n}spp")) for n in (1, 4)]
        cells += [fmt(score(a, f"stills-curves-test-{n}spp", stills=True), trmae=False) for n in (1, 2, 4, 8)]
        cells += [fmt(score(a, f"{s}-{n}spp")) for s in SETS for n in (1, 4)]
        out.append(f"| {a} | " + " | ".join(cells) + " |")
    (HERE / "curves.md").write_text("\n".join(out) + "\n")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for a, c in zip(ARMS, ("C0", "C3")):
        rs = rows(a)
        ax.plot([r["step"] for r in rs], [r["val_psnr"] for r in rs], "-o", color=c, label=f"{a} validation")
        ax.plot([r["step"] for r in rs if r.get("test_psnr")], [r["test_psnr"] for r in rs if r.get("test_psnr")],
                "--s", color=c, label=f"{a} curves-test")
    ax.set_xlabel("step (batch 8 of 8-frame windows)")
    ax.set_ylabel("PSNR dB")
    ax.set_title("From scratch, same data and recipe")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(HERE / "curves.png", dpi=120)


if __name__ == "__main__":
    main()
