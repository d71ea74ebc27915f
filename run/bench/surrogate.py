"""Speed of the surrogate: batched inference per bed, and one `amfe predict` of one bed.

    python -m run.bench.surrogate [--model MODEL.pt] [--data /work/data/small_test.h5]

1. Batched: Surrogate.predict on the data set's images (all members and
   test-time symmetries the model uses), in numpy (the default backend) and
   in torch on 1 and on 2 threads, best of several repeats, in ms per bed for
   batches of 1, 100 and all.
2. One bed, in process: read the bed file, pixelate it, image its bonds (a
   model with the bond input), predict (each timed).
3. One bed, the whole command: wall time of `amfe predict BED.h5` in a fresh
   process (Python start-up and imports included; the shipped six-constant
   models import no torch).

The bed of 2. and 3. is record 0 of the data set, regenerated with
`amfe pack --scale SCALE --seed <its seed>`. Not a timed test: numbers for
docs/surrogate.md.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time


from run.common import ROOT, parser  # noqa: E402


def bench_batched(sur, images, threads=(1, 2), batches=(1, 100, None), repeats=5):
    """{(threads, batch): ms per bed} of Surrogate.predict, best of ``repeats``; ``threads``
    are torch's (a Surrogate whose backend is numpy runs on its BLAS's threads whatever
    they say)."""
    torch = None
    if sur.backend == "torch":
        import torch
    out = {}
    old = torch.get_num_threads() if torch else None
    try:
        for t in threads:
            if torch:
                torch.set_num_threads(t)
            for b in batches:
                n = len(images) if b is None else min(b, len(images))
                x = images[:n]
                sur.predict(x)                               # warm-up
                best = min(_timed(lambda: sur.predict(x)) for _ in range(repeats))
                out[(t, n)] = 1e3 * best / n
    finally:
        if torch:
            torch.set_num_threads(old)
    return out


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def make_bed(data_path, directory):
    """Record 0's bed of the data set, as BED.h5 in ``directory`` (amfe pack --scale --seed)."""
    import h5py
    with h5py.File(data_path, "r") as f:
        seed, scale = int(f["seed"][0]), f.attrs["scale"]
    scale = scale.decode() if isinstance(scale, bytes) else str(scale)
    path = os.path.join(directory, "bed.h5")
    subprocess.run([sys.executable, "-m", "amfe.cli", "pack", "--scale", scale, "--seed",
                    str(seed), "-o", path], check=True, capture_output=True, cwd=ROOT)
    return path


def bench_bed(model, bed_path, repeats=5):
    """In-process seconds of reading, pixelating and predicting one bed (best of ``repeats``)."""
    from amfe.io.bedfile import read_bed
    from amfe.training.predict import Surrogate

    t0 = time.perf_counter()
    sur = Surrogate.load(model)
    load = time.perf_counter() - t0
    best = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        bed = read_bed(bed_path)
        t1 = time.perf_counter()
        _, _, times = sur.predict_bed(bed)
        t2 = time.perf_counter()
        row = {"read_bed": t1 - t0, "pixelate": times["pixelate"],
               "bonds": times.get("bonds", 0.0), "predict": times["predict"], "total": t2 - t0}
        best = row if best is None or row["total"] < best["total"] else best
    best["load_model"] = load
    best["n_particles"] = int(bed.n)
    return best


def bench_cli(model, bed_path, repeats=3):
    """Wall seconds of `amfe predict BED.h5 --model MODEL` in a fresh process."""
    cmd = [sys.executable, "-m", "amfe.cli", "predict", bed_path]
    if model:
        cmd += ["--model", str(model)]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_import(repeats=3):
    """Wall seconds of `python -c "import torch"` (the floor of any command that uses torch)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import torch"], check=True)
        times.append(time.perf_counter() - t0)
    return min(times)


def run_all(model, data_path, log=print):
    from amfe.training.data import read_rows
    from amfe.training.predict import Surrogate

    sur = Surrogate.load(model)
    images, _ = read_rows(data_path, inputs=sur.inputs)
    # "batched": torch on 1 and 2 threads (what train_surrogate and surrogate_docs read),
    # "batched_numpy": the default backend of the shipped six-constant models
    res = {"model": str(sur.path), "members": sur.n_members, "tta": sur.tta,
           "batched": bench_batched(Surrogate.load(model, backend="torch"), images)}
    if sur.backend == "numpy":
        res["batched_numpy"] = bench_batched(sur, images, threads=(1,))
    for key, what in (("batched_numpy", "numpy"), ("batched", "torch on {t} thread(s)")):
        for (t, n), ms in res.get(key, {}).items():
            log(f"batched: {what.format(t=t)}, batch {n:4d}: {ms:.4f} ms per bed")
    with tempfile.TemporaryDirectory() as tmp:
        bed = make_bed(data_path, tmp)
        res["bed"] = bench_bed(model, bed)
        log("one bed in process ({n_particles} particles): read {read_bed:.4f} s, pixelate "
            "{pixelate:.4f} s, bond image {bonds:.4f} s, predict {predict:.4f} s, total {total:.4f} s (model load "
            "{load_model:.3f} s, once)".format(**res["bed"]))
        res["cli"] = bench_cli(model, bed)
        res["import_torch"] = bench_import()
        log(f"`amfe predict bed.h5` in a fresh process: {res['cli']:.2f} s wall "
            f"(python -c 'import torch' alone: {res['import_torch']:.2f} s)")
    return res


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    ap.add_argument("--data", default="/work/data/small_test.h5",
                    help="data set whose images are predicted (default the held-out test set)")
    args = ap.parse_args(argv)
    run_all(args.model, args.data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
