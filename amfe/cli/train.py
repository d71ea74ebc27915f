"""`amfe train DATA.h5 -o MODEL.pt`: train a CNN surrogate on a data set (paper section 7).

    amfe train data.h5 --arch custom -o model.pt [--epochs 80] [--seed 0] [--members 5]
                       [--test heldout.h5]

Adam, batch 100, 80 epochs, MSE on normalised labels, an 80/20
train/validation split by --split-seed; every member seeded. Prints the loss
and the validation error per property each epoch under a progress bar, writes
the learning curve (PNG) beside the model and the checkpoint (plain tensors
and numbers, loaded with torch.load(weights_only=True)). See training/.

Every option, the model and curve paths and the data sets are checked before
training starts, so a bad -o or --test costs nothing.
"""
import os
import sys
from types import SimpleNamespace

from amfe.cli.options import (
    nonnegative_float,
    nonnegative_int,
    positive_float,
    positive_int,
    thread_count,
)
from amfe.errors import AmfeError
from amfe.io.paths import check_output

# amfe.training.train.TrainConfig's defaults, without importing torch to build the parser
# (tests/test_training.py checks that they agree).
DEFAULTS = SimpleNamespace(arch="custom", epochs=80, batch_size=100, lr=1e-3, schedule="constant",
                           loss="mse",
                           weight_decay=0.0, seed=0, members=1, split_seed=0, val_fraction=0.2,
                           augment="none", flag_percentile=95.0, inputs=("fill",))


def register(sub):
    from amfe.training import ARCH_NAMES, AUGMENTATIONS, LOSSES, SCHEDULES

    d = DEFAULTS
    p = sub.add_parser("train", help="train a CNN surrogate on a data set (checkpoint + curve)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("data", metavar="DATA.h5", help="data set made by amfe dataset")
    p.add_argument("-o", "--output", metavar="MODEL.pt", required=True, help="checkpoint to write")
    p.add_argument("--arch", choices=list(ARCH_NAMES), default=d.arch,
                   help="network (default custom: the paper's Custom Net)")
    p.add_argument("--epochs", type=positive_int, default=d.epochs, help=f"default {d.epochs}")
    p.add_argument("--batch-size", type=positive_int, default=d.batch_size,
                   help=f"default {d.batch_size}")
    p.add_argument("--lr", type=positive_float, default=d.lr,
                   help=f"Adam learning rate (default {d.lr:g})")
    p.add_argument("--schedule", choices=SCHEDULES, default=d.schedule,
                   help="learning rate: constant (the paper's) or cosine decay to 0")
    p.add_argument("--loss", choices=LOSSES + ("constants",), default=d.loss,
                   help="on the normalised labels: mse (the paper's) or l1 (aims at the median); "
                        "--head stiffness: mse (C's 21 entries) or constants (the nine's mean "
                        "relative error)")
    p.add_argument("--head", choices=("constants", "stiffness"), default="constants",
                   help="what the network outputs: the six constants (default) or the full "
                        "stiffness C (21 Cholesky outputs; fine-tunes --init's multiscale net, "
                        "amfe.training.stiffness_train)")
    p.add_argument("--nu-weight", type=positive_float, default=1.0,
                   help="--head stiffness --loss constants: weight of the Poisson ratios' "
                        "relative errors against the moduli's (default 1)")
    p.add_argument("--weight-decay", type=nonnegative_float, default=d.weight_decay,
                   help="Adam weight decay")
    p.add_argument("--seed", type=nonnegative_int, default=d.seed,
                   help="seed of the first member (member k: seed + k; default 0)")
    p.add_argument("--members", type=positive_int, default=d.members,
                   help="ensemble size (default 1); >1 calibrates the out-of-distribution flag")
    p.add_argument("--split-seed", type=nonnegative_int, default=d.split_seed,
                   help="seed of the train/validation split (default 0)")
    p.add_argument("--val-fraction", type=nonnegative_float, default=d.val_fraction,
                   help="validation share (default 0.2, the paper's 400 of 2000)")
    p.add_argument("--linear-moduli", action="store_true",
                   help="standardise Ex, Ey, Ez themselves instead of their logarithms")
    p.add_argument("--log-poisson", metavar="NAMES", default="",
                   help="comma list of Poisson ratios (nu_yz, nu_xz, nu_xy) to standardise as "
                        "logarithms too; every training label must be positive (default none)")
    p.add_argument("--augment", choices=AUGMENTATIONS, default=d.augment,
                   help="label-preserving symmetries: flips (mirror x, y) or d4 (also swap x, y)")
    p.add_argument("--tta", choices=("none", "flips", "d4"), default="none",
                   help="test-time augmentation: predict the mean over a bed's four mirror images "
                        "(flips) or its eight symmetric images (d4); default none")
    p.add_argument("--flag-percentile", type=positive_float, default=d.flag_percentile,
                   help="ensemble flag threshold: this percentile of the validation spread "
                        "score (default 95)")
    p.add_argument("--inputs", default=",".join(d.inputs), metavar="KINDS",
                   help="image kinds stacked as input channels: fill (volume fraction, the "
                        "paper's) or fill,bonds (plus the bond-stiffness image; the data set "
                        "needs /bond_images) (default fill)")
    p.add_argument("--width", type=positive_float,
                   help="custom/alexnet/vgg/multiscale: channel-count multiplier (default 1)")
    p.add_argument("--convs", type=positive_int,
                   help="custom: 3x3 convolutions per block (default 1; more: a deeper net)")
    p.add_argument("--hidden", type=positive_int, nargs="+",
                   help="alexnet/vgg/multiscale: widths of the hidden FC layers (default 4096 "
                        "4096; multiscale 512 256 128)")
    p.add_argument("--batch-norm", action="store_true", help="vgg: batch normalisation")
    p.add_argument("--init", metavar="MODEL.pt",
                   help="fine-tune: start from this checkpoint's weights (amfe train's or a merged "
                        "model), keeping its network, inputs and label normalisation; member k "
                        "starts from its member --init-member + k")
    p.add_argument("--init-member", type=nonnegative_int, default=0, metavar="K",
                   help="with --init: the first member to start from (default 0)")
    p.add_argument("--max-train", type=positive_int, default=None, metavar="N",
                   help="train on at most N of the training beds (error versus data size; "
                        "default all)")
    p.add_argument("--test", metavar="HELDOUT.h5",
                   help="also evaluate on this held-out data set (stored in the checkpoint)")
    p.add_argument("--curve", metavar="PNG",
                   help="learning-curve file, .png, .pdf or .svg (default MODEL.png)")
    p.add_argument("--threads", type=thread_count, help="torch CPU threads (default: torch's)")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto",
                   help="where to train: auto (default) is CUDA when torch sees a GPU, else the "
                        "CPU; the checkpoint is saved for the CPU either way")
    p.add_argument("--workers", type=nonnegative_int, default=0,
                   help="DataLoader workers when the data set is read lazily (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or per-epoch lines")
    p.set_defaults(func=run)


def arch_args_of(args):
    out = {}
    if args.width is not None:
        out["width"] = args.width
    if args.hidden:
        out["hidden"] = list(args.hidden)
    if args.batch_norm:
        out["batch_norm"] = True
    if args.convs is not None:
        out["convs"] = args.convs
    return out


CURVE_FORMATS = (".png", ".pdf", ".svg")


def check_paths(args):
    """Refuse bad output paths and unusable data sets before training; returns the curve path."""
    if not str(args.output).endswith(".pt"):
        raise AmfeError(f"the model file should end in .pt, got {args.output}")
    inputs = [args.data, args.test, args.init]
    check_output(args.output, inputs=inputs)
    curve = args.curve or os.path.splitext(args.output)[0] + ".png"
    if os.path.splitext(curve)[1].lower() not in CURVE_FORMATS:
        raise AmfeError(f"--curve {curve}: the learning curve is written as "
                        f"{', '.join(f[1:] for f in CURVE_FORMATS)}; give a file name ending so")
    check_output(curve, inputs=inputs + [args.output], option="--curve")
    return curve


def check_test_set(args, inputs):
    """AmfeError unless the --test data set can be evaluated by a model of the training data,
    and holds what training accepts (amfe.training.guards)."""
    from amfe.training.data import dataset_info

    want = dataset_info(args.data, inputs)["image_shape"]
    info = dataset_info(args.test, inputs)
    if info["image_shape"] != want:
        raise AmfeError(f"--test {args.test} has images of shape "
                        f"{'x'.join(map(str, info['image_shape']))}, the training data "
                        f"{'x'.join(map(str, want))}; give a held-out set of the same scale")
    if info["ok"].size < 2:
        raise AmfeError(f"--test {args.test} has {info['ok'].size} usable record(s); its errors "
                        "and R^2 need at least 2")
    from amfe.training.data import read_rows
    from amfe.training.guards import check_data, check_ok_records

    check_ok_records(args.test, info["ok_nonfinite"])   # what training refuses, before it starts
    images, labels = read_rows(args.test, info["ok"], inputs)
    check_data(args.test, info["ok"], images, labels, info["image_shape"][0] // len(inputs))


# Options that --init takes from the initial checkpoint.
NETWORK_OPTIONS = {"arch": DEFAULTS.arch, "inputs": ",".join(DEFAULTS.inputs), "width": None,
                   "convs": None, "hidden": None, "batch_norm": False, "linear_moduli": False,
                   "log_poisson": ""}


def check_init_options(args):
    """AmfeError when --init comes with an option that would change the network it starts from."""
    if not args.init:
        if args.init_member:
            raise AmfeError("--init-member needs --init MODEL.pt")
        return
    given = [k for k, default in NETWORK_OPTIONS.items() if getattr(args, k) != default]
    if given:
        raise AmfeError(f"--init {args.init} takes the network, its inputs and its label "
                        "normalisation from that checkpoint; drop "
                        + ", ".join("--" + k.replace("_", "-") for k in given))
    if not os.path.isfile(args.init):
        raise AmfeError(f"--init {args.init}: no such file")


def run(args):
    curve = check_paths(args)
    if args.head == "stiffness":
        return run_stiffness(args, curve)
    import torch

    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.metrics import metrics_line
    from amfe.training.plots import plot_learning_curves
    from amfe.training.predict import Surrogate
    from amfe.training.train import TrainConfig, evaluate_file, train_model

    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = TrainConfig(arch=args.arch, arch_args=arch_args_of(args), epochs=args.epochs,
                      batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
                      schedule=args.schedule, loss=args.loss, seed=args.seed, members=args.members,
                      split_seed=args.split_seed, val_fraction=args.val_fraction,
                      log_moduli=not args.linear_moduli, log_poisson=args.log_poisson,
                      augment=args.augment, tta=args.tta,
                      flag_percentile=args.flag_percentile, workers=args.workers,
                      max_train=args.max_train or 0, inputs=args.inputs, device=args.device,
                      init=args.init or "", init_member=args.init_member)
    cfg.check()
    check_init_options(args)
    if args.test:
        check_test_set(args, cfg.inputs)

    def log(line):
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    ckpt = train_model(args.data, cfg, progress=not args.quiet, log=log)
    lines = [f"amfe train: {ckpt['arch']}, {ckpt['n_parameters']:,} parameters, "
             f"{len(ckpt['members'])} member(s), trained in {ckpt['training']['seconds']:.1f} s"]
    val = ckpt["metrics"].get("validation")
    if val:
        lines.append("  validation mean relative error %: " + metrics_line(val))
        lines.append("  validation R^2:                   " + metrics_line(val, "r2", 1, "{:.4f}"))
    if args.test:
        m, _, _ = evaluate_file(Surrogate(ckpt, args.output), args.test)
        ckpt["metrics"]["test"] = dict(m, path=str(args.test))
        lines.append(f"  held-out {args.test} ({m['n']} beds) mean relative error %: "
                     + metrics_line(m))
        lines.append("  held-out R^2: " + metrics_line(m, "r2", 1, "{:.4f}"))
    _write(args.output, save_checkpoint, args.output, ckpt)
    _write(curve, plot_learning_curves, {ckpt["arch"]: ckpt["history"]}, curve,
           f"{ckpt['arch']} on {os.path.basename(args.data)}")
    lines.append(f"wrote {args.output} ({os.path.getsize(args.output) / 1e6:.2f} MB) and {curve}")
    print("\n".join(lines))
    return 0


def _write(path, write, *args):
    """write(*args), an OSError (a full disk) as one line naming ``path``; earlier files stay."""
    try:
        write(*args)
    except OSError as exc:
        raise AmfeError(f"cannot write {path}: {exc.strerror or exc}") from None


def run_stiffness(args, curve):
    """`--head stiffness`: a full-stiffness model (21 Cholesky outputs of C,
    amfe.training.stiffness_train) from --init's network; train, evaluate on --test (the six
    constants), save; 0 on success."""
    check_init_options(args)   # a missing --init: StiffnessConfig.check says so
    import torch

    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.metrics import metrics_line
    from amfe.training.stiffness_train import StiffnessConfig, train_stiffness

    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = StiffnessConfig(init=args.init, init_member=args.init_member, members=args.members,
                          seed=args.seed, epochs=args.epochs, batch_size=args.batch_size,
                          lr=args.lr, schedule=args.schedule, loss=args.loss,
                          split_seed=args.split_seed, val_fraction=args.val_fraction,
                          augment=args.augment, tta=args.tta, max_train=args.max_train or 0,
                          nu_weight=args.nu_weight)

    def log(line):
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    ckpt = train_stiffness(args.data, cfg, log=log)
    lines = [f"amfe train: stiffness head on {ckpt['arch']}, {len(ckpt['members'])} member(s), "
             f"trained in {ckpt['training']['seconds']:.1f} s"]
    if args.test:
        from amfe.training.predict import Surrogate
        from amfe.training.train import evaluate_file
        m, _, _ = evaluate_file(Surrogate(ckpt, args.output), args.test)
        ckpt["metrics"]["test"] = dict(m, path=str(args.test))
        lines.append(f"  held-out {args.test} ({m['n']} beds) mean relative error %: "
                     + metrics_line(m))
    _write(args.output, save_checkpoint, args.output, ckpt)
    lines.append(f"wrote {args.output} ({os.path.getsize(args.output) / 1e6:.2f} MB)")
    print("\n".join(lines))
    return 0
