"""One ensemble from members trained separately (for example at the same time on two cores).

Member k of ``amfe train --seed S --members M`` is the network that ``amfe
train --seed S+k`` trains alone on the same data set: the split (split
seed), the normaliser (the training labels) and the recipe are the same,
and a member's weights, batch order and augmentation depend on its own seed
only. :func:`merge_members` checks that the checkpoints agree on all of
that, concatenates their members in seed order, and redoes what depends on
the whole ensemble: the out-of-distribution flag's calibration and the
validation metrics (``metrics["test"]`` is dropped; evaluate the merged
model again).
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.training.data import Normalizer, dataset_hash, dataset_info, read_rows
from amfe.training.metrics import validation_metrics
from amfe.training.predict import Surrogate
from amfe.training.train import calibrate_spread

# Checkpoint entries that must be equal in every part (training: all but the seed and timing).
SAME = ("arch", "arch_args", "normalizer", "image_shape", "inputs", "pixelation", "material",
        "tta")
SAME_DATA = ("sha256", "n_train", "n_validation", "validation_rows")
FREE_TRAINING = ("seed", "members", "seconds", "flag_percentile", "init_member")


def merge_members(ckpts, data_path, flag_percentile=95.0, names=None):
    """The checkpoint dict of one ensemble made of the members of ``ckpts`` (list of dicts).

    data_path: the training data set (its validation beds calibrate the flag).
    names: one label per checkpoint for error messages. AmfeError when the
    parts were not trained on the same data and split with the same recipe,
    or repeat a seed.
    """
    names = names or [f"checkpoint {k + 1}" for k in range(len(ckpts))]
    if len(ckpts) < 2:
        raise AmfeError("merging needs at least two checkpoints")
    first = ckpts[0]
    for ck, name in zip(ckpts[1:], names[1:]):
        for key in SAME:
            if ck.get(key) != first.get(key):
                raise AmfeError(f"{name} differs from {names[0]} in {key}: not members of one "
                                "ensemble")
        for key in SAME_DATA:
            if ck["dataset"].get(key) != first["dataset"].get(key):
                raise AmfeError(f"{name} was trained on other data or another split than "
                                f"{names[0]} (dataset {key} differs)")
        if (ck.get("init") or {}).get("sha256") != (first.get("init") or {}).get("sha256"):
            raise AmfeError(f"{name} was fine-tuned from another model than {names[0]} "
                            "(init differs)")
        for key in set(first["training"]) | set(ck["training"]):
            if key not in FREE_TRAINING and ck["training"].get(key) != first["training"].get(key):
                raise AmfeError(f"{name} was trained with another recipe than {names[0]} "
                                f"({key}: {ck['training'].get(key)!r} against "
                                f"{first['training'].get(key)!r})")
    parts = sorted(((seed, state, hist, _init_member(ck, j)) for ck in ckpts
                    for j, (seed, state, hist) in enumerate(zip(ck["member_seeds"], ck["members"],
                                                                ck["history"]))),
                   key=lambda p: p[0])
    seeds = [p[0] for p in parts]
    if len(set(seeds)) != len(seeds):
        raise AmfeError(f"the checkpoints repeat a member seed ({seeds}): train each part "
                        "with its own --seed")
    out = dict(first, members=[p[1] for p in parts], member_seeds=seeds,
               history=[p[2] for p in parts], metrics={})
    out.pop("created", None)   # save_checkpoint stamps the merge
    if first.get("init"):   # which initial member each merged member started from
        out["init"] = dict(first["init"], member=[p[3][0] for p in parts],
                           member_seeds=[p[3][1] for p in parts])
    out["training"] = dict(first["training"], seed=seeds[0], members=len(seeds),
                           flag_percentile=float(flag_percentile),
                           seconds=float(sum(ck["training"].get("seconds", 0.0)
                                             for ck in ckpts)))
    inputs = tuple(first["inputs"])
    if dataset_hash(data_path, dataset_info(data_path, inputs)["ok"], inputs) != \
            first["dataset"]["sha256"]:
        raise AmfeError(f"{data_path} is not the data set the members were trained on "
                        "(its sha256 differs from the checkpoints')")
    rows = np.asarray(first["dataset"]["validation_rows"], dtype=np.int64)
    if rows.size:
        images, labels = read_rows(data_path, rows, inputs)
        out["spread"] = None
        sur = Surrogate(out, "the merged model")
        out["spread"] = calibrate_spread(sur.member_outputs(images), flag_percentile)
        res = Surrogate(out, "the merged model").predict(images)
        norm = Normalizer.from_dict(first["normalizer"])
        out["metrics"]["validation"] = validation_metrics(
            res, labels, norm, first["training"].get("lr", float("nan")))
    return out


def _init_member(ck, j):
    """(index, seed) of the initial model's member that member j of ``ck`` started from."""
    init = ck.get("init")
    if not init:
        return None, None
    first, seeds = init["member"], init.get("member_seeds") or []
    return (first[j] if isinstance(first, list) else first + j,
            seeds[j] if j < len(seeds) else None)
