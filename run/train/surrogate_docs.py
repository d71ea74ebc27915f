"""The round-1 comparison's docs page (docs/surrogate_round1.md): what run/train/train_surrogate.py
measured, written as markdown. Split from that script, which runs the trainings and the
evaluations."""
import os
import shlex
import time

import numpy as np

from amfe.vocab import LABEL_NAMES
from run.common import ROOT

DOCS = os.path.join(ROOT, "docs")
LARGE_ERROR = 0.05       # a bed's prediction is a "large error" if any property is off by more


def round1_model(args):
    """Round 1's shipped model as this pipeline trains it (WORK/bonds.pt)."""
    return os.path.join(args.work, "bonds.pt")


def command(args, name, extra):
    """The `amfe train` command line of run ``name`` (its checkpoint WORK/name.pt)."""
    out = os.path.join(args.work, f"{name}.pt")
    return ([".venv/bin/amfe", "train", args.train] + extra
            + ["--test", args.test, "--threads", "1", "-o", out])


def data_command(path):
    import h5py
    with h5py.File(path, "r") as f:
        a = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    return (f"mpirun -n 2 .venv/bin/amfe dataset -o {path} --count {int(a['count'])} "
            f"--seed {int(a['seed'])} --scale {a['scale']}"
            + (f" --rtol {float(a['rtol']):g}" if float(a.get("rtol", 1e-8)) != 1e-8 else ""))


def pct(x):
    return f"{100 * x:.2f}"


def _mre_row(name, m):
    return f"| {name} | " + " | ".join(pct(m[p]["mre"]) for p in LABEL_NAMES) + " |"


def _pct1(x):
    return "-" if not np.isfinite(x) else f"{100 * x:.1f}"


def _targets_met(m):
    return (all(m[p]["mre"] < 0.02 for p in LABEL_NAMES[:3])
            and all(m[p]["mre"] < 0.03 for p in LABEL_NAMES[3:]))


def write_docs(args, runs, results, ckpts, ood, ood_fill, bench, elapsed, floor, groups):
    from amfe.training.plots import plot_learning_curves

    ens, shp = ckpts["ensemble"], ckpts["bonds"]
    plot_learning_curves({"Custom Net": ens["history"][0], "LeNet-5": ckpts["lenet5"]["history"],
                          "AlexNet": ckpts["alexnet"]["history"], "VGG": ckpts["vgg"]["history"]},
                         os.path.join(DOCS, "surrogate_curves.png"),
                         f"{args.epochs} epochs, seed 0, amfe's recipe")
    plot_learning_curves({"Custom Net + bond image, ensemble": shp["history"]},
                         os.path.join(DOCS, "surrogate_ensemble.png"),
                         f"the shipped ensemble: 5 members, seeds 0-4, {args.bond_epochs} epochs")
    plot_learning_curves({"Custom Net, paper's recipe": ckpts["paper"]["history"]},
                         os.path.join(DOCS, "surrogate_paper_recipe.png"),
                         "Custom Net, the paper's recipe (80 epochs, constant lr, no augmentation)")
    size_mb = os.path.getsize(round1_model(args)) / 1e6
    ms = results["bonds"]["metrics"]
    met = _targets_met(ms)
    L = []
    w = L.append
    w("# The CNN surrogate, round 1: the paper's networks compared, and round 1's model card")
    w("")
    w("**The surrogate as amfe ships it now is in [surrogate.md](surrogate.md) (model card: "
      "[model_card.md](model_card.md)).** This page is round 1's comparison of the paper's "
      "networks and round 1's model card, kept as the baseline.")
    w("")
    train_min = sum(float(ck["training"]["seconds"]) for ck in ckpts.values()) / 60
    w("Written by `python -m run.train.train_surrogate` "
      f"({time.strftime('%Y-%m-%d', time.gmtime())} on this machine: the trainings took "
      f"{train_min:.0f} min of one-thread time, two at a time; the rest of the run "
      f"{elapsed / 60:.1f} min); "
      "every number below comes from that run. Networks and training: `training/` "
      "(docstrings); commands: `amfe train`, `amfe predict`.")
    w("")
    w("## Held-out comparison (the paper's section 7, on amfe's labels)")
    w("")
    te = shp["metrics"].get("test", {})
    w(f"Trained on `{args.train}` ({shp['dataset']['n_train']} training and "
      f"{shp['dataset']['n_validation']} validation beds, split seed 0), evaluated on the "
      f"held-out `{args.test}` ({te.get('n', '?')} beds, another data-set seed). Mean relative "
      "error |pred - true| / |true| in %, then R^2, per property. Training time: one torch "
      "thread, two trainings at a time on the 2-core machine. Inference: ms per bed, the "
      "whole held-out set in one batch, one thread, all members included. Input: the "
      "volume-fraction image (3 x 20 x 20, the paper's), or that and the bond-stiffness image "
      "on the same cells (6 x 20 x 20, amfe.dataset.bondimage: per cell the sum of k_n L^2 / (E V) "
      "over its bonds).")
    w("")
    w("| network | input | parameters | training | ms / bed | "
      + " | ".join(LABEL_NAMES) + " | " + " | ".join(f"R^2 {p}" for p in LABEL_NAMES) + " |")
    w("|---|---|---|---|---|" + "---|" * 12)
    for n in ("custom", "lenet5", "alexnet", "vgg", "ensemble", "paper", "custom_bonds", "bonds"):
        r = results[n]
        m = r["metrics"]
        params = f"{r['params']:,}" + (f" x {r['members']}" if r["members"] > 1 else "")
        inp = "+".join("volume fraction" if k == "fill" else "bond image" for k in r["inputs"])
        name = f"**{r['description']}**" if n == "bonds" else r["description"]
        w(f"| {name} | {inp} | {params} | {r['train_seconds'] / 60:.1f} min | "
          f"{r['ms_per_bed']:.3f} | " + " | ".join(pct(m[p]["mre"]) for p in LABEL_NAMES)
          + " | " + " | ".join(f"{m[p]['r2']:.3f}" for p in LABEL_NAMES) + " |")
    w("")
    w("Targets of the issue: under 2 % for each modulus and under 3 % for each Poisson ratio. "
      + ("**The shipped model meets them.**" if met else
         "**They are not met** by any model here (see 'Why' below and "
         "[surrogate_diagnosis.md](surrogate_diagnosis.md)); the shipped model is the best "
         "one measured.")
      + " The paper reports under 4 % on average over the six with Custom Net on its own "
      "data set; the shipped model's average here is "
      f"{pct(np.mean([ms[p]['mre'] for p in LABEL_NAMES]))} %.")
    full = [g for g in groups if g[0].startswith("no skips")]
    if full and not met:
        name, n, e = full[0]
        w("")
        w(f"Where the beds are whole the targets are within reach: on the {n} held-out beds "
          f"with {name} the shipped model's errors are "
          + ", ".join(f"{p} {pct(v)} %" for p, v in zip(LABEL_NAMES, e))
          + ". The error is in the beds with holes (table 'Where the error is' below).")
    w("")
    w("### What helped (held-out mean relative error %, same test beds)")
    w("")
    w("| model | " + " | ".join(LABEL_NAMES) + " |")
    w("|---|" + "---|" * 6)
    rows = [("Custom Net, paper's recipe (80 epochs, constant lr, no augmentation)",
             results["paper"]["metrics"]),
            (f"Custom Net, {args.epochs} epochs, cosine lr, no augmentation",
             results["noaug"]["metrics"]),
            (f"Custom Net, amfe's recipe ({args.epochs} epochs, cosine lr, d4 augmentation)",
             results["custom"]["metrics"]),
            ("  the same with linear moduli (standardised Ex, Ey, Ez instead of their logs)",
             results["linear"]["metrics"]),
            ("  + test-time averaging over the 4 mirror images (4 passes)",
             results["custom"]["metrics_tta"]),
            ("  ensemble of 5 seeds", results["ensemble"]["metrics"]),
            ("  + the bond-stiffness image as 3 more input channels (one network)",
             results["custom_bonds"]["metrics"]),
            (f"  ensemble of 5 seeds with the bond image, {args.bond_epochs} epochs "
             "(**shipped**)", ms),
            (f"  + test-time averaging (20 passes, {results['bonds']['ms_per_bed_tta']:.2f} "
             "ms per bed, not shipped)", results["bonds"]["metrics_tta"])]
    for name, m in rows:
        w(_mre_row(name, m))
    w("")
    w("### Error versus training-set size (Custom Net, volume fraction, amfe's recipe, "
      "validation beds fixed)")
    w("")
    w("| training beds | " + " | ".join(LABEL_NAMES) + " |")
    w("|---|" + "---|" * 6)
    for n, k in (("n400", 400), ("n800", 800), ("custom", ens["dataset"]["n_train"])):
        w(_mre_row(str(k), results[n]["metrics"]))
    e = [np.mean([results[n]["metrics"][p]["mre"] for p in LABEL_NAMES[:3]])
         for n in ("n400", "n800", "custom")]
    slope = np.polyfit(np.log([400, 800, ens["dataset"]["n_train"]]), np.log(e), 1)[0]
    w("")
    need = ens["dataset"]["n_train"] * (0.02 / e[2]) ** (1 / slope) if slope < -0.05 else None
    w(f"The moduli's mean error falls as N^{slope:.2f} with the number N of training beds"
      + (f": at that rate 2 % would need about {need:,.0g} beds." if need else "."))
    w("")
    w("### Why the targets are missed" if not met else "### What limits the error")
    w("")
    fl = floor["mean_rel_std"]
    w(f"- Not label noise. {floor['n_beds']} parameter draws x {floor['n_copies']} beds that "
      "differ only in the lattice seed (particle enlargements and jitter; same scan path and "
      "skipped pieces, images alike to "
      f"{100 * floor['mean_density_rel_std']:.2f} % in density) scatter in their labels by "
      + ", ".join(f"{p} {100 * v:.2f} %" for p, v in zip(LABEL_NAMES, fl))
      + " (relative standard deviation, mean over the draws): a perfect image-based model "
      "would stay well under the targets.")
    w("- The neck size. 0.03 mm volume-fraction cells barely show how large the sintered "
      "necks are, yet the bond springs (paper eqs. 1-5) and so the moduli hang on it: the "
      "bond-stiffness image cuts the moduli's error by about a third (table above; "
      "[surrogate_diagnosis.md](surrogate_diagnosis.md)).")
    w(f"- Data. The error falls slowly with the number of training beds (table above); with "
      f"{ens['dataset']['n_train']} beds of 0.6 mm (below the representative volume: "
      "[report.md](report.md) finds the constants within 5 % of their large-bed limit only "
      "from about 2.4 mm) each label carries the particular arrangement of a few paths "
      "between holes, which no image at this resolution shows.")
    w("- Where the error is: the shipped model's held-out mean relative error % by kind of "
      "bed:")
    w("")
    w("| beds | n | " + " | ".join(LABEL_NAMES) + " |")
    w("|---|---|" + "---|" * 6)
    for name, n, e in groups:
        w(f"| {name} | {n} | " + " | ".join(pct(v) for v in e) + " |")
    w("")
    w("  Beds with skipped track pieces and sparsely scanned beds, whose stiffness hangs on "
      "a few bonded paths between holes, carry most of the error.")
    w("")
    w("## Speed")
    w("")
    b = bench
    for (t, n), v in b["batched"].items():
        w(f"- shipped ensemble, batched: {t} thread(s), batch {n}: **{v:.3f} ms per bed**")
    w(f"- one bed in process ({b['bed']['n_particles']} particles): read "
      f"{1e3 * b['bed']['read_bed']:.1f} ms, pixelate {1e3 * b['bed']['pixelate']:.0f} ms, "
      f"bond image {1e3 * b['bed']['bonds']:.0f} ms, predict {1e3 * b['bed']['predict']:.1f} ms "
      f"(model load {1e3 * b['bed']['load_model']:.0f} ms, once)")
    w(f"- `amfe predict bed.h5` as a fresh process: {b['cli']:.2f} s wall, of which "
      f"{b['import_torch']:.2f} s is Python importing torch")
    w("- the paper: 37.24 ms per prediction (Custom Net); the PETSc solve of a `small` bed: "
      "about 1.4 s on one core")
    w("")
    w("## Learning curves")
    w("")
    w("![four networks](surrogate_curves.png)")
    w("")
    w("![the shipped ensemble](surrogate_ensemble.png)")
    w("")
    w("![the paper's recipe](surrogate_paper_recipe.png)")
    w("")
    w("## Round 1's model card (amfe/models/custom_small.pt until round 2; the shipped model "
      "is now [model_card.md](model_card.md))")
    w("")
    w(f"- Custom Net (training/nets.py, same padding) on 6 x 20 x 20 inputs: the 3 layers of "
      "the volume-fraction image, then the 3 of the bond-stiffness image; "
      f"{shp['n_parameters']:,} parameters per member, 5 members trained with seeds "
      f"{shp['member_seeds']}, stored in one checkpoint ({size_mb:.2f} MB) of plain tensors "
      "and numbers (`torch.load(weights_only=True)`). The paper's Custom Net on its 3 x 20 x "
      f"20 input has {results['custom']['params']:,}.")
    w(f"- Data: `{args.train}`, sha256 of its input images and labels "
      f"`{shp['dataset']['sha256']}` (in the checkpoint). Made with:")
    w("")
    w("```bash")
    w("source run/env.sh")
    w(data_command(args.train))
    w(data_command(args.test) + "   # the held-out test set")
    w("```")
    w("")
    w("(Files made before the bond image existed get it with `.venv/bin/amfe dataset "
      "--add-bond-images DATA.h5`, which regenerates each bed from its seed: about 0.05 s "
      "per bed, no solve.)")
    w("")
    w("- Trained (exactly what the pipeline ran):")
    w("")
    w("```bash")
    w(shlex.join(command(args, "bonds", runs["bonds"][1])))
    w("```")
    w("")
    tr = shp["training"]
    w(f"- Recipe: Adam (lr {tr['lr']:g}, cosine decay to 0), batch {tr['batch_size']}, "
      f"{tr['epochs']} epochs, MSE on standardised labels (log for Ex, Ey, Ez), random mirror "
      "and x<->y transpose augmentation (labels permuted for the transpose), train/validation "
      f"split {100 * (1 - tr['val_fraction']):.0f}/{100 * tr['val_fraction']:.0f} by split seed "
      f"{tr['split_seed']}; prediction: the mean of the five members.")
    px = shp["pixelation"]
    w(f"- Pixelation stored with it: cells {' x '.join(f'{1e3 * c:g}' for c in px['image_cell'])}"
      f" mm, sample spacing {1e6 * px['image_spacing']:g} um, box 0 to "
      f"{' x '.join(f'{1e3 * c:g}' for c in px['bed_size'])} mm; `amfe predict` images a "
      "bed exactly so (both images).")
    w("- Held-out errors per property (shipped ensemble):")
    w("")
    w("| | " + " | ".join(LABEL_NAMES) + " |")
    w("|---|" + "---|" * 6)
    for key, name, f in (("mre", "mean relative error %", pct),
                         ("median_re", "median relative error %", pct),
                         ("p95_re", "95th percentile %", pct),
                         ("max_re", "worst bed %", pct),
                         ("r2", "R^2", lambda v: f"{v:.4f}")):
        w(f"| {name} | " + " | ".join(f(ms[p][key]) for p in LABEL_NAMES) + " |")
    w("")
    sp = shp["spread"]
    fr = shp.get("fill_range") or {}
    w(f"- Out-of-distribution flag: {sp['definition']}; threshold "
      f"{sp['threshold']:.3f} ({sp['percentile']:g}th percentile on the validation beds). "
      f"Fill check: {fr.get('definition', 'none')}; range {fr.get('lo', 0):.3f} - "
      f"{fr.get('hi', 0):.3f}. A bed is flagged when either says so.")
    w("")
    w("## The flag: caught versus missed")
    w("")
    w(f"A bed has a large error when any of its six properties is off by more than "
      f"{100 * LARGE_ERROR:.0f} % (also shown: 20 %, since the in-distribution errors are "
      "themselves several %). Caught: large error and flagged (by the spread or the fill "
      "check); missed: large error, not flagged; false alarm: flagged without a large error. "
      "`amfe predict --fallback` solves the flagged beds with PETSc.")
    w("")
    if ood.get("failed_ood"):
        w(f"({ood['failed_ood']} out-of-distribution beds failed to generate or solve and are "
          "left out.)")
        w("")
    w("The worst property's relative error per bed (its median over the beds, then over the "
      "flagged and the unflagged beds alone) and the median spread score are given too.")
    w("")
    w("| beds | limit | n | flagged | large | caught | missed | false alarms | median max error % "
      "| flagged | unflagged | median score |")
    w("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ood["rows"]:
        w(f"| {r['set'].strip()} | {100 * r['limit']:.0f} % | {r['beds']} | {r['flagged']} | "
          f"{r['large']} | {r['caught']} | {r['missed']} | {r['false_alarms']} | "
          f"{100 * r['median_max_error']:.1f} | {_pct1(r['median_error_flagged'])} | "
          f"{_pct1(r['median_error_unflagged'])} | {r['median_score']:.2f} |")
    w("")
    tot = {r["set"].strip(): r for r in ood_fill["rows"] if r["limit"] == 0.20}
    o = tot.get("out of distribution")
    if o:
        w(f"For comparison, the volume-fraction-only ensemble on the same out-of-distribution "
          f"beds at 20 %: {o['large']} large errors, {o['caught']} caught, {o['missed']} "
          f"missed, {o['false_alarms']} false alarms.")
        w("")
    w("Out-of-distribution variants (run/train/make_ood.py): enl_low enlargement U(1.02, 1.03-1.05); "
      "enl_high U(1.10, 1.15-1.18); sparse scanned fraction 0.2-0.3; rot0_45 layer rotation 0 "
      "or 45 degrees; wide tracks 0.2-0.3 mm; jitter +/-0.06 R (training: U(1.05, 1.06-1.14), "
      "0.35-1, 67 or 90 degrees, 0.05-0.15 mm, 0.025 R).")
    w("")
    with open(os.path.join(DOCS, "surrogate_round1.md"), "w") as fh:
        fh.write("\n".join(L) + "\n")
