"""`amfe train DATA.h5 --head stiffness --init MODEL.pt -o OUT.pt`: a full-stiffness model.

The network, inputs and pixelation are --init's (a multiscale checkpoint);
its last layer becomes 21 Cholesky outputs of C (amfe.training.stiffness_train).
The options that train a six-constant model from scratch (--arch, --width,
...) are refused, as with any --init.
"""
import os
import sys


def run_stiffness(args, curve):
    """Train, evaluate on --test (the six constants), save; 0 on success."""
    from amfe.cli.train import _write, check_init_options
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
