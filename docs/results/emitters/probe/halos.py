"""The worst pixels of run folders on data/curves-test (the trainer's test windows, last frame): per
item PSNR and relMSE, the 15 largest relative squared errors with the reference, the prediction, the noisy
input, the albedo and the brightest reference pixel within 6 of it, and the share of the tonemapped squared
error from dark, too bright and too dark pixels. argv: run folders. Writes nothing.

    python docs/results/emitters/probe/halos.py docs/results/cheap-wskpn/scratch-more docs/results/cheap-wskpn/open-1
"""
import sys, json, numpy as np, torch
from mcdenoise.training.runs import load_run
from mcdenoise.training.dataset import SequenceDataset, collate
from mcdenoise.training.train import run_window
from mcdenoise.training.metrics import RELMSE_EPS, psnr, relmse
from mcdenoise.runtime.transfer import reinhard_gamma
torch.set_num_threads(2)
for r in sys.argv[1:]:
    spec, model, ck = load_run(r)
    cfg = json.load(open(r + "/config.json"))
    ds = SequenceDataset("data/curves-test", "all", tuple(spec.inputs.layers), crop=128, spp_choices=cfg["spp"],
                         window=cfg["window"], augment=False, centre_only=True)
    P, R, N, A = [], [], [], []
    with torch.no_grad():
        for i in range(0, len(ds), 4):
            b = collate([ds[j] for j in range(i, min(len(ds), i + 4))])
            outs = run_window(model, b, spec.protocol)
            P.append(outs[-1]["output"].numpy()); R.append(b["reference"][:, -1].numpy()); N.append(b["color"][:, -1].numpy())
            A.append(b["albedo"][:, -1].numpy())
    p, rf, n, a = (np.concatenate(x).transpose(0, 2, 3, 1) for x in (P, R, N, A))
    print("==", r, "items", len(p), "psnr %.2f relmse %.2f" % (psnr(p, rf), relmse(p, rf)))
    per = [(psnr(p[i], rf[i]), relmse(p[i], rf[i])) for i in range(len(p))]
    print(" per-item psnr", " ".join("%.1f" % x for x, _ in per))
    print(" per-item relmse", " ".join("%.1f" % y for _, y in per))
    e = (p - rf) ** 2 / (rf ** 2 + RELMSE_EPS)   # relmse's per-pixel terms
    lum = rf.mean(-1); pl = p.mean(-1); nl = n.mean(-1)
    flat = e.mean(-1).reshape(-1)
    idx = np.argsort(flat)[::-1][:15]
    for k in idx:
        i, y, x = np.unravel_index(k, lum.shape)
        print("  item %d (%d,%d) err %.0f ref %.3f pred %.3f noisy %.3f alb %.2f  ref-max-nbhd %.2f" % (i, y, x, flat[k], lum[i, y, x], pl[i, y, x], nl[i, y, x], a[i, :, y, x].mean() if a.ndim==4 and a.shape[1]==3 else a[i, y, x].mean(), lum[i, max(0,y-6):y+7, max(0,x-6):x+7].max()))
    tm = ((reinhard_gamma(p) - reinhard_gamma(rf)) ** 2).mean(-1)
    print(" share of tonemapped SE from pixels with ref<0.05: %.2f, pred>3*ref: %.2f, pred<ref/3: %.2f" % (
        tm[lum < 0.05].sum() / tm.sum(), tm[pl > 3 * lum + 0.01].sum() / tm.sum(), tm[pl < lum / 3].sum() / tm.sum()))

