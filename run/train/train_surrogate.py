"""The surrogate pipeline in one command: train, compare, evaluate, ship, document.

    python -m run.train.train_surrogate [--train /work/data/small_train.h5]
        [--test /work/data/small_test.h5] [--ood /work/data/small_ood.h5]
        [--work /work/data/surrogate] [--jobs 2] [--epochs 300] [--bond-epochs 600]

Every training is one `amfe train` command (printed, and written to the model
card), run as a subprocess with one torch thread, ``--jobs`` at a time; its
checkpoint and log go to WORK/NAME.pt and WORK/NAME.log. A run whose
checkpoint exists is not redone, so a killed pipeline resumes where it
stopped (delete WORK/NAME.pt to redo one run). The runs:

- bonds: Custom Net, 5 members (seeds 0-4), amfe's recipe (below) for
  --bond-epochs epochs, on the volume-fraction and the bond-stiffness images
  (``--inputs fill,bonds``, amfe.dataset.bondimage): round 1's shipped model
  (amfe/models/custom_small.pt until round 2, which ships the multi-scale
  net of docs/model_card.md; this pipeline no longer copies into amfe/models);
- custom_bonds: one such network, --epochs epochs (what the bond image is
  worth against the same network on the volume fraction alone);
- ensemble: Custom Net, 5 members (seeds 0-4), amfe's recipe on the volume
  fraction alone, as the paper; its member 0 is the "Custom Net" row of the
  comparison;
- lenet5, alexnet, vgg: the other networks, amfe's recipe, seed 0 (AlexNet
  and VGG at half the channels and 1024-wide FC layers, see amfe.training.nets;
  --full-size trains the full ones, about 5x longer);
- paper: Custom Net with `amfe train`'s defaults, the paper's recipe (80
  epochs, constant learning rate 1e-3, no augmentation);
- noaug, linear: Custom Net, amfe's recipe without the augmentation, or with
  linear instead of log-standardised moduli (what each choice is worth);
- n400, n800: Custom Net on the first 400 / 800 training beds (error versus
  data size).

amfe's recipe: Adam, batch 100, lr 1e-3 with cosine decay, --epochs epochs
(default 300), log-standardised moduli, random mirror/transpose
augmentation (d4). No test-time averaging in the shipped model: averaging
over a bed's four mirror images lowers the errors a little (the table shows
how much) but costs four forward passes, which would put the ensemble over
1 ms per bed on one core.

Then every model is evaluated on the held-out test file (another data-set
seed): mean relative error and R^2 per property, parameters, training time,
batched inference time per bed; the ensemble's flag on the out-of-
distribution file of run/train/make_ood.py when it exists; and docs/surrogate_round1.md
(comparison table, model card, flag results) and the learning-curve PNGs in
docs/ are written. Run time on the 2-core development machine: about 35
minutes with --jobs 2 and 300 epochs (printed at the end).
"""
import argparse
import json
import os
import shlex
import subprocess
import sys
import time

import numpy as np

from amfe.vocab import LABEL_NAMES
from run.common import ROOT, parser
from run.train.surrogate_docs import LARGE_ERROR, command, round1_model, write_docs


def recipe(epochs):
    return ["--epochs", str(epochs), "--schedule", "cosine", "--augment", "d4"]


def plan_runs(args):
    """{name: (description, amfe train arguments after DATA.h5)}, the longest runs first."""
    big = [] if args.full_size else ["--width", "0.5", "--hidden", "1024", "1024"]
    r = recipe(args.epochs)
    bonds = ["--inputs", "fill,bonds"]
    return {
        "bonds": ("Custom Net + bond image, 5 members (seeds 0-4, "
                  f"{args.bond_epochs} epochs): shipped",
                  ["--arch", "custom", "--members", "5", "--seed", "0"] + bonds
                  + recipe(args.bond_epochs)),
        "alexnet": ("AlexNet" + ("" if args.full_size else " (half width, FC 1024)"),
                    ["--arch", "alexnet", "--seed", "0"] + big + r),
        "vgg": ("VGG-11" + ("" if args.full_size else " (half width, FC 1024)"),
                ["--arch", "vgg", "--seed", "0"] + big + r),
        "ensemble": ("Custom Net, 5 members (seeds 0-4)",
                     ["--arch", "custom", "--members", "5", "--seed", "0"] + r),
        "lenet5": ("LeNet-5", ["--arch", "lenet5", "--seed", "0"] + r),
        "custom_bonds": ("Custom Net + bond image", ["--arch", "custom", "--seed", "0"] + bonds + r),
        "paper": ("Custom Net, the paper's recipe (amfe train defaults)",
                  ["--arch", "custom", "--seed", "0"]),
        "noaug": ("Custom Net, amfe's recipe without augmentation",
                  ["--arch", "custom", "--seed", "0"] + [a for a in r if a not in ("--augment",
                                                                                 "d4")]),
        "linear": ("Custom Net, amfe's recipe with linear (not log) moduli",
                   ["--arch", "custom", "--seed", "0", "--linear-moduli"] + r),
        "n400": ("Custom Net on 400 training beds", ["--arch", "custom", "--seed", "0",
                                                     "--max-train", "400"] + r),
        "n800": ("Custom Net on 800 training beds", ["--arch", "custom", "--seed", "0",
                                                     "--max-train", "800"] + r),
    }


def run_trainings(args, runs, log):
    """Run the `amfe train` commands whose checkpoints are missing, ``args.jobs`` at a time."""
    todo = [n for n in runs if not os.path.isfile(os.path.join(args.work, f"{n}.pt"))]
    for n in runs:
        if n not in todo:
            log(f"  {n}: {args.work}/{n}.pt exists, kept")
    running = {}
    t0 = time.perf_counter()
    while todo or running:
        while todo and len(running) < args.jobs:
            name = todo.pop(0)
            cmd = command(args, name, runs[name][1])
            logf = open(os.path.join(args.work, f"{name}.log"), "w")
            log(f"  start {name}: {shlex.join(cmd)}")
            proc = subprocess.Popen(cmd, cwd=ROOT, stdout=logf, stderr=subprocess.STDOUT,
                                    env=dict(os.environ, OMP_NUM_THREADS="1"))
            running[name] = (proc, logf, time.perf_counter())
        time.sleep(2)
        for name, (proc, logf, ts) in list(running.items()):
            if proc.poll() is None:
                continue
            logf.close()
            del running[name]
            if proc.returncode != 0:
                raise SystemExit(f"amfe train for {name} failed (exit {proc.returncode}); see "
                                 f"{args.work}/{name}.log")
            log(f"  done {name} in {time.perf_counter() - ts:.0f} s "
                f"(pipeline {time.perf_counter() - t0:.0f} s)")


def single_member(ckpt, k=0):
    """Member k of an ensemble checkpoint as a one-network checkpoint (its own history)."""
    out = dict(ckpt, members=[ckpt["members"][k]], member_seeds=[ckpt["member_seeds"][k]],
               history=[ckpt["history"][k]], spread=None)
    out["training"] = dict(ckpt["training"], members=1, seconds=ckpt["history"][k]["seconds"])
    return out


def evaluate(args, runs, log):
    import torch

    from run.bench.surrogate import bench_batched
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.data import read_rows
    from amfe.training.metrics import property_metrics
    from amfe.training.predict import Surrogate

    torch.set_num_threads(1)
    results = {}
    ckpts = {n: load_checkpoint(os.path.join(args.work, f"{n}.pt")) for n in runs}
    models = {"custom": (single_member(ckpts["ensemble"]), "Custom Net")}
    for n in ("lenet5", "alexnet", "vgg", "paper", "noaug", "linear", "n400", "n800",
              "custom_bonds"):
        models[n] = (ckpts[n], runs[n][0])
    models["ensemble"] = (ckpts["ensemble"], runs["ensemble"][0])
    models["bonds"] = (ckpts["bonds"], runs["bonds"][0])
    data = {}
    for n, (ck, desc) in models.items():
        sur = Surrogate(ck, f"{n}", backend="torch")   # timed on torch threads below
        if sur.inputs not in data:
            data[sur.inputs] = read_rows(args.test, inputs=sur.inputs)
        images, labels = data[sur.inputs]
        res = sur.predict(images)
        m = property_metrics(res["mean"], labels)
        ms = bench_batched(sur, images, threads=(1,), batches=(None,), repeats=3)
        results[n] = {"description": desc, "metrics": m, "params": int(ck["n_parameters"]),
                      "train_seconds": float(ck["training"]["seconds"]),
                      "ms_per_bed": float(next(iter(ms.values()))),
                      "n_train": ck["dataset"]["n_train"], "members": len(ck["members"]),
                      "tta": sur.tta, "epochs": ck["training"]["epochs"],
                      "inputs": list(sur.inputs)}
        # the same network with test-time averaging over the four mirror images
        sur.tta = "flips"
        results[n]["metrics_tta"] = property_metrics(sur.predict(images)["mean"], labels)
        if n in ("ensemble", "bonds"):
            ms = bench_batched(sur, images, threads=(1,), batches=(None,), repeats=3)
            results[n]["ms_per_bed_tta"] = float(next(iter(ms.values())))
        log(f"  {n:9s} held-out mean rel. error % "
            + " ".join(f"{p} {100 * m[p]['mre']:.2f}" for p in LABEL_NAMES))
    return results, ckpts


def ood_report(args, ckpt, log):
    """Caught / missed large errors of the ensemble flag on held-out and out-of-distribution beds."""
    import h5py

    from amfe.training.data import dataset_info, read_rows
    from amfe.training.metrics import relative_errors
    from amfe.training.predict import Surrogate

    sur = Surrogate(ckpt, "ensemble")
    out = {"threshold": sur.threshold, "large_error": LARGE_ERROR}
    sets = [("held-out (in distribution)", args.test, None)]
    if args.ood and os.path.isfile(args.ood):
        with h5py.File(args.ood, "r") as f:
            variants = np.array([v.decode() if isinstance(v, bytes) else v
                                 for v in f["variant"][()]])
        sets.append(("out of distribution", args.ood, variants))
    rows = []
    for label, path, variants in sets:
        ok = dataset_info(path, sur.inputs)["ok"]
        images, labels = read_rows(path, ok, sur.inputs)
        res = sur.predict(images)
        err = relative_errors(res["mean"], labels).max(axis=1)
        groups = {label: np.ones(len(ok), bool)}
        if variants is not None:
            for v in dict.fromkeys(variants[ok]):
                groups[f"  {v}"] = variants[ok] == v
        for g, m in groups.items():
            for lim in (LARGE_ERROR, 0.20):
                large = err[m] > lim
                fl = res["flagged"][m]
                rows.append({"set": g, "limit": lim, "beds": int(m.sum()),
                             "flagged": int(fl.sum()), "large": int(large.sum()),
                             "caught": int((large & fl).sum()), "missed": int((large & ~fl).sum()),
                             "false_alarms": int((~large & fl).sum()),
                             "median_max_error": float(np.median(err[m])),
                             "median_error_flagged": float(np.median(err[m][fl])) if fl.any()
                             else float("nan"),
                             "median_error_unflagged": float(np.median(err[m][~fl]))
                             if (~fl).any() else float("nan"),
                             "median_score": float(np.median(res["score"][m]))})
        if variants is not None:
            out["failed_ood"] = int(len(variants) - len(ok))
    out["rows"] = rows
    for r in rows:
        if r["limit"] == LARGE_ERROR:
            log(f"  {r['set']:28s} beds {r['beds']:4d} flagged {r['flagged']:4d} large(>5%) "
                f"{r['large']:4d} caught {r['caught']:4d} missed {r['missed']:4d}")
    return out


def noise_floor(work, n_beds=12, n_copies=3, log=print):
    """Label scatter at a fixed image: the floor of any image-based surrogate's error.

    For n_beds parameter draws of the small scale (data-set seed 77), n_copies
    beds that differ only in their lattice seed (particle enlargements and
    jitter), with the scan path and the skipped pieces held fixed (the skip
    draws come from one generator per draw), are pixelated and homogenised.
    Their images agree to a few 0.1 % in density; the spread of their labels
    is noise no network can predict. Cached in WORK/noise_floor.json.
    """
    from unittest import mock

    path = os.path.join(work, "noise_floor.json")
    if os.path.isfile(path):
        with open(path) as fh:
            return json.load(fh)
    import amfe.model.bed as bedmod
    from amfe.dataset.images import pixelate
    from amfe.model.scales import get_scale, record_seed, sample_bed_params
    from amfe.solvers.driver import homogenize_bed
    from amfe.model.options import SolveOptions

    sc = get_scale("small")
    original = bedmod.scanned_mask
    rows = []
    for k in range(n_beds):
        params = sample_bed_params(sc, record_seed(77, k))
        fixed = (lambda c, size, t, scan, rng=None, _k=k:
                 original(c, size, t, scan, np.random.default_rng([77, _k])))
        labels, dens = [], []
        with mock.patch.object(bedmod, "scanned_mask", fixed):
            for j in range(n_copies):
                bed = bedmod.generate_bed(**dict(params, seed=params["seed"] + 1000 * (j + 1)))
                img = pixelate(bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                               box=((0.0, 0.0, 0.0), sc.size), spacing=sc.image_spacing)
                props = homogenize_bed(bed, SolveOptions(solver="gamg", material=bed.material())
                                       ).properties
                labels.append([props[n] for n in LABEL_NAMES])
                dens.append(float(img.mean()))
        labels = np.array(labels)
        rows.append({"rel_std": (labels.std(0, ddof=1) / np.abs(labels.mean(0))).tolist(),
                     "density_rel_std": float(np.std(dens, ddof=1) / np.mean(dens)),
                     "skip_fraction": float(params["scan"].skip_fraction)})
        log(f"  noise floor {k + 1}/{n_beds}: label rel. std % "
            + " ".join(f"{100 * v:.2f}" for v in rows[-1]["rel_std"]))
    out = {"n_beds": n_beds, "n_copies": n_copies, "rows": rows,
           "mean_rel_std": np.mean([r["rel_std"] for r in rows], axis=0).tolist(),
           "mean_density_rel_std": float(np.mean([r["density_rel_std"] for r in rows]))}
    with open(path, "w") as fh:
        json.dump(out, fh, indent=2)
    return out


def error_groups(args, ckpt):
    """The ensemble's held-out mean relative error % by kind of bed (skipped pieces, coverage)."""
    import h5py

    from amfe.training.data import dataset_info, read_rows
    from amfe.training.metrics import relative_errors
    from amfe.training.predict import Surrogate

    sur = Surrogate(ckpt)
    ok = dataset_info(args.test, sur.inputs)["ok"]
    images, labels = read_rows(args.test, ok, sur.inputs)
    err = relative_errors(sur.predict(images)["mean"], labels)
    with h5py.File(args.test, "r") as f:
        skip = f["params/skip_fraction"][()][ok]
        cov = f["params/coverage"][()][ok]
    groups = [("no skipped pieces", skip == 0), ("skipped pieces", skip > 0),
              ("scanned fraction < 0.6", cov < 0.6), ("scanned fraction >= 0.6", cov >= 0.6),
              ("no skips, scanned fraction >= 0.9", (skip == 0) & (cov >= 0.9))]
    return [(name, int(m.sum()), err[m].mean(axis=0).tolist()) for name, m in groups if m.any()]


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--train", default="/work/data/small_train.h5")
    ap.add_argument("--test", default="/work/data/small_test.h5")
    ap.add_argument("--ood", default="/work/data/small_ood.h5")
    ap.add_argument("--work", default="/work/data/surrogate")
    ap.add_argument("--jobs", type=int, default=2, help="trainings at a time (default 2)")
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--bond-epochs", type=int, default=600,
                    help="epochs of the shipped bond-image ensemble (default 600)")
    ap.add_argument("--full-size", action="store_true",
                    help="AlexNet and VGG at full width (4096-wide FC layers)")
    ap.add_argument("--no-docs", action="store_true", help="do not write docs/")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    os.makedirs(args.work, exist_ok=True)

    def log(line):
        print(line, flush=True)

    runs = plan_runs(args)
    log(f"[1/5] trainings ({len(runs)}, {args.jobs} at a time; logs in {args.work}/NAME.log)")
    run_trainings(args, runs, log)
    log("[2/5] held-out evaluation")
    results, ckpts = evaluate(args, runs, log)
    log("[3/5] ensemble flag on held-out and out-of-distribution beds")
    ood = ood_report(args, ckpts["bonds"], log)
    ood_fill = ood_report(args, ckpts["ensemble"], log)
    log("[4/5] label noise at a fixed image, errors by kind of bed, speed")
    floor = noise_floor(args.work, log=log)
    groups = error_groups(args, ckpts["bonds"])
    from run.bench.surrogate import run_all
    bench = run_all(round1_model(args), args.test, log=lambda s: log("  " + s))
    elapsed = time.perf_counter() - t0
    summary = {"results": results, "ood": ood, "ood_fill_only": ood_fill, "noise_floor": floor, "error_groups": groups,
               "bench": dict(bench, batched={f"{t} threads, batch {n}": v
                                             for (t, n), v in bench["batched"].items()}),
               "elapsed_seconds": elapsed}
    with open(os.path.join(args.work, "results.json"), "w") as fh:
        json.dump(summary, fh, indent=2, default=float)
    if not args.no_docs:
        log("[5/5] docs/surrogate_round1.md and learning curves")
        write_docs(args, runs, results, ckpts, ood, ood_fill, bench, elapsed, floor, groups)
    log(f"done in {elapsed / 60:.1f} min; results in {args.work}/results.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
