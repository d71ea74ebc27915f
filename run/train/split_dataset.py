"""Records FIRST..END-1 of a finished data set as a data-set file of their own.

    .venv/bin/python -m run.train.split_dataset DATA.h5 FIRST END -o PART.h5

For a held-out set that serves two purposes (issue 34: the medium beds of
seed 12 are split into test beds and interval-calibration beds), so each
purpose reads a file of its own and no bed is used for both. Every dataset
whose first axis is the record axis is cut; the root attributes are kept
and `split_of`, `split_first`, `split_end` record where the rows came from.
The output is written atomically (amfe.io.atomic: never half a file).
"""
import argparse
import os
import sys
from run.common import parser


def copy_tree(src, dst, data_of):
    """Every dataset of the open h5py file ``src`` into ``dst`` as the array ``data_of(name,
    dataset)`` (gzip for two axes or more), with its attributes, and every group's attributes."""
    import h5py
    import numpy as np

    def copy(name, obj):
        if isinstance(obj, h5py.Dataset):
            data = data_of(name, obj)
            dst.create_dataset(name, data=data, dtype=obj.dtype,
                               compression="gzip" if np.ndim(data) > 1 else None)
            dst[name].attrs.update(dict(obj.attrs))
        elif isinstance(obj, h5py.Group):
            dst.require_group(name).attrs.update(dict(obj.attrs))
    src.visititems(copy)


def split(source, first, end, output):
    import h5py
    from amfe.errors import AmfeError
    from amfe.io.atomic import atomic_write
    with h5py.File(source, "r") as f:
        n = int(f["status"].shape[0])
        if not 0 <= first < end <= n:
            raise AmfeError(f"{source} has {n} records: FIRST..END must lie in 0..{n}, got "
                            f"{first}..{end}")

        def write(tmp):
            with h5py.File(tmp, "w") as g:
                g.attrs.update(dict(f.attrs))
                g.attrs.update(split_of=os.path.basename(source), split_first=first,
                               split_end=end, count=end - first)
                copy_tree(f, g, lambda name, obj: obj[first:end] if obj.ndim and
                          obj.shape[0] == n else obj[()])
        atomic_write(output, write, by_name=True)


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("data")
    p.add_argument("first", type=int)
    p.add_argument("end", type=int)
    p.add_argument("-o", "--output", required=True)
    args = p.parse_args(argv)
    from amfe.errors import AmfeError
    try:
        split(args.data, args.first, args.end, args.output)
    except AmfeError as exc:
        print(f"split_dataset: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote records {args.first}..{args.end - 1} of {args.data} to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
