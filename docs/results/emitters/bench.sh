#!/usr/bin/env bash
# Whole-frame time at 1280x720 through the driver, RUNS (default 5) bench runs into bench-1 .. bench-RUNS: the
# shipped wskpn-4x3-aa, the file before it (docs/results/cheap-wskpn/scratch-more-2 exported by evaluate.sh to
# /tmp/emitters/scratch-more-2.onnx), wskpn-3-aa and Open Image Denoise fast and high, interleaved frame by frame,
# medians of 15 frames; then bench-ratios.txt: each run's ms and its ratio to Open Image Denoise fast, and the
# median ratio over the runs (issue 15: under a third). SUMMARY_ONLY=1: only the summary of the runs there.
# Stop other work first (kill -STOP); this machine's numbers vary by a few % from run to run.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/emitters
if [ -z "$SUMMARY_ONLY" ]; then
  [ -f /tmp/emitters/scratch-more-2.onnx ] || mcdenoise export docs/results/cheap-wskpn/scratch-more-2 --out /tmp/emitters/scratch-more-2.onnx
  for i in $(seq 1 ${RUNS:-5}); do
    mcdenoise bench models/wskpn-4x3-aa.onnx /tmp/emitters/scratch-more-2.onnx models/wskpn-3-aa.onnx --methods oidn-fast \
      oidn-high --sizes 1280x720 --frames 15 --warmup 2 --no-torch --no-quality --no-memory --out $out/bench-$i > /dev/null
  done
fi
python - $out > $out/bench-ratios.txt <<'PY'
import re, statistics, sys, pathlib
out = pathlib.Path(sys.argv[1])
names = ("wskpn-4x3-aa", "wskpn-3-aa-conv-3-blocks-4", "wskpn-3-aa", "oidn-fast", "oidn-high")
print("1280x720 whole frame, ms (docs/results/emitters/bench.sh); wskpn-3-aa-conv-3-blocks-4 is the file before")
print("run | " + " | ".join(names) + " | wskpn-4x3-aa / oidn-fast | file before / oidn-fast")
ratios, before = [], []
for d in sorted(out.glob("bench-[0-9]*"), key=lambda p: int(p.name.split("-")[1])):
    text = (d / "bench.md").read_text()
    w = text[text.index("## Whole frame"):]
    ms = {n: float(re.search(r"\| " + re.escape(n) + r" \| ([0-9.]+) \|", w).group(1)) for n in names}
    ratios.append(ms["wskpn-4x3-aa"] / ms["oidn-fast"])
    before.append(ms["wskpn-3-aa-conv-3-blocks-4"] / ms["oidn-fast"])
    print(f"{d.name} | " + " | ".join(f"{ms[n]:.1f}" for n in names) + f" | {ratios[-1]:.3f} | {before[-1]:.3f}")
print(f"median ratio over {len(ratios)} runs: wskpn-4x3-aa {statistics.median(ratios):.3f} "
      f"(range {min(ratios):.3f}-{max(ratios):.3f}), the file before {statistics.median(before):.3f}")
PY
cat $out/bench-ratios.txt
