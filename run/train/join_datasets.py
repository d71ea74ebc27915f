"""Finished data sets of one scale joined into one data-set file, record after record.

    .venv/bin/python -m run.train.join_datasets A.h5 B.h5 [...] -o JOINED.h5

For a held-out set made of several data-set seeds (issue 34: the 1.2 mm test
beds are records 0-149 of seed 12 and the 300 of seed 15), so that one file
scores a model and one coverage figure has all the beds behind it. The files
must agree on everything that decides what a record means (the scale, the
bed size, the image grid and imaging version, the label names and label
rule, the solver's tolerance) and hold the same datasets; a mismatch is
refused in one line. Every dataset whose first axis is the record axis is
concatenated; the first file's root attributes are kept, its ``seed``
becomes ``joined_seeds`` (one per file) and ``joined_of`` names the files.
Per-record ``seed`` (each bed's own) is kept, so every bed still
regenerates; a dataset that is not per record is the first file's. The
output is written atomically (amfe.io.atomic), as run/train/split_dataset.py's,
whose copy_tree writes it.
"""
import argparse
import os
import sys
from run.common import parser


MUST_AGREE = ("scale", "bed_size", "image_shape", "image_cell", "imaging_version",
              "label_names", "label_rule_version", "rtol", "format_version")
"""Root attributes that decide what a record means: the files must agree on them."""


def _record_datasets(f, n):
    """{name: dataset} of every dataset of ``f`` whose first axis has length n."""
    import h5py
    out = {}
    f.visititems(lambda name, obj: out.__setitem__(name, obj)
                 if isinstance(obj, h5py.Dataset) and obj.ndim and obj.shape[0] == n else None)
    return out


def join(paths, output):
    import h5py
    import numpy as np
    from amfe.errors import AmfeError
    from amfe.io.atomic import atomic_write
    from run.train.split_dataset import copy_tree
    if len(paths) < 2:
        raise AmfeError("give at least two data sets to join")
    files = [h5py.File(p, "r") for p in paths]
    try:
        first = files[0]
        for path, f in zip(paths, files):
            if "status" not in f or "seed" not in f.attrs:
                raise AmfeError(f"{path} is not a data set that a run wrote (no /status or no "
                                "seed attribute): join those, not a joined or other file")
        counts = [int(f["status"].shape[0]) for f in files]
        for path, f in zip(paths[1:], files[1:]):
            for key in MUST_AGREE:
                a, b = first.attrs.get(key), f.attrs.get(key)
                if not np.array_equal(np.asarray(a), np.asarray(b)):
                    raise AmfeError(f"{path}: {key} is {b!r}, {paths[0]} has {a!r}: only data "
                                    "sets of one kind join")
        parts = [_record_datasets(f, n) for f, n in zip(files, counts)]
        names = sorted(parts[0])
        for path, part in zip(paths[1:], parts[1:]):
            if sorted(part) != names:
                raise AmfeError(f"{path} holds other record datasets than {paths[0]}: "
                                f"{sorted(set(part) ^ set(names))}")

        def data_of(name, obj):   # a dataset not per record: the first file's
            return (np.concatenate([part[name][()] for part in parts]) if name in parts[0]
                    else obj[()])

        def write(tmp):
            with h5py.File(tmp, "w") as g:
                g.attrs.update({k: v for k, v in first.attrs.items()
                                if k not in ("seed", "split_of", "split_first", "split_end")})
                g.attrs.update(count=sum(counts), joined_of=[os.path.basename(p) for p in paths],
                               joined_seeds=[int(f.attrs["seed"]) for f in files],
                               joined_counts=counts)
                copy_tree(first, g, data_of)
        atomic_write(output, write, by_name=True)
    finally:
        for f in files:
            f.close()
    return sum(counts)


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("data", nargs="+")
    p.add_argument("-o", "--output", required=True)
    args = p.parse_args(argv)
    from amfe.errors import AmfeError
    try:
        n = join(args.data, args.output)
    except (AmfeError, OSError, KeyError) as exc:
        print(f"join_datasets: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {n} records of {len(args.data)} data sets to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
