"""Train the ``anybed`` surrogate (issue 46): 2-6 layers, drawn nu and psi, from the small model.

Each member starts from the matching member of the shipped 3-layer steel model
(amfe.training.anybed.from_small: bit for bit its output on a small bed) and is
fine-tuned on the drawn-material data sets (``--data``, each a data set of
`amfe dataset --size 0.6 0.6 0.Z --materials draw`, or a steel one) with the
small model's normaliser, L1 loss on the normalised labels, mirror/transpose
augmentation and a cosine learning rate. Writes a checkpoint of the shipped
layout (arch multiscale with ``features``, inputs fill + bonds, ``anybed`` block).

    python -m run.train.train_anybed --data D1.h5 D2.h5:0-999,2000-2999 ... \
        -o amfe/models/anybed_small.pt

or one member a core (``--members 0 -o p0.pt`` and ``--members 1 -o p1.pt``, then
``--join p0.pt p1.pt --data <the same> -o anybed_small.pt``).
"""
import os
import time

import h5py
import numpy as np
import torch

from amfe.training.anybed import E_TRAINED, MAX_LAYERS, anybed_inputs, from_small
from amfe.training.checkpoint import build_members, load_checkpoint, save_checkpoint
from amfe.training.conformal import calibrate, calibration
from amfe.training.data import Normalizer, augment_batch
from amfe.training.ensemble import predict_raw, relative_spread
from amfe.training.predict import Surrogate
from amfe.vocab import LABEL_NAMES
from run.common import ROOT, join_members, parser, record_spec

SMALL = os.path.join(ROOT, "amfe", "models", "multiscale_small.pt")


def read_set(spec):
    """(inputs (n, 15, H, W), labels (n, 6) at E_TRAINED) of a data set's solved records
    (``PATH[:RANGES]``: those in the ranges, run.common.record_spec)."""
    path, keep = record_spec(spec)
    with h5py.File(path, "r") as f:
        status = f["status"][:]
        ok = (status == 0) & keep(np.arange(len(status)))
        fill, bonds = f["images"][:][ok], f["bond_images"][:][ok]
        labels = f["labels"][:][ok].astype(np.float64)
        n = int(ok.sum())
        p = f["params"]
        nu = p["nu"][:][ok] if "nu" in p else np.full(n, 0.28)
        psi = p["psi"][:][ok] if "psi" in p else np.full(n, 0.08)
        E = p["E"][:][ok] if "E" in p else np.full(n, E_TRAINED)
    labels[:, :3] *= (E_TRAINED / E)[:, None]     # moduli scale with E exactly
    return anybed_inputs(fill, bonds, nu, psi), labels


def split(n, fraction, seed=0):
    """(validation, training) row indices: one split for every member, so that the
    validation beds are held out of the whole ensemble (they calibrate its intervals)."""
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(seed))
    n_val = max(1, int(round(fraction * n)))
    return perm[:n_val], perm[n_val:]


def train_member(net, x, y, norm, args, seed):
    """Fine-tune ``net`` on (x, y) raw labels; returns the validation L1 history."""
    g = torch.Generator().manual_seed(seed)
    val, train = split(x.shape[0], args.val_fraction)
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    steps = args.epochs * ((len(train) + args.batch_size - 1) // args.batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    history = []
    for epoch in range(args.epochs):
        net.train()
        order = train[torch.randperm(len(train), generator=g)]
        total = 0.0
        for k in range(0, len(order), args.batch_size):
            b = order[k:k + args.batch_size]
            xb, yb = augment_batch(xt[b], yt[b], "d4", g)
            loss = (net(xb) - norm.encode(yb)).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(b)
        net.eval()
        with torch.no_grad():
            v = float((net(xt[val]) - norm.encode(yt[val])).abs().mean())
        history.append({"epoch": epoch, "train": total / len(train), "val": v})
        print(f"  member {seed} epoch {epoch + 1}/{args.epochs}: train {total / len(train):.4f} "
              f"val {v:.4f}", flush=True)
    return history


def calibrate_on_validation(ckpt, x, y, args):
    """(conformal, metrics): split conformal intervals from the validation beds (held out of
    every member), and their mean relative errors per layer count."""
    val = split(x.shape[0], args.val_fraction)[0].numpy()
    sur = Surrogate(ckpt, "anybed")
    members = np.stack([predict_raw(net, torch.as_tensor(x[val]), sur.norm, sur.tta).numpy()
                        for net in sur.nets])
    mean, spread = members.mean(axis=0), relative_spread(members)
    cal = calibrate(mean, y[val], list(LABEL_NAMES), spread)
    layers = np.rint(x[val, 2 * MAX_LAYERS, 0, 0] * 3 + 3).astype(int)   # the layers descriptor
    rel = np.abs(mean - y[val]) / np.abs(y[val])
    metrics = {f"{n} layers": {"n": int((layers == n).sum()),
                        "mre": dict(zip(LABEL_NAMES, map(float, rel[layers == n].mean(axis=0))))}
               for n in np.unique(layers)}
    for n, m in metrics.items():
        print(f"  validation, {n} ({m['n']} beds): "
              + ", ".join(f"{k} {100 * v:.2f} %" for k, v in m["mre"].items()))
    return calibration({"0.6x0.6": cal}, names=list(LABEL_NAMES)), metrics


def main():
    p = parser(__doc__)
    p.add_argument("--data", nargs="+", required=True,
                   help="data sets (0.6 mm, any layers), each PATH[:A-B,C-D]: those records only")
    p.add_argument("-o", "--output", required=True, help="the checkpoint to write")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--batch-size", type=int, default=100)
    p.add_argument("--val-fraction", type=float, default=0.1,
                   help="held out of every member: the intervals' calibration beds")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--members", type=int, nargs="+", default=None,
                   help="train only these members (one process a core), written as a part")
    p.add_argument("--join", nargs="+", default=None,
                   help="parts (--members) to join in order, instead of training")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    small = load_checkpoint(SMALL)
    norm = Normalizer.from_dict(small["normalizer"])
    parts = [read_set(path) for path in args.data]
    x = np.concatenate([a for a, _ in parts])
    y = np.concatenate([b for _, b in parts])
    hw = x.shape[-2:]
    print(f"{x.shape[0]} beds from {len(args.data)} data sets, input {x.shape[1:]}", flush=True)
    t0 = time.perf_counter()
    states, histories, seeds, seconds, joined = join_members(args.join or [], args.data, "anybed")
    if joined is not None:
        args.epochs, args.lr = joined["epochs"], joined["lr"]
    for k, start in enumerate([] if args.join else build_members(small)):
        if args.members is not None and k not in args.members:
            continue
        net = from_small(start.state_dict(), hw)
        hist = train_member(net, x, y, norm, args, seed=k)
        states.append({n: v.detach().clone() for n, v in net.state_dict().items()})
        histories.append(hist)
        seeds.append(k)
    ckpt = {key: small[key] for key in ("normalizer", "pixelation", "tta", "label_rule",
                                        "format", "format_version", "amfe_version",
                                        "torch_version")}
    ckpt.update(arch="multiscale", arch_args={"n_fill": 6, "width": 0.5, "features": 3},
                members=states, member_seeds=seeds,
                image_shape=[int(x.shape[1]), int(hw[0]), int(hw[1])],
                inputs=["fill", "bonds"], material=dict(small["material"]),
                anybed={"descriptors": ["layers", "nu", "psi"], "data": list(args.data),
                        "n_beds": int(x.shape[0]), "epochs": args.epochs, "lr": args.lr,
                        "init": os.path.relpath(SMALL, ROOT),
                        "seconds": seconds + time.perf_counter() - t0},
                history=histories, created=time.strftime("%Y-%m-%dT%H:%M:%S+00:00",
                                                         time.gmtime()))
    ckpt["conformal"], ckpt["validation"] = calibrate_on_validation(ckpt, x, y, args)
    save_checkpoint(args.output, ckpt)
    print(f"wrote {args.output} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
