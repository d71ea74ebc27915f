"""Train the flag's error network (amfe.training.flagnet) for the shipped small model.

On data sets of `small` beds that no network of the small model's chain saw (a
``PATH:LO-HI`` keeps the records whose index lies in LO..HI), the shipped model's
prediction gives each bed's signed relative error r = predicted / label - 1; each
member (a multi-scale net started from the shipped member ``seed % members``, 12
outputs) learns a Laplace distribution of r per constant, plus the cross-entropy
of the event "some constant more than 10 % off" under it (``--bce`` weighs it),
on the bed mirrored at random in x and y (r does not change). Adam, one cycle,
the encoder at ``--body`` times the head's rate. Writes the members' weights as
an .npz (amfe.training.flagnet.save_flagnet); calibrate_flag.py --flagnet then
fits the flag with it.

    python -m run.train.train_flagnet --data S3.h5:52000-61622 S20.h5 S2.h5 S25.h5 \\
        --seeds 0 1 -o amfe/models/flag_small_net.npz
"""
import time

import h5py
import numpy as np
import torch
from torch.nn import functional as F

from amfe.training.checkpoint import load_checkpoint
from amfe.training.data import dataset_info, flip_images, read_rows
from amfe.training.flagnet import SCALE, save_flagnet
from amfe.training.flagrisk import BAD
from amfe.training.multiscale import MultiScaleNet
from amfe.training.predict import Surrogate
from run.common import ROOT, parser


def residuals(sur, spec):
    """(images float32 (n, layers, H, W), r (n, 6)) of a ``PATH[:LO-HI]`` data set's ok beds."""
    path, _, span = spec.partition(":")
    rows = dataset_info(path, sur.inputs)["ok"]
    if span:
        lo, hi = (int(v) for v in span.split("-"))
        with h5py.File(path, "r") as f:
            index = f["index"][()]
        rows = [r for r in rows if lo <= index[r] <= hi]
    images, labels = read_rows(path, rows, sur.inputs)
    return images.astype(np.float32), sur.predict(images)["mean"] / labels - 1.0


def bad_logit(mu, logb, bad=BAD):
    """Torch twin of amfe.training.flagnet.bad_logit (mu, logb (n, 6) in SCALE units)."""
    b = torch.exp(logb.clamp(-5.0, 5.0))
    t = bad / SCALE
    z_up, z_lo = (t - mu) / b, (mu + t) / b
    e_up, e_lo = 0.5 * torch.exp(-z_up.abs()), 0.5 * torch.exp(-z_lo.abs())
    up = torch.where(z_up >= 0, e_up, 1 - e_up)
    lo = torch.where(z_lo >= 0, e_lo, 1 - e_lo)
    inside = (1 - up - lo).clamp(1e-6, 1.0)
    log_good = torch.log(inside).sum(1).clamp(max=-1e-6)
    return torch.log(-torch.expm1(log_good)) - log_good


def loss_of(out, r, bce):
    """The Laplace negative log-likelihood of r (n, 6) (SCALE units) under out (n, 12), plus
    ``bce`` times the cross-entropy of "some |r| > BAD"."""
    mu, logb = out[:, :6], out[:, 6:].clamp(-5.0, 5.0)
    loss = (torch.abs(r - mu) / torch.exp(logb) + logb).mean()
    if bce:
        bad = (r.abs() > BAD / SCALE).any(1).float()
        loss = loss + bce * F.binary_cross_entropy_with_logits(bad_logit(mu, logb), bad)
    return loss


def start_net(ckpt, member):
    """A 12-output multi-scale net with the shipped member's weights but its last layer's."""
    net = MultiScaleNet(ckpt["image_shape"], outputs=12, **ckpt["arch_args"])
    own = net.state_dict()
    last = max(int(k.split(".")[1]) for k in own if k.startswith("head."))
    for name, value in ckpt["members"][member].items():
        if not name.startswith(f"head.{last}."):
            own[name] = torch.as_tensor(value)
    net.load_state_dict(own)
    return net


def train_member(ckpt, x, r, seed, a, log=print):
    """One member's state dict (numpy arrays) trained on images x and errors r (SCALE units)."""
    torch.manual_seed(seed)
    net = start_net(ckpt, seed % len(ckpt["members"]))
    head = [p for n, p in net.named_parameters() if n.startswith("head.")]
    body = [p for n, p in net.named_parameters() if not n.startswith("head.")]
    opt = torch.optim.Adam([{"params": body, "lr": a.lr * a.body}, {"params": head, "lr": a.lr}])
    steps = a.epochs * -(-len(x) // a.batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, [a.lr * a.body, a.lr], total_steps=steps,
                                                pct_start=0.1)
    g = torch.Generator().manual_seed(seed)
    for epoch in range(a.epochs):
        net.train()
        total, order = 0.0, torch.randperm(len(x), generator=g)
        for s in range(0, len(x), a.batch_size):
            idx = order[s:s + a.batch_size]
            fx, fy = (bool(v) for v in torch.rand(2, generator=g) < 0.5)
            loss = loss_of(net(flip_images(x[idx], fx, fy, False)), r[idx], a.bce)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        log(f"  member seed {seed}, epoch {epoch + 1}/{a.epochs}: loss {total / len(x):.4f}")
    return {k: v.detach().numpy() for k, v in net.state_dict().items()}


def main():
    p = parser(__doc__)
    p.add_argument("--data", nargs="+", required=True, help="PATH or PATH:LO-HI (record index)")
    p.add_argument("--model", default=f"{ROOT}/amfe/models/multiscale_small.pt")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch-size", type=int, default=100)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--body", type=float, default=0.3, help="the encoder's rate / the head's")
    p.add_argument("--bce", type=float, default=3.0)
    p.add_argument("-o", "--output", required=True)
    a = p.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()
    ckpt = load_checkpoint(a.model)
    sur = Surrogate.load(a.model)
    parts = [residuals(sur, spec) for spec in a.data]
    x = torch.as_tensor(np.concatenate([q[0] for q in parts]))
    r_rel = np.concatenate([q[1] for q in parts])
    r = torch.as_tensor(r_rel / SCALE, dtype=torch.float32)
    print(f"{len(x)} beds, {100 * (np.abs(r_rel) > BAD).any(1).mean():.1f} % bad")
    states = [train_member(ckpt, x, r, seed, a) for seed in a.seeds]
    save_flagnet(a.output, states, {
        "image_shape": list(ckpt["image_shape"]), "arch_args": dict(ckpt["arch_args"]),
        "model": str(a.model), "data": list(a.data), "beds": int(len(x)), "seeds": a.seeds,
        "epochs": a.epochs, "lr": a.lr, "body": a.body, "bce": a.bce,
        "batch_size": a.batch_size, "minutes": round((time.time() - t0) / 60, 1)})
    print(f"wrote {a.output} ({(time.time() - t0) / 60:.1f} min)")


if __name__ == "__main__":
    main()
