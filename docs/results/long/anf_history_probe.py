"""Per frame: anf-s with its history against anf-s reset before every frame, on the hand-made
room at 4 spp (the one case in table.md where a history makes a sequence worse than none), with
and without the driver's auto-exposure (which a history fixes at its first frame).

    python docs/results/long/anf_history_probe.py > docs/results/long/anf_history_probe.txt
"""
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.training.metrics import psnr
from mcdenoise.training.testsets import at_spp, read_sequences

seq = read_sequences("data/heldout-room_window")[0]
for auto in (True, False):
    quiet = lambda m: None  # noqa: E731
    kept = Denoiser.load("models/anf-s.onnx", log=quiet, autoexposure=auto)
    reset = Denoiser.load("models/anf-s.onnx", log=quiet, autoexposure=auto)
    print(f"auto-exposure {'on' if auto else 'off'}: frame, PSNR dB with history, reset before the frame")
    for t, fr in enumerate(seq):
        f = at_spp(fr, 4)
        with_history = kept(f)
        reset.reset()
        print(f"{t:2d} {psnr(with_history, f.reference):6.2f} {psnr(reset(f), f.reference):6.2f}")
