"""Train the network of one thickness (issue 46; amfe.training.thicknets): from scratch, on
the drawn-material beds of that thickness alone, its outputs in log space.

A multi-scale network (arch ``multiscale``, run in numpy by amfe.training.npnet) reads the
bed's fill and bond layers and nu, psi as constant planes. Each member is trained from
its own seed on the same beds: squared error of the standardised log labels, AdamW,
one-cycle learning rate, mirror augmentation (the six constants do not change under x or
y mirrors), mirror-averaged prediction; with ``--augment d4z`` also the x <-> y swap and
the bed upside down, which the network then reads both ways up
(amfe.training.thicknets.thick_members). The anybed stack reads its output as one more
column (run/train/fit_anybed_stack.py), on beds it never saw.

    python -m run.train.train_thick --data L2.h5:0-999,2000-7999 --members 0 -o p0.pt
    python -m run.train.train_thick --data L2.h5:0-999,2000-7999 --members 1 -o p1.pt
    python -m run.train.train_thick --data L2.h5:0-999,2000-7999 --join p0.pt p1.pt \
        -o amfe/models/thick_2layers.pt
    python -m run.train.train_thick --data L5.h5:0-999,3000-12999 --augment d4z --epochs 60 \
        --members 0 -o p0.pt     (and 1, then --join as above: thick_5layers.pt)
"""
import os
import time

import numpy as np
import torch

from amfe.training.checkpoint import load_checkpoint, save_checkpoint
from amfe.training.data import transpose_labels
from amfe.training.multiscale import MultiScaleNet
from amfe.training.thicknets import BOTH_WAYS_UP, THICK_DESCRIPTORS, thick_inputs, upside_down
from amfe.vocab import LABEL_NAMES
from run.common import ROOT, join_members, parser
from run.train.fit_anybed_stack import read_unseen

ANYBED = os.path.join(ROOT, "amfe", "models", "anybed_small.pt")
#: Copied from the anybed checkpoint: the imaging, test-time mirrors and file format.
SHARED = ("pixelation", "tta", "label_rule", "format", "format_version", "amfe_version",
          "torch_version", "material")


def read_sets(specs):
    """(inputs (n, 2 L + 2, H, W), labels (n, 6) at 210 GPa) of data sets of one thickness."""
    parts = [read_unseen(s) for s in specs]
    layers = {p[0].shape[1] for p in parts}
    if len(layers) != 1:
        raise SystemExit(f"error: the data sets hold beds of {sorted(layers)} layers, not one")
    x = np.concatenate([thick_inputs(f, b, nu, psi) for f, b, _, nu, psi in parts])
    y = np.concatenate([p[2] for p in parts])
    keep = np.all(y > 0, axis=1)
    if not keep.any():
        raise SystemExit("error: every bed has a non-positive constant: nothing to learn in logs")
    if not keep.all():   # an auxetic direction: a network of the constants' logs cannot learn it
        print(f"leaving out {int((~keep).sum())} of {len(y)} beds with a non-positive constant "
              f"(the network learns their logs)", flush=True)
    return x[keep], y[keep], layers.pop()


#: Training augmentations: x and y mirrors (the 2-layer network's), and with "d4z" also the
#: x <-> y swap (labels permuted, amfe.training.data.transpose_labels) and the bed upside
#: down (its layers in reverse order): both are exact symmetries of the six constants on a
#: square bed of whole layers (docs/surrogate.md, "The networks of one thickness").
AUGMENTS = ("flips", BOTH_WAYS_UP)


def augment(xb, zb, layers, mode, norm, rng):
    """A batch's inputs (B, 2 L + 2, H, W) and standardised log labels (B, 6), each sample
    under random symmetries of ``mode``; norm: (mean, std) (6,) of the log labels."""
    if mode == "flips":     # the whole batch mirrored alike (the 2-layer network's training)
        if rng.random() < 0.5:
            xb = xb.flip(3)
        if rng.random() < 0.5:
            xb = xb.flip(2)
        return xb, zb
    B = len(xb)
    pick = torch.as_tensor(rng.random((4, B)) < 0.5)
    xb = torch.where(pick[0].view(B, 1, 1, 1), xb.flip(3), xb)
    xb = torch.where(pick[1].view(B, 1, 1, 1), xb.flip(2), xb)
    xb = torch.where(pick[2].view(B, 1, 1, 1), xb[:, upside_down(layers, xb.shape[1])], xb)
    xb = torch.where(pick[3].view(B, 1, 1, 1), xb.transpose(2, 3), xb)
    mean, std = (torch.as_tensor(a, dtype=zb.dtype) for a in norm)
    swapped = transpose_labels((zb * std + mean).exp()).log()
    zb = torch.where(pick[3].view(B, 1), (swapped - mean) / std, zb)
    return xb, zb


def train_member(x, z, layers, args, seed, norm):
    """A MultiScaleNet trained on inputs x, standardised log labels z (norm: their (mean, std)
    of the logs); (state, history)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = MultiScaleNet(x.shape[1:], width=args.width, n_fill=layers,
                        features=len(THICK_DESCRIPTORS), channels=args.channels,
                        hidden=args.hidden)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    per_epoch = -(-len(x) // args.batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, args.lr, total_steps=args.epochs * per_epoch)
    xt, zt, history = torch.as_tensor(x), torch.as_tensor(z), []
    for epoch in range(args.epochs):
        net.train()
        total = 0.0
        for b in torch.randperm(len(xt)).split(args.batch_size):
            xb, zb = augment(xt[b], zt[b], layers, args.augment, norm, rng)
            loss = ((net(xb) - zb) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(b)
        history.append({"epoch": epoch, "train": total / len(xt)})
        print(f"member {seed} epoch {epoch}: {total / len(xt):.4f}", flush=True)
    return {n: v.detach().clone() for n, v in net.state_dict().items()}, history


def main():
    p = parser(__doc__)
    p.add_argument("--data", nargs="+", required=True, help="PATH[:A-B,C-D] of one thickness")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--members", type=int, nargs="+", default=[0, 1])
    p.add_argument("--join", nargs="+", metavar="PART.pt", help="join members trained apart")
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--width", type=float, default=1.0)
    p.add_argument("--channels", type=int, nargs="+", default=[48, 96, 128])
    p.add_argument("--hidden", type=int, nargs="+", default=[128])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--augment", choices=AUGMENTS, default="flips")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    x, y, layers = read_sets(args.data)
    t = np.log(y)
    mean, std = t.mean(axis=0), t.std(axis=0)
    z = ((t - mean) / std).astype(np.float32)
    print(f"{len(x)} beds of {layers} layers, input {x.shape[1:]}", flush=True)
    t0 = time.perf_counter()
    states, histories, seeds, seconds, _ = join_members(args.join or [], args.data, "thick",
                                                       agree={"augment": args.augment})
    for k in [] if args.join else args.members:
        state, hist = train_member(x, z, layers, args, k, (mean, std))
        states.append(state)
        histories.append(hist)
        seeds.append(k)
    anybed = load_checkpoint(ANYBED)
    ckpt = {key: anybed[key] for key in SHARED}
    ckpt.update(
        normalizer={"mean": mean.tolist(), "std": std.tolist(), "log": [True] * 6,
                    "labels": list(LABEL_NAMES)},
        arch="multiscale",
        arch_args={"n_fill": layers, "width": args.width, "features": len(THICK_DESCRIPTORS),
                   "channels": list(args.channels), "hidden": list(args.hidden)},
        members=states, member_seeds=seeds, image_shape=list(x.shape[1:]),
        inputs=["fill", "bonds"],
        thick={"layers": layers, "descriptors": list(THICK_DESCRIPTORS), "data": list(args.data),
               "n_beds": len(x), "epochs": args.epochs, "lr": args.lr, "augment": args.augment,
               "seconds": seconds + time.perf_counter() - t0},
        history=histories, created=time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime()))
    save_checkpoint(args.output, ckpt)
    print(f"wrote {args.output} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
