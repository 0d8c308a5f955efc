"""The long sequences' and held-out scenes' scores (docs/results/long/eval.sh) as markdown.

    python docs/results/long/table.py > docs/results/long/table.md

Reads every ``*.json`` of ``mcdenoise evaluate`` under docs/results/long/<set>/."""
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: What ``mcdenoise render --check-references`` writes (training.render.command.REFERENCE_CHECK),
#: copied beside the set's scores by eval.sh.
REFERENCE_CHECK = "reference_check.json"


def load() -> dict:
    """{set: {spp: {method: result}}}; a run's model is named "<spec> (<run folder>)"."""
    out: dict = {}
    for p in sorted(HERE.glob("*/*.json")):
        if p.name == REFERENCE_CHECK:
            continue
        d = json.loads(p.read_text())
        setup = d.pop("_setup")
        who = p.stem.rsplit("-", 1)[0]
        for m, r in d.items():
            if who != "baseline" and m == "noisy":
                continue          # every run's file repeats the baseline's noisy row
            label = m if who == "baseline" else f"{m} ({who})"
            out.setdefault(p.parent.name, {}).setdefault(setup["spp"], {})[label] = (r, setup)
    return out


def _bare(label: str) -> str:
    """The label of ``label``'s model reset before every frame: "<spec> (no history)", with a
    run's folder kept after it ("<spec> (no history) (<run>)")."""
    spec, _, run = label.partition(" (")
    return f"{spec} (no history)" + (f" ({run}" if run else "")


def _f(x, fmt):
    return "-" if x is None else format(x, fmt)


def main() -> None:
    res = load()
    for name, by_spp in res.items():
        _, setup = next(iter(next(iter(by_spp.values())).values()))
        print(f"## {name}\n\n`{setup['data']}`: {setup['sequences']} sequence(s); PSNR dB over all frames and "
              f"after {setup['warmup']} warm-up frames, TRMAE (Eq. 16) and the motion-compensated "
              "temporal error (wte, metrics.warped_temporal_error: 1 = as steady as the reference, "
              "more = flicker, less = smoothed in time beyond it) after warm-up; history: what the model's "
              "history earns after warm-up (its PSNR minus the same model's reset before every frame, "
              "the \"(no history)\" row; a history must never make a sequence worse than none).\n")
        check = HERE / name / REFERENCE_CHECK
        if check.exists():
            c = json.loads(check.read_text())
            print(f"References: two independent {c['ref_spp']}-spp references of each sequence's first frame "
                  f"agree to {c['min_db']:.2f} dB at worst ({', '.join(f'{v:.2f}' for v in c['sequences'].values())}), "
                  f"so each is about {c['min_db'] + 3:.1f} dB from the converged image (the difference of two "
                  "carries both noises): a method's PSNR well below that is measured, not the references' noise.\n")
        spps = sorted(by_spp)
        print("| method | " + " | ".join(f"{s} spp PSNR all | after warm-up | TRMAE | wte | history" for s in spps) + " |")
        print("|---|" + "---:|---:|---:|---:|---:|" * len(spps))
        # Each model's "(no history)" row right below it; Open Image Denoise last.
        methods = sorted({m for v in by_spp.values() for m in v},
                         key=lambda m: (m != "noisy", m.startswith("oidn"), m.replace(" (no history)", ""),
                                        " (no history)" in m))
        for m in methods:
            cells = []
            for s in spps:
                r = by_spp[s].get(m)
                if r is None:
                    cells += ["-"] * 5
                    continue
                r, a = r[0], r[0].get("after_warmup") or {}
                bare = by_spp[s].get(_bare(m))
                earns = None if bare is None or a.get("psnr") is None else \
                    a["psnr"] - (bare[0].get("after_warmup") or {}).get("psnr", float("nan"))
                cells += [_f(r["psnr"], ".2f"), _f(a.get("psnr"), ".2f"), _f(a.get("trmae"), ".3f"),
                          _f(a.get("wte"), ".3f"), _f(earns, "+.2f")]
            print(f"| {m} | " + " | ".join(cells) + " |")
        print()


if __name__ == "__main__":
    main()
