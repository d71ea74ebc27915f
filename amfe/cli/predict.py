"""`amfe predict BED.h5`: the surrogate's elastic constants of a bed, in milliseconds.

    amfe predict BED.h5 [BED.h5 ...] [--model MODEL.pt] [-o OUT.json | -o -] [--check]
                 [--fallback]

Pixelates the bed exactly as the model's training data (cells, layers and
sample spacing are stored in the checkpoint) and runs the network(s); the
default model is the ensemble shipped in amfe/models/ for the bed's size
(training/shipped.py: 0.6 mm and, where shipped, 1.2 mm beds). With an
ensemble, the members' spread flags beds unlike the training data;
--fallback then runs the PETSc solve instead, --check always runs it and
prints both with their difference. Both also work under mpirun.

Every path and option is checked before the model is loaded (amfe.io.paths):
``-o`` may not be the bed or the model, ``-o -`` writes the JSON to stdout
and the table to stderr. A prediction that is not finite (a damaged model:
NaN weights, or an overflow) is never reported: it is flagged, --fallback
solves instead, and without --fallback it is an error (exit 2, no file).

Several beds are predicted in one process: the model is loaded once and
the beds' images go through the network in one batch. With one bed the
JSON is that bed's result (as always); with several it is
{schema_version, command, beds: [one result per bed, in the order given]},
each naming its input.path. Every result names the boundary condition its
constants are for (``bc``: "kubc", as the labels).
"""
import json
import math
import os
import sys
import time

from amfe.cli.interrupt import launcher_rank
from amfe.cli.options import nonnegative_float, thread_count
from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.paths import check_output, is_stdout
from amfe.io.result_meta import header, predict_block
from amfe.model.material import resolve_material
from amfe.vocab import LABEL_NAMES as SIX

NINE = SIX + ("G_yz", "G_xz", "G_xy")


def register(sub):
    p = sub.add_parser("predict", help="elastic constants of a bed from the CNN surrogate",
                       description=__doc__.split("\n\n")[0],
                       epilog="With --check or --fallback, any -option (single dash) goes to "
                              "PETSc.")
    p.add_argument("bed", metavar="BED.h5", nargs="+",
                   help="bed HDF5 file(s) (/particles/centers, /radii); several: one batch")
    p.add_argument("--model", metavar="MODEL.pt",
                   help="checkpoint from amfe train (default: the shipped model for the "
                        "bed's size, amfe/models/multiscale_SCALE.pt)")
    p.add_argument("--stiffness", action="store_true",
                   help="use the shipped full-stiffness model for the bed's size "
                        "(amfe/models/stiffness_SCALE.pt): C, the shear moduli and their "
                        "intervals as well (0.6, 1.2 and 3 mm beds)")
    p.add_argument("-o", "--output", metavar="OUT.json",
                   help="write the result as JSON here (-: to stdout, the table to stderr)")
    p.add_argument("--check", action="store_true",
                   help="also run the PETSc solve; print and store both and their difference")
    p.add_argument("--fallback", action="store_true",
                   help="run the PETSc solve instead when the ensemble spread flags the bed")
    p.add_argument("--threshold", type=nonnegative_float,
                   help="flag threshold on the spread score, a finite number >= 0 (default: the "
                        "model's, calibrated on its validation beds)")
    p.add_argument("--threads", type=thread_count, help="torch CPU threads (default: torch's)")
    p.set_defaults(func=run)


def check_args(args):
    """Refuse bad paths and option combinations before any work (AmfeError)."""
    if args.petsc_args and not (args.check or args.fallback):
        raise AmfeError(f"unknown option(s) {' '.join(args.petsc_args)}: single-dash options go "
                        "to PETSc, which amfe predict runs only with --check or --fallback")
    if args.stiffness and args.model:
        raise AmfeError("give --model or --stiffness, not both: --stiffness picks the shipped "
                        "full-stiffness model")
    if args.output is not None:
        check_output(args.output, inputs=[*args.bed, args.model], allow_stdout=True)
    from amfe.model.tolerance import check_command_rtol, given_rtol
    from amfe.solvers.petsc import option_pairs
    for name, value in given_rtol(None, option_pairs(args.petsc_args)):   # issue 45
        check_command_rtol("predict --check" if args.check else "homogenize", value, name)


def run(args):
    t_start = time.perf_counter()
    age = process_age()
    check_args(args)
    import torch

    from amfe.io.bedfile import read_bed
    from amfe.training.predict import Surrogate, check_material
    from amfe.training.shipped import shipped_model_for

    if args.threads:
        torch.set_num_threads(args.threads)
    # start-up: the interpreter, amfe's and torch's imports (before any work on the bed)
    times = {"start_up": time.perf_counter() - t_start + age} if age is not None else {}
    beds = []
    for path in args.bed:
        t = time.perf_counter()
        beds.append((path, read_bed(path), time.perf_counter() - t))
    # One model per bed size (training/shipped.py) unless --model names one for all.
    chosen = [args.model or shipped_model_for(bed, args.stiffness) for _, bed, _ in beds]
    outs = [None] * len(beds)
    for model in dict.fromkeys(chosen):
        t = time.perf_counter()
        sur = Surrogate.load(model)
        times["load_model"] = time.perf_counter() - t
        threshold = args.threshold if args.threshold is not None else sur.threshold
        if args.fallback and threshold is None and not sur.fill_range \
                and not sur.ckpt.get("conformal"):
            raise AmfeError(f"--fallback needs a flag threshold: {sur.path} is a single network "
                            "without a calibrated ensemble spread; use an ensemble (amfe train "
                            "--members 5) or give --threshold")
        mine = [k for k, m in enumerate(chosen) if m == model]
        for k in mine:
            check_material(beds[k][1], sur.ckpt, sur.path)
        predictions = sur.predict_beds([beds[k][1] for k in mine])
        for k, (res, image, t_pred) in zip(mine, predictions):
            path, bed, t_read = beds[k]
            bed_times = {**times, "read_bed": t_read, **t_pred}
            outs[k] = _one_bed(args, sur, threshold, (path, bed), (res, image), bed_times,
                               t_start)
    if outs[0][1] == 0:
        write_result(outs[0][0] if len(outs) == 1 else batch_result([o for o, _ in outs]),
                     args.output)
    return 0


def batch_result(results):
    """The JSON of several beds: {schema_version, command, beds: [results]}."""
    from amfe.io.result_meta import SCHEMA_VERSION
    return {"schema_version": SCHEMA_VERSION, "command": "predict", "beds": results}


def _one_bed(args, sur, threshold, item, prediction, times, t_start):
    """(result dict, rank) of one bed's prediction (and solve, with --check/--fallback).

    item: (path, Bed); prediction: (result, image) of Surrogate.predict_beds."""
    (path, bed), (res, image) = item, prediction
    from amfe.training.predict import as_properties

    score = float(res["score"][0])
    reasons = flag_reasons(res, threshold, sur.n_members)
    bars = interval_of(sur, bed, res) if "non-finite" not in reasons else None
    if bars is not None and bars["interval_flag"]:
        reasons.append("interval")
    comm = None
    if args.check or args.fallback:
        from mpi4py import MPI
        comm = MPI.COMM_WORLD
        reasons = comm.bcast(reasons, root=0)   # every rank takes the same branch
    flagged = bool(reasons)
    if "non-finite" in reasons and not args.fallback:
        bad = [k for k, v in zip(SIX, res["mean"][0]) if not math.isfinite(v)]
        raise AmfeError(f"the surrogate's prediction is not finite ({', '.join(bad) or 'spread'}"
                        f"): the model {sur.path} is damaged or overflows on this bed; run with "
                        "--fallback to solve with PETSc instead, or use amfe homogenize")

    solver = None
    if comm is not None and (args.check or flagged):
        from amfe.model.options import SolveOptions
        from amfe.solvers.driver import homogenize_bed
        from amfe.solvers.petsc import init_petsc
        init_petsc(args.petsc_args)
        t = time.perf_counter()
        solver = homogenize_bed(bed, SolveOptions(material=bed.material(),
                                                  solver="gamg")).to_dict()
        times["solve"] = time.perf_counter() - t
    rank = comm.rank if comm is not None else launcher_rank()

    surrogate_props = _finite_or_none(as_properties(res["mean"][0]))
    out = {
        "bed": os.fspath(path),
        "bc": "kubc",   # the labels' boundary condition (docs/model.md, section 5)
        "properties": surrogate_props,
        "spread": _finite_or_none(as_properties(res["spread"][0])),
        "spread_score": score if math.isfinite(score) else None,
        "threshold": threshold,
        # Split conformal intervals at the model's nominal coverage, None where the model
        # has no calibration for the bed's size (amfe.training.conformal).
        "intervals": bars["intervals"] if bars else None,
        "coverage": bars["coverage"] if bars else None,
        "interval_calibration": bars["calibration"] if bars else None,
        "fill": float(res["fill"][0]),
        "fill_range": ([sur.fill_range["lo"], sur.fill_range["hi"]] if sur.fill_range
                       else None),
        "flagged": flagged,
        "flag_reasons": reasons,
        "source": "surrogate",
        "model": os.fspath(sur.path),
        "arch": sur.ckpt["arch"],
        "members": sur.n_members,
        "inputs": list(sur.inputs),
        "labels": sur.labels,            # the label rule (docs/model.md, section 5)
        "image_shape": list(image.shape),
        "density": float(image.mean(dtype="float64")),
    }
    if "stiffness" in res:   # a stiffness head: C and the nine constants derived from it
        out["stiffness"] = {"C": [[float(v) for v in row] for row in res["stiffness"][0]],
                            "constants": _finite_or_none(dict(zip(NINE, map(float,
                                                                            res["constants9"][0])))),
                            "voigt": "xx, yy, zz, yz, xz, xy; Pa"}
    if solver is not None:
        solver_props = {k: float(solver["properties"][k]) for k in NINE}
        if args.fallback and flagged:
            out["source"] = "solver"
            out["properties"] = solver_props
            out["surrogate"] = {"properties": surrogate_props}
        if args.check:
            out["check"] = {"solver": solver_props,
                            "relative_difference": {k: _relative(surrogate_props[k],
                                                                 solver_props[k]) for k in SIX}}
        out["solver"] = solver["solver"]
    out = {**header("predict", bed.centers, bed.radii, resolve_material(bed.attrs)[1],
                    input_path=path), **out, "predict": predict_block(out)}
    times["total"] = time.perf_counter() - t_start
    out["seconds"] = times["total"]
    out["timings"] = times
    return out, rank


def interval_of(sur, bed, res):
    """The bed's interval block (amfe.training.conformal.interval_block) at its imaged size."""
    from amfe.training.conformal import interval_block
    from amfe.training.predict import _image_size
    conformal = sur.ckpt.get("conformal")
    if "constants9" in res and conformal and len(conformal.get("names", ())) == 9:
        return interval_block(res["constants9"][0], NINE, conformal, _image_size(bed, sur.ckpt),
                              res["spread9"][0])   # a stiffness head calibrated on all nine
    return interval_block(res["mean"][0], SIX, conformal, _image_size(bed, sur.ckpt),
                          res["spread"][0])


def process_age():
    """Seconds since this process started (Linux /proc, 10 ms ticks), or None elsewhere."""
    try:
        with open("/proc/self/stat") as fh:
            start_ticks = float(fh.read().rsplit(")", 1)[1].split()[19])   # field 22, starttime
        with open("/proc/uptime") as fh:
            up = float(fh.read().split()[0])
        return max(0.0, up - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return None


def flag_reasons(res, threshold, n_members):
    """Why the bed is flagged: a list of "spread", "fill", "non-finite" (empty: in distribution).

    A NaN compares false with any threshold, so a non-finite prediction is a
    reason of its own; it is never "in distribution".
    """
    reasons = []
    score = float(res["score"][0])
    if threshold is not None and n_members > 1 and score > threshold:
        reasons.append("spread")
    if bool(res["fill_out"][0]):
        reasons.append("fill")
    if bool(res["nonfinite"][0]):
        reasons.append("non-finite")
    return reasons


def _relative(value, reference):
    """(value - reference) / |reference|, None when the value is None (not finite)."""
    return None if value is None else (value - reference) / abs(reference)


def _finite_or_none(props):
    """{name: value}, a non-finite value as None (JSON null: JSON has no NaN)."""
    return {k: (v if math.isfinite(v) else None) for k, v in props.items()}


def write_result(out, output):
    """The JSON to ``output`` (atomically) or stdout (``-``, /dev/stdout), and the table to stdout
    or stderr."""
    if output is not None and is_stdout(output):
        print(summary(out), file=sys.stderr, flush=True)
        print(json.dumps(out, indent=2), flush=True)
        return
    if output:
        try:
            write_json(output, out)
        except OSError as exc:   # a full disk: the old file, if any, is left as it was
            raise AmfeError(f"cannot write -o {output}: {exc.strerror or exc}") from None
    print(summary(out, output), flush=True)


def _fmt(key, value):
    """A property as printed: moduli in GPa, ratios bare, 6 significant digits."""
    if value is None:
        return "not finite"
    return f"{value / 1e9:.6g} GPa" if key.startswith(("E", "G")) else f"{value:.6g}"


def summary(out, output=None):
    """The table amfe predict prints (tests compare its numbers with the JSON); one per bed."""
    if "beds" in out:
        tables = "\n".join(summary(one) for one in out["beds"])
        return tables + (f"\nwrote {output}" if output else "")
    check = out.get("check")
    lines = [f"{out['bed']}: image {'x'.join(map(str, out['image_shape']))}, packing density "
             f"{out['density']:.3f}; model {out['model']} ({out['arch']}, {out['members']} "
             f"member(s), inputs {','.join(out.get('inputs', ['fill']))})"]
    surrogate = out.get("surrogate", {}).get("properties", out["properties"])
    head = f"  {'':6s} {'surrogate':>16s} {'spread':>8s}"
    if check:
        head += f" {'solver':>16s} {'difference':>10s}"
    if out.get("intervals"):
        head += f"  {100 * out['coverage']:g} % interval"
    lines.append(head)
    for k in SIX:
        line = f"  {k:6s} {_fmt(k, surrogate[k]):>16s} {_percent(out['spread'][k], 7, '')}"
        if check:
            line += (f" {_fmt(k, check['solver'][k]):>16s} "
                     f"{_percent(check['relative_difference'][k], 9, '+')}")
        if out.get("intervals"):
            lo, hi = out["intervals"][k]
            line += f"  [{_fmt(k, lo)}, {_fmt(k, hi)}]"
        lines.append(line)
    for k in NINE[6:] if out.get("stiffness") else ():   # shear moduli of the predicted C
        line = f"  {k:6s} {_fmt(k, out['stiffness']['constants'][k]):>16s}"
        if k in (out.get("intervals") or {}):
            lo, hi = out["intervals"][k]
            line += f" {'':8s}  [{_fmt(k, lo)}, {_fmt(k, hi)}]"
        lines.append(line)
    if out.get("coverage"):
        lines.append(f"intervals: split conformal, nominal coverage {100 * out['coverage']:g} % "
                     f"({out['interval_calibration']['n']} calibration beds of "
                     f"{out['interval_calibration']['size']} mm)")
    elif out.get("interval_calibration"):
        lines.append(out["interval_calibration"]["note"])
    if out["members"] < 2:
        lines.append("no spread flag (a single network has no spread)")
    elif out["threshold"] is None:   # members merged without validation beds to set it
        lines.append("no spread flag (the model has no spread threshold; its intervals flag)")
    elif out["spread_score"] is None:
        lines.append(f"spread score not finite (threshold {out['threshold']:.3g})")
    else:
        lines.append(f"spread score {out['spread_score']:.3g} (threshold {out['threshold']:.3g})")
    if out["fill_range"]:
        lo, hi = out["fill_range"]
        inside = lo <= out["fill"] <= hi
        lines.append(f"fill of the fullest cells {out['fill']:.3f} (training beds {lo:.3f} - "
                     f"{hi:.3f}){'' if inside else ': outside, another enlargement?'}")
    reasons = out.get("flag_reasons", [])
    if "non-finite" in reasons:
        lines.append("FLAGGED: the surrogate's prediction is not finite (a damaged model?)")
    elif reasons == ["interval"]:
        lines.append("FLAGGED: an interval is wider than the model's limit")
    elif out["flagged"]:
        lines.append("FLAGGED: unlike the training beds")
    else:
        lines.append("in distribution")
    if out["source"] == "solver":
        lines.append("source: solver (PETSc, --fallback); its constants:")
        for k in NINE:
            lines.append(f"  {k:6s} {_fmt(k, out['properties'][k]):>16s}")
    else:
        lines.append("source: surrogate")
    t = out["timings"]
    stages = ("load_model", "read_bed", "pixelate", "bonds", "predict", "solve")
    parts = [f"{k.replace('_', ' ')} {t[k]:.3g} s" for k in stages if k in t]
    lines.append(f"time {out['seconds']:.3g} s: " + ", ".join(parts))
    if "start_up" in t:
        imaging = t.get("pixelate", 0.0) + t.get("bonds", 0.0)
        lines.append(f"one call: start-up {t['start_up']:.3g} s (Python, amfe and torch imports), "
                     f"model {t['load_model']:.3g} s, imaging {imaging:.3g} s, "
                     f"network {t['predict']:.3g} s")
    if output:
        lines.append(f"wrote {output}")
    return "\n".join(lines)


def _percent(fraction, width, sign):
    """A relative value as a percentage column; "-" for None (not finite)."""
    if fraction is None:
        return f"{'-':>{width + 1}s}"
    return f"{100 * fraction:{sign}{width}.2f}%"
