"""Report section 4, by bed size: each shipped network on its own size's held-out beds.

Measured by run/report/report.py (section 4) for every (scale, held-out data set) given with
``--size-test SCALE=PATH`` (the defaults are the held-out sets of docs/datasets.md that
exist on this machine): the shipped model of that scale (training/shipped.py), its mean
relative error per constant with the standard error, the tail (beds with any constant more
than 10 % off), the coverage of its 90 % intervals with the 95 % binomial interval
(run/train/calibrate_intervals.py), and the time to predict one bed of that size from its
particles on one core (pixelation, bond image and network, best of three).
"""
import os
import time


DEFAULT_TESTS = {"small": "/work/data/test_seed10_1000.h5",
                 "medium": "/work/data/medium_test450.h5",
                 "paper": "/work/data/paper_seed22_150.h5"}


def parse_size_tests(items):
    """{scale: path} of ``--size-test SCALE=PATH`` items (the defaults that exist when none)."""
    if not items:
        return {k: v for k, v in DEFAULT_TESTS.items() if os.path.exists(v)}
    out = {}
    for item in items:
        scale, sep, path = item.partition("=")
        if not sep or not path:
            raise ValueError(f"--size-test takes SCALE=PATH, got {item!r}")
        out[scale] = path
    return out


def measure_sizes(tests, log=print):
    """[{scale, model, test, n, mre, se, tail10, coverage, predict_seconds}] per scale."""
    import h5py
    import torch
    from run.train.calibrate_intervals import coverage_numbers
    from run.train.eval_surrogate import evaluate
    from amfe.model.scales import bed_for, get_scale
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import SHIPPED, models_dir
    torch.set_num_threads(1)
    rows = []
    for scale, test in tests.items():
        model = models_dir() / SHIPPED[scale]
        if not model.is_file():
            log(f"  {scale}: no shipped model ({model.name}); skipped")
            continue
        r = evaluate(str(model), test)["all beds"]
        sur = Surrogate.load(model)
        cov = coverage_numbers(sur, test) if sur.ckpt.get("conformal") else None
        with h5py.File(test, "r") as f:
            seed = int(f["seed"][0])
        bed = bed_for(get_scale(scale), seed)
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            sur.predict_bed(bed)
            best = min(best, time.perf_counter() - t0)
        rows.append({"scale": scale, "size_mm": float(get_scale(scale).size[0]) * 1e3,
                     "model": model.name, "test": test, "n": r["n"], "mre": r["mre"],
                     "se": r["se"], "tail10": r["tail10"], "coverage": cov,
                     "predict_seconds": best})
        log(f"  {scale}: {model.name} on {r['n']} beds, mean rel err "
            + " ".join(f"{100 * e:.2f}" for e in r["mre"]) + f" %, one bed {best:.2f} s")
    return rows


def section_sizes(rows, md):
    """Markdown lines of the by-size table after section 4's."""
    if not rows:
        return
    from amfe.vocab import LABEL_NAMES
    md += ["### By bed size", "",
           "Each shipped network (`amfe predict` picks it by the bed's size) on its own size's "
           "held-out beds, never used to train, choose or calibrate it (docs/datasets.md): mean "
           "relative error % +- its standard error; the tail (any constant more than 10 % "
           "off); the share of beds whose label lies in its 90 % interval, lowest and highest "
           "over the six constants, with how many of the six have 90 % inside the 95 % "
           "binomial interval; one bed predicted from its particles (imaging and network, one "
           "core, best of three).", "",
           "| size | model | beds | " + " | ".join(LABEL_NAMES)
           + " | any > 10 % | coverage % | nominal inside | one bed |",
           "|---|---|---|" + "---|" * (len(LABEL_NAMES) + 4)]
    for r in rows:
        c = r["coverage"]
        if c:
            cov = f"{100 * min(c['covered']):.1f}-{100 * max(c['covered']):.1f}"
            inside = sum(a <= c["nominal"] <= b for a, b in c["binomial"][:6])
            inside = f"{inside} of 6"
        else:
            cov, inside = "no interval claimed", ""
        md.append(f"| {r['size_mm']:g} mm | `{r['model']}` | {r['n']} | "
                  + " | ".join(f"{100 * e:.2f} +- {100 * s:.2f}" for e, s in zip(r["mre"], r["se"]))
                  + f" | {100 * r['tail10']:.1f} | {cov} | {inside} | "
                  f"{r['predict_seconds']:.2f} s |")
    md.append("")
