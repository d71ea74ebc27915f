"""Fine-tuning a stiffness head (``amfe train --head stiffness --init MODEL.pt``).

A trained six-constant multi-scale model (training/multiscale.py) already
reads a bed's holes and bonds; its last linear layer maps 128 features to
six normalised constants. A stiffness model keeps the trunk and every
hidden layer's weights and replaces that last layer by one with 21 outputs,
the Cholesky factor of C (amfe.training.stiffness). The new layer starts
from a ridge regression of the training beds' Cholesky outputs on the
trunk's features (:func:`init_head`), so the first epoch starts near the
training beds' C (at worst near their mean C) rather than from noise, and a
short fine-tune of the whole net follows. An ``init`` that is itself a
stiffness model (another bed size, issue 34) keeps its own last layer and
its ``stiffness_scale``: the fine-tune starts from its C, not from a ridge fit.

Loss (``loss``):

- ``constants``: the mean relative error of the nine constants derived from
  C (Ex, Ey, Ez, nu_yz, nu_xz, nu_xy, G_yz, G_xz, G_xy, as
  amfe.model.averages.compliance_and_constants), i.e. the score itself;
- ``mse``: the mean squared difference of C's 21 entries in the normalised
  unit (amfe.training.stiffness_fit.stiffness_loss).

Mirror / x <-> y augmentation moves C as a tensor (:func:`augment_tensor`,
the batched form of amfe.training.stiffness.augment_stiffness). The
checkpoint is an ordinary amfe surrogate checkpoint (arch ``multiscale``
with ``outputs`` 21) plus ``head`` "stiffness", ``outputs`` "cholesky21"
and ``stiffness_scale`` [Pa], so ``amfe predict`` and run/train/merge_members.py
take it as they take a six-constant model (amfe.training.stiffness_predict).
"""
import math
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from amfe.dataset.parts import label_rule
from amfe.errors import AmfeError
from amfe.training import STIFFNESS_HEAD
from amfe.training.data import dataset_hash, dataset_info, flip_images, read_rows, split_indices
from amfe.training.fillcheck import calibrate_fill
from amfe.training.finetune import check_grid, load_init, widened_fill_range
from amfe.training.nets import build_net, count_parameters
from amfe.training.stiffness import (
    EIG_FLOOR,
    N_CHOLESKY,
    nine_from_stiffness,
    stiffness_from_raw,
    transform_stiffness,
)
from amfe.training.stiffness_fit import read_stiffness, stiffness_loss
from amfe.training.stiffness_predict import is_stiffness
from amfe.training.train import pixelation_of

STIFFNESS_LOSSES = ("constants", "mse")


@dataclass
class StiffnessConfig:
    init: str                   # the six-constant multi-scale checkpoint to start from
    init_member: int = 0        # member k starts from its member init_member + k
    members: int = 1
    seed: int = 0
    epochs: int = 20
    batch_size: int = 100
    lr: float = 5e-4
    schedule: str = "cosine"
    loss: str = "constants"
    split_seed: int = 0
    val_fraction: float = 0.05
    augment: str = "d4"
    tta: str = "flips"
    max_train: int = 0
    ridge: float = 1e-2         # of the last layer's initial fit (features are O(1))
    nu_weight: float = 1.0      # constants loss: weight of the Poisson ratios (moduli: 1)

    def check(self):
        if self.loss not in STIFFNESS_LOSSES:
            raise AmfeError(f"--head stiffness takes --loss {' or '.join(STIFFNESS_LOSSES)}, "
                            f"got {self.loss}")
        if not (self.nu_weight > 0 and self.nu_weight < float("inf")):
            raise AmfeError(f"--nu-weight must be a positive number, got {self.nu_weight}")
        if not self.init:
            raise AmfeError("--head stiffness fine-tunes a trained multi-scale model: give "
                            "--init MODEL.pt")


def raw_of_stiffness(C_norm):
    """The 21 raw outputs (n, 21) float64 whose stiffness_from_raw is C_norm (n, 6, 6), normed."""
    C = torch.as_tensor(np.asarray(C_norm), dtype=torch.float64)
    L = torch.linalg.cholesky(C - EIG_FLOOR * torch.eye(6, dtype=C.dtype))
    d = torch.diagonal(L, dim1=-2, dim2=-1).clamp_min(1e-9)
    inv_softplus = d + torch.log(-torch.expm1(-d))   # log(exp(d) - 1), stable
    L = L - torch.diag_embed(torch.diagonal(L, dim1=-2, dim2=-1)) + torch.diag_embed(inv_softplus)
    rows, cols = np.tril_indices(6)
    return L[:, rows, cols]


def features(net, images, batch_size=256):
    """The inputs of ``net``'s last linear layer (n, features) float64, eval mode."""
    got = []
    hook = net.head[-1].register_forward_hook(lambda m, inp, out: got.append(inp[0].double()))
    net.eval()
    try:
        with torch.inference_mode():
            for s in range(0, images.shape[0], batch_size):
                net(images[s:s + batch_size])
    finally:
        hook.remove()
    return torch.cat(got)


def init_head(net, images, C_norm, ridge=1e-2):
    """Set the last layer to the ridge fit of the beds' raw outputs on their features.

    The features' mean goes to the bias, so with ``ridge`` large the layer
    predicts the raw outputs' mean for every bed (close to the mean C).
    """
    F_ = features(net, images)
    target = raw_of_stiffness(C_norm)
    mu_f, mu_t = F_.mean(0), target.mean(0)
    A, b = F_ - mu_f, target - mu_t
    W = torch.linalg.solve(A.T @ A / len(A) + ridge * torch.eye(A.shape[1], dtype=A.dtype),
                           A.T @ b / len(A)).T
    last = net.head[-1]
    with torch.no_grad():
        last.weight.copy_(W.float())
        last.bias.copy_((mu_t - W @ mu_f).float())


def constants_loss(raw, C_norm, nu_weight=1.0):
    """Mean relative error of the nine constants of the predicted C against C_norm's, the
    three Poisson ratios weighted ``nu_weight`` (a weighted mean: weights sum to one)."""
    pred = nine_from_stiffness(stiffness_from_raw(raw.double()))
    true = nine_from_stiffness(C_norm.double())
    w = torch.ones(9, dtype=pred.dtype)
    w[3:6] = float(nu_weight)
    return (((pred - true).abs() / true.abs()) * (w / w.sum())).sum(dim=1).mean()


def loss_function(cfg):
    """loss(raw (n, 21), C_norm (n, 6, 6)) of the configuration."""
    if cfg.loss == "mse":
        return stiffness_loss
    return lambda raw, C: constants_loss(raw, C, cfg.nu_weight)


def augment_tensor(images, C, mode, generator):
    """Random symmetries of a batch (``mode`` flips or d4), C moved as a tensor alike (batched)."""
    if mode == "none":
        return images, C
    n = images.shape[0]
    draws = torch.randint(0, 2, (n, 3), generator=generator).bool()
    if mode == "flips" or images.shape[-1] != images.shape[-2]:
        draws[:, 2] = False
    images, C = images.clone(), C.clone()
    code = draws[:, 0].long() + 2 * draws[:, 1].long() + 4 * draws[:, 2].long()
    for c in code.unique().tolist():
        idx = (code == c).nonzero().flatten()
        sym = (bool(c & 1), bool(c & 2), bool(c & 4))
        images[idx] = flip_images(images[idx], *sym)
        C[idx] = transform_stiffness(C[idx], *sym)
    return images, C


def stiffness_members(start, n, image_shape):
    """``n`` stiffness nets from the initial members reading images (layers, H, W): every
    weight but a six-constant model's last layer (a stiffness model's is kept)."""
    args = dict(start["arch_args"], outputs=N_CHOLESKY)
    nets = []
    for state in start["states"][:n]:
        net = build_net(start["arch"], image_shape, args)
        own = net.state_dict()
        keep = {k: v for k, v in state.items() if k in own and own[k].shape == v.shape}
        net.load_state_dict(keep, strict=False)
        nets.append(net)
    return nets, args


def fit_member(net, train, val, cfg, seed, log, keep_head=False):
    """Fine-tune one net; train/val: (images float32 tensor, C_norm float64 tensor). History
    dict. keep_head: the net's last layer is already a stiffness head (no ridge fit)."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(int(seed))
    x, C = train
    if not keep_head:
        init_head(net, x, C, cfg.ridge)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    steps = cfg.epochs * math.ceil(x.shape[0] / cfg.batch_size)
    sched = (torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps)
             if cfg.schedule == "cosine" else None)
    loss_fn = loss_function(cfg)
    hist = {"seed": int(seed), "train_loss": [], "val_loss": [], "val_mre": [],
            "epoch_seconds": []}
    hist["val_mre_initial"] = _val_mre(net, val)
    t_start = time.perf_counter()
    for epoch in range(cfg.epochs):
        t0 = time.perf_counter()
        net.train()
        total = 0.0
        for idx in torch.randperm(x.shape[0], generator=gen).split(cfg.batch_size):
            xb, cb = augment_tensor(x[idx], C[idx], cfg.augment, gen)
            loss = loss_fn(net(xb), cb)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if sched is not None:
                sched.step()
            total += loss.item() * len(idx)
        hist["train_loss"].append(total / x.shape[0])
        if not math.isfinite(hist["train_loss"][-1]):
            raise AmfeError(f"stiffness member seed {seed}: the loss is not finite at epoch "
                            f"{epoch + 1}; lower --lr")
        with torch.no_grad():
            net.eval()
            hist["val_loss"].append(float(loss_fn(net(val[0]), val[1])) if len(val[0]) else None)
        hist["val_mre"].append(_val_mre(net, val))
        hist["epoch_seconds"].append(time.perf_counter() - t0)
        log(f"seed {seed}: epoch {epoch + 1:3d}/{cfg.epochs} loss {hist['train_loss'][-1]:.4g} "
            f"val {hist['val_loss'][-1]} | val err % (nine, no TTA) "
            + " ".join(f"{100 * e:.2f}" for e in hist["val_mre"][-1]))
    hist["seconds"] = time.perf_counter() - t_start
    net.eval()
    return hist


def _val_mre(net, val):
    """Mean relative error (9,) of the nine constants on the validation beds, no TTA."""
    if not len(val[0]):
        return []
    with torch.no_grad():
        net.eval()
        pred = nine_from_stiffness(stiffness_from_raw(net(val[0]).double()))
        true = nine_from_stiffness(val[1])
    return [float(v) for v in ((pred - true).abs() / true.abs()).mean(0)]


def train_stiffness(data_path, cfg, log=print):
    """Fine-tune ``cfg.members`` stiffness nets on the data set: the checkpoint dict."""
    cfg.check()
    start = load_init(cfg.init, cfg.init_member, cfg.members)
    if start["arch"] != "multiscale":
        raise AmfeError(f"--head stiffness starts from a multiscale model; {cfg.init} is "
                        f"{start['arch']}")
    inputs = tuple(start["inputs"])
    info = dataset_info(data_path, inputs)
    train_rows, val_rows = split_indices(info["ok"], cfg.val_fraction, cfg.split_seed)
    if cfg.max_train:
        train_rows = train_rows[:cfg.max_train]
    check_grid(start, data_path, info, pixelation_of(info))   # another bed size is fine
    keep_head = is_stiffness(start["ckpt"])
    if label_rule(info) < 2:   # predict converts rule-1 moduli per bed, which C would not follow
        raise AmfeError(f"{data_path} has label rule 1 labels; a stiffness head is trained on "
                        "label rule 2 data sets (docs/model.md, section 5)")
    C_train = read_stiffness(data_path, train_rows)
    C_val = read_stiffness(data_path, val_rows)
    for C in (C_train, C_val):
        if not (np.isfinite(C).all() and (np.linalg.eigvalsh(C)[:, 0] > 0).all()):
            raise AmfeError(f"{data_path}: a bed's /C is not finite and positive definite")
    # a kept head's outputs are in its own unit
    scale = float(start["ckpt"]["stiffness_scale"] if keep_head else np.median(C_train[:, 0, 0]))
    x_train, _ = read_rows(data_path, train_rows, inputs)
    x_val, _ = read_rows(data_path, val_rows, inputs)
    train = (torch.from_numpy(x_train).float(), torch.from_numpy(C_train / scale))
    val = (torch.from_numpy(x_val).float(), torch.from_numpy(C_val / scale))
    log(f"{data_path}: train {len(train_rows)}, validation {len(val_rows)} (split seed "
        f"{cfg.split_seed}); stiffness head on {cfg.init} member {cfg.init_member}+ "
        f"({'its own head kept' if keep_head else 'head fitted'}); "
        f"scale {scale:.4g} Pa; loss {cfg.loss}, {cfg.epochs} epochs, lr {cfg.lr:g} "
        f"({cfg.schedule}), augment {cfg.augment}")
    nets, arch_args = stiffness_members(start, cfg.members, info["image_shape"])
    seeds = [cfg.seed + k for k in range(cfg.members)]
    hists = [fit_member(net, train, val, cfg, seed, log, keep_head)
             for net, seed in zip(nets, seeds)]
    ckpt = dict(start["ckpt"])
    for key in ("conformal", "metrics", "created", "spread", "history", "init"):
        ckpt.pop(key, None)
    n_fill = x_train.shape[1] // len(inputs)
    training = asdict(cfg)
    training["seconds"] = float(sum(h["seconds"] for h in hists))
    ckpt.update({
        "image_shape": [int(s) for s in info["image_shape"]],
        "arch_args": arch_args, "n_parameters": count_parameters(nets[0]),
        "members": [n.state_dict() for n in nets], "member_seeds": seeds,
        "head": STIFFNESS_HEAD, "outputs": "cholesky21", "stiffness_scale": scale,
        "pixelation": pixelation_of(info), "tta": cfg.tta, "spread": None,
        "dataset": {"path": str(data_path), "sha256": dataset_hash(data_path, info["ok"], inputs),
                    "seed": info.get("seed"), "scale": info.get("scale"),
                    "n_ok": int(info["ok"].size), "n_train": int(len(train_rows)),
                    "n_validation": int(len(val_rows)),
                    "validation_rows": [int(r) for r in val_rows]},
        "training": training, "history": hists, "init": start["record"], "metrics": {},
        "label_rule": label_rule(info),
        "fill_range": widened_fill_range(start["fill_range"], calibrate_fill(x_train[:, :n_fill])),
    })
    return ckpt
