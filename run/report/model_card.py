"""The shipped surrogate's model card, docs/model_card.md, from the checkpoint and held-out beds.

    .venv/bin/python -m run.report.model_card --test /work/data/heldout_seed4_1000.h5 \
        --test /work/data/heldout_seed2_300.h5 --ood /work/data/small_ood.h5 \
        --baseline /work/data/exp/custom_small_round1.pt --previous /work/data/exp/initial.pt

The continuum springs' model's card (docs/model_card_continuum.md; its --also lines are
the held-out sets' rebuilds and the calibration, as the card shows them):

    L=$(for f in labels/small_continuum_seed47100_labels_0000*.h5; do echo -n "--labels $f "; done)
    .venv/bin/python -m run.report.model_card --model amfe/models/multiscale_small_continuum.pt \
        --test /work/labels47c/small_continuum_s47200_test.h5 --init-commit 5aa7ca8 \
        --init-model amfe/models/multiscale_small.pt --init-card docs/model_card.md $L \
        --also "..." -o docs/model_card_continuum.md

Everything comes from the checkpoint (architecture, members and seeds, data
set hash and split, recipe) and from evaluating it here: errors per property
and per kind of bed on each held-out file (run/train/eval_surrogate.py's groups),
batched speed on one thread, and the out-of-distribution flag's caught and
missed large errors (run/train/train_surrogate.py's ood_report). --baseline and
--previous add the same rows for round 1's shipped model and the one shipped
before, for comparison.
"""
import argparse
import os
import shlex
import sys
from types import SimpleNamespace

from run.common import ROOT, parser  # noqa: E402

OUT = os.path.join(ROOT, "docs", "model_card.md")
MODEL = "amfe/models/multiscale_small.pt"


def train_commands(ck, init_path=None, model=MODEL):
    """The `amfe train` lines that made each member, and the merge that made the ensemble.

    A fine-tuned model (``ck["init"]``) gets `--init` lines (the network options come from
    the initial model, ``init_path`` where it is kept) after the initial model's own lines.
    """
    tr, data, init = ck["training"], ck["dataset"]["path"], ck.get("init")
    common = ["--epochs", str(tr["epochs"]), "--batch-size",
              str(tr["batch_size"]), "--lr", f"{tr['lr']:g}", "--schedule", tr["schedule"],
              "--augment", tr["augment"], "--split-seed", str(tr["split_seed"]), "--threads", "1"]
    common += ["--loss", tr["loss"]] if tr.get("loss", "mse") != "mse" else []
    common += (["--val-fraction", f"{tr['val_fraction']:g}"]
               if tr.get("val_fraction", 0.2) != 0.2 else [])
    if init:
        return _member_lines(ck, data, common, lambda k: ["--init", init_path or init["path"],
                                                          "--init-member", str(init["member"][k])],
                             model)
    common = ["--arch", ck["arch"], *common, "--inputs", ",".join(ck["inputs"])]
    common += [a for k, v in ck["arch_args"].items() if k == "width"
               for a in ("--width", f"{v:g}")]
    common += ["--linear-moduli"] if not tr.get("log_moduli", True) else []
    common += ["--log-poisson", ",".join(tr["log_poisson"])] if tr.get("log_poisson") else []
    return _member_lines(ck, data, common, lambda k: [], model)


def _member_lines(ck, data, common, extra, model=MODEL):
    stem = "tuned" if ck.get("init") else "member"
    parts = [f"/work/data/exp/{stem}{s}.pt" for s in ck["member_seeds"]]
    lines = [shlex.join([".venv/bin/amfe", "train", data, *common, *extra(k), "--seed", str(s),
                         "-o", p])
             for k, (s, p) in enumerate(zip(ck["member_seeds"], parts))]
    test = ["--test", ck["metrics"]["test"]["path"]] if "test" in ck["metrics"] else []
    tta = ["--tta", ck["tta"]] if ck.get("tta", "none") != "none" else []
    lines.append(shlex.join([".venv/bin/python", "-m", "run.train.merge_members", *parts, "--data", data,
                             *test, *tta, "-o", model]))
    return lines


def error_rows(metrics):
    from amfe.vocab import LABEL_NAMES
    rows = ["| | " + " | ".join(LABEL_NAMES) + " |", "|---|" + "---|" * len(LABEL_NAMES)]
    for key, name in (("mre", "mean relative error %"), ("median_re", "median %"),
                      ("p95_re", "95th percentile %"), ("max_re", "worst bed %")):
        rows.append(f"| {name} | " + " | ".join(f"{100 * metrics[p][key]:.2f}"
                                                for p in LABEL_NAMES) + " |")
    rows.append("| R^2 | " + " | ".join(f"{metrics[p]['r2']:.4f}" for p in LABEL_NAMES) + " |")
    return rows


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--model", default=os.path.join(ROOT, MODEL))
    ap.add_argument("--test", action="append", required=True, help="held-out data set (repeat)")
    ap.add_argument("--ood", help="out-of-distribution data set of run/train/make_ood.py")
    ap.add_argument("--baseline", help="another checkpoint to compare with (round 1's model)")
    ap.add_argument("--previous", help="the model shipped before, to compare with")
    ap.add_argument("--run-count", type=int, default=12000,
                    help="the --count of the data-set run the training file is a prefix of")
    ap.add_argument("--init-commit", default="5991b88",
                    help="for a fine-tuned model: the commit whose amfe/models/"
                         "multiscale_small.pt was the initial model")
    ap.add_argument("--init-model", default=MODEL,
                    help="for a fine-tuned model: the file, in that commit, it started from")
    ap.add_argument("--init-card", default="docs/model_card.md",
                    help="where that commit describes the initial model")
    ap.add_argument("--labels", action="append", metavar="TABLE.h5",
                    help="the committed label tables (labels/, repeat) the training data set "
                         "is rebuilt from: the card then gives the fresh-clone command "
                         "`amfe dataset --from-labels` instead of the labelling run")
    ap.add_argument("--also", action="append", default=[], metavar="COMMAND",
                    help="a command line appended to the card's commands (repeat): how the "
                         "held-out sets are rebuilt, the intervals' calibration")
    ap.add_argument("-o", "--output", default=OUT)
    args = ap.parse_args(argv)
    import torch
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.data import read_rows
    from amfe.training.predict import Surrogate
    from run.bench.surrogate import bench_batched
    from run.train.eval_surrogate import evaluate, table
    from run.train.train_surrogate import LARGE_ERROR, ood_report
    from amfe.training.train import evaluate_file

    torch.set_num_threads(1)
    ck = load_checkpoint(args.model)
    sur = Surrogate(ck, args.model, backend="torch")   # timed on torch threads below
    models = {"shipped": args.model,
              **({"shipped before": args.previous} if args.previous else {}),
              **({"round 1": args.baseline} if args.baseline else {})}
    L = []
    w = L.append
    tr, ds = ck["training"], ck["dataset"]
    name = os.path.relpath(os.path.abspath(args.model), ROOT)
    w(f"# Model card: {name}")
    w("")
    springs = sur.springs
    role = ("The model of `amfe predict --springs continuum` for beds of its size "
            "(`training/shipped.py`), whose labels are solved with the continuum springs (issue "
            "47, docs/model.md section 11); for the paper springs' models, " if
            springs["name"] == "continuum" else "The default model of `amfe predict` for beds "
            "of its size (`training/shipped.py`); ")
    w(f"Written by `python -m run.report.model_card` (the command is in its docstring). {role}"
      "issue 13's measurements and the models it was chosen from "
      "are in [surrogate_scaling.md](surrogate_scaling.md), a summary in "
      "[surrogate.md](surrogate.md); round 1's networks in [surrogate_round1.md](surrogate_round1.md).")
    w("")
    w("## What it is")
    w("")
    w("- Labels: " + ("label rule 2 (docs/model.md, section 5)." if ck.get("label_rule", 1) >= 2
                      else "trained on label rule 1, converted. Its training labels are "
                      "rule 1's (the largest bonded piece, V = the hull of its centres); "
                      "`amfe predict` converts each bed's moduli to rule 2 (the load-carrying "
                      "pieces, V = the bed's box) by V_hull / V_box of that bed "
                      "(`training/predict.py`, exact where rule 2 keeps the same piece; the "
                      "Poisson ratios do not move). The held-out errors below are on rule-1 "
                      "labels; against rule-2 labels see docs/datasets.md, \"Label rules\"."))
    if springs["name"] == "continuum":
        w(f"- Springs of the labels: continuum, fit version {springs['version']} (alpha "
          f"{springs['alpha']:.5g}, beta_n {springs['beta_n']:.5g}, beta_t "
          f"{springs['beta_t']:.5g}; `amfe/models/springs_continuum.json`): the labels are "
          "`amfe homogenize --springs continuum`'s, so a new fit needs new labels and a new "
          "model (tests/test_continuum_surrogate.py fails when they differ).")
    w(f"- {len(ck['members'])} members of the multi-scale net (`training/multiscale.py`, "
      f"arguments {ck['arch_args']}), {ck['n_parameters']:,} parameters each, seeds "
      f"{ck['member_seeds']}; {os.path.getsize(args.model) / 1e6:.2f} MB of plain tensors "
      "(`torch.load(weights_only=True)`). Prediction: the members' mean"
      + {"none": ".", "flips": ", each member's averaged over the bed's four mirror images "
         "(test-time averaging: the six constants do not change when a bed is mirrored in x "
         "or y; `--tta flips` of run/train/merge_members.py).",
         "d4": ", each member's averaged over the eight symmetries of the square."}[
          ck.get("tta", "none")])
    w(f"- Input: {' x '.join(map(str, ck['image_shape']))} images, "
      f"{' then '.join(ck['inputs'])} (volume fraction and bond stiffness per cell and layer), "
      f"pixelated by `amfe predict` exactly as the training data (cells "
      f"{' x '.join(f'{1e3 * c:g}' for c in ck['pixelation']['image_cell'])} mm, box "
      f"{' x '.join(f'{1e3 * c:g}' for c in ck['pixelation']['bed_size'])} mm).")
    init = ck.get("init")
    if init:
        ids = init["dataset"]
        w(f"- Fine-tuned (`amfe train --init`): its members started from the members "
          f"{init['member']} of `{args.init_model}` as shipped in commit {args.init_commit} (seeds "
          f"{init['member_seeds']}; its card: `git show {args.init_commit}:{args.init_card}`), "
          f"which had been {'fine-tuned' if init['training'].get('init') else 'trained'} on "
          f"{ids['n_train']} beds of the data-set seed {ids['seed']} "
          f"(`{os.path.basename(str(ids['path']))}`, sha256 `{ids['sha256']}`)"
          + ("; where that model started is in its card." if init["training"].get("init")
             else "."))
    w(f"- Data: `{os.path.basename(ds['path'])}`, the first {ds['n_ok']} records of the "
      f"data-set seed {ds['seed']} run (`{ds['scale']}` scale; docs/datasets.md), "
      f"{ds['n_train']} training and {ds['n_validation']} validation beds "
      f"(split seed {tr['split_seed']}); sha256 of the images and labels `{ds['sha256']}`.")
    loss = {"mse": "MSE", "l1": "L1 (mean absolute)"}[tr.get("loss", "mse")]
    w(f"- Recipe: Adam, lr {tr['lr']:g} ({tr['schedule']}), batch {tr['batch_size']}, "
      f"{tr['epochs']} epochs, {loss} loss on log-standardised moduli"
      + "".join(f" and {n}" for n in tr.get("log_poisson", [])) + f", {tr['augment']} augmentation; "
      f"{tr['seconds'] / 60:.0f} min of one-thread training for both members"
      + (" (the fine-tuning; the initial model's took longer, see its card)." if init else "."))
    w("- Made with:")
    w("")
    w("```bash")
    if args.labels:   # from a fresh clone: the committed tables, no solve (docs/datasets.md)
        tables = [os.path.relpath(t, ROOT) for t in args.labels]
        w("# in a clone of amfe after `bash run/setup.sh`; rebuilds the training data set "
          "bit for bit, solving nothing")
        w(shlex.join([".venv/bin/amfe", "dataset", "--from-labels", *tables, "-o", ds["path"]]))
    else:
        run_file = f"/work/data/train_seed{ds['seed']}_{args.run_count}.h5"
        w(f"mpirun -n 2 .venv/bin/amfe dataset -o {run_file} --count {args.run_count} "
          f"--seed {ds['seed']} --scale {ds['scale']} --solver auto     # resumable")
        w(f"amfe dataset --prefix-of {run_file} -o {ds['path']} --count {ds['n_ok']}")
    init_path = None
    if init:
        init_path = "/work/data/exp/initial.pt"
        w(f"git show {args.init_commit}:{args.init_model} > {init_path}")
    L.extend(train_commands(ck, init_path, name))
    L.extend(args.also)
    w("```")
    w("")
    w("## Held-out errors")
    cache = {}
    for test in args.test:
        m, _, _ = evaluate_file(sur, test)
        w("")
        w(f"`{os.path.basename(test)}` ({m['n']} beds, a data-set seed never trained on):")
        w("")
        L.extend(error_rows(m))
        results = {name: {test: evaluate(path, test, cache)} for name, path in models.items()}
        w("")
        L.extend(table(results, test).splitlines()[2:])
    conf = ck.get("conformal")
    if conf:   # issue 34: split conformal intervals, per bed size, checked on the held-out beds
        from run.train.calibrate_intervals import coverage_report
        w("")
        w("## Intervals")
        w("")
        w(f"Split conformal intervals (`training/conformal.py`, `run/train/calibrate_intervals.py`) at "
          f"a nominal coverage of {100 * conf['coverage']:g} % per constant, calibrated per bed "
          "size on held-out beds that no training run or model choice used: "
          + "; ".join(f"{key} mm: {c['n']} beds" for key, c in conf["sizes"].items())
          + f". A bed whose interval is wider than {100 * conf['flag_half_width']:g} % "
          "(relative half-width) is flagged. Measured coverage on the held-out beds above:")
        for test in args.test:
            w("")
            L.extend(coverage_report(sur, test).splitlines())
    w("")
    w("## Speed")
    w("")
    w(f"`Surrogate.predict` on the held-out images, best of 5, one torch thread ({os.cpu_count()} "
      f"cores here, load average {os.getloadavg()[0]:.1f} before; the issue's limit is 1 ms "
      "per bed batched):")
    w("")
    images, _ = read_rows(args.test[0], None, sur.inputs)
    for (t, n), v in bench_batched(sur, images, threads=(1,), batches=(1, 100, None)).items():
        w(f"- {t} thread, batch {n}: **{v:.3f} ms per bed**")
    w("")
    if args.ood:
        w("## The flag: caught versus missed")
        w("")
        ood = ood_report(SimpleNamespace(test=args.test[0], ood=args.ood), ck, log=lambda s: None)
        w(f"Flag threshold {ood['threshold']:.3f} ({ck['spread']['percentile']:g}th percentile "
          f"of the spread score on the validation beds) or the fill check. A large error: the "
          f"worst of the six over {100 * LARGE_ERROR:.0f} % or 20 %.")
        w("")
        w("| beds | limit | n | flagged | large | caught | missed | false alarms |")
        w("|---|---|---|---|---|---|---|---|")
        for r in ood["rows"]:
            w(f"| {r['set'].strip()} | {100 * r['limit']:.0f} % | {r['beds']} | {r['flagged']} | "
              f"{r['large']} | {r['caught']} | {r['missed']} | {r['false_alarms']} |")
        w("")
    with open(args.output, "w") as f:
        f.write("\n".join(L) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
