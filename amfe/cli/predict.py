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
the beds' images go through the network in one batch (amfe.cli.predict_core).
The JSON is always {schema_version, command, beds: [one record per bed, in
the order given]} (one bed too; amfe.predict's Prediction.to_dict() is a
record), each naming its input.path. A bed that cannot be predicted gets a
record with source "failed" and the reason, and the exit status is 3
(--fallback solves it instead); a single bed that fails is an error (exit
2). Every result names the boundary condition its constants are for
(``bc``: "kubc", as the labels).
"""
import json
import os
import sys
import time

from amfe.cli.options import (
    add_flag_share_arg,
    add_material_args,
    given_material,
    nonnegative_float,
    thread_count,
)
from amfe.cli.predict_common import check_springs
from amfe.cli.predict_core import NINE, SIX, flag_reasons, interval_of  # noqa: F401 (re-exported)
from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.paths import check_output, is_stdout
from amfe.model.continuum_springs import SPRING_CHOICES

#: exit status of a batch in which some beds could not be predicted (their records say why)
EXIT_SOME_FAILED = 3


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
    p.add_argument("--springs", choices=SPRING_CHOICES,
                   help="the bond springs of the labels the model learnt (docs/model.md, "
                        "section 11): continuum picks the shipped continuum-spring model "
                        "(0.6 mm beds); --check and --fallback solve with the model's springs "
                        "(default: the paper's, or those of --model's labels)")
    p.add_argument("-o", "--output", metavar="OUT.json",
                   help="write the result as JSON here (-: to stdout, the table to stderr)")
    p.add_argument("--check", action="store_true",
                   help="also run the PETSc solve; print and store both and their difference")
    p.add_argument("--fallback", action="store_true",
                   help="run the PETSc solve instead when the bed is flagged (by its risk on 0.6 "
                        "mm beds, else its interval or the ensemble's spread) or cannot be "
                        "predicted")
    p.add_argument("--threshold", type=nonnegative_float,
                   help="flag threshold on the ensemble's spread score, a finite number >= 0 "
                        "(default: the model's, calibrated on its validation beds; a 0.6 mm bed "
                        "is flagged by its risk instead, unless this is given)")
    add_flag_share_arg(p)
    p.add_argument("--threads", type=thread_count,
                   help="CPU threads of a model that runs in torch (a full-stiffness model, "
                   "another architecture; default: torch's); the shipped six-constant models "
                   "run in numpy")
    add_material_args(p, "for every bed, instead of its file's")
    p.set_defaults(func=run)


def check_args(args):
    """Refuse bad paths and option combinations before any work (AmfeError)."""
    if args.petsc_args and not (args.check or args.fallback):
        raise AmfeError(f"unknown option(s) {' '.join(args.petsc_args)}: single-dash options go "
                        "to PETSc, which amfe predict runs only with --check or --fallback")
    if args.stiffness and args.model:
        raise AmfeError("give --model or --stiffness, not both: --stiffness picks the shipped "
                        "full-stiffness model")
    check_springs(args.springs, args.stiffness)
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
    from amfe.cli.predict_core import predict_records

    if args.threads:   # torch only then: the shipped six-constant models run in numpy
        import torch
        torch.set_num_threads(args.threads)
    # start-up: the interpreter and amfe's imports (before any work on the bed)
    times = {"start_up": time.perf_counter() - t_start + age} if age is not None else {}
    args.material, args.material_source = given_material(args), "command line"
    records, failed = predict_records(args, args.bed, times, t_start)
    if len(records) == 1 and failed:   # one bed: its error, as amfe homogenize's (no file)
        raise AmfeError(records[0][0]["error"])
    if records[0][1] == 0:
        write_result(batch_result([out for out, _ in records]), args.output)
    return EXIT_SOME_FAILED if failed else 0


def batch_result(results):
    """The JSON of several beds: {schema_version, command, beds: [results]}."""
    from amfe.io.result_meta import SCHEMA_VERSION
    return {"schema_version": SCHEMA_VERSION, "command": "predict", "beds": results}


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
    if "image_shape" not in out:   # a bed the surrogate could not predict
        return _unpredicted(out)
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
    if out.get("risk"):
        r = out["risk"]
        lines.append(f"risk of a constant more than 10 % off: {r['risk']:.3g} (logit; flagged "
                     f"above {r['threshold']:.3g}, which {100 * r['flag_share']:.3g} % of the "
                     f"calibration beds exceed), interval bin {r['bin']}")
        if r.get("correction"):
            lines.append("constants corrected by the flag's error network by "
                         + ", ".join(f"{k} {100 * (v - 1):+.1f} %"
                                     for k, v in r["correction"].items()))
    lines += [f"note: {note}" for note in out.get("notes") or ()]
    reasons = out.get("flag_reasons", [])
    if "non-finite" in reasons:
        lines.append("FLAGGED: the surrogate's prediction is not finite (a damaged model?)")
    elif "risk" in reasons:
        lines.append("FLAGGED: a bed of the kind the surrogate gets wrong (its risk is above the "
                     "flag's threshold; docs/surrogate.md, \"The flag\"): solve it (--fallback)")
    elif reasons == ["interval"]:
        lines.append("FLAGGED: an interval is wider than the model's limit")
    elif "uncalibrated" in reasons:
        lines.append("FLAGGED: another size and another thickness or material at once: no "
                      "held-out beds of such a combination (solve it to trust it: --fallback)")
    elif out["flagged"]:
        lines.append("FLAGGED: unlike the training beds")
    elif out.get("risk"):   # "in distribution" would claim more than the risk says
        lines.append("not flagged: its risk is below the flag's threshold, though a few such "
                     "beds are more than 10 % off (their share at each --flag-share: "
                     "docs/surrogate.md, \"The flag\")")
    else:
        lines.append("in distribution")
    if out["source"] == "solver":
        lines.append("source: solver (PETSc, --fallback); its constants:")
        for k in NINE:
            lines.append(f"  {k:6s} {_fmt(k, out['properties'][k]):>16s}")
    else:
        lines.append("source: surrogate")
    t = out["timings"]
    stages = ("load_model", "read_bed", "pixelate", "bonds", "predict", "flag", "solve")
    parts = [f"{k.replace('_', ' ')} {t[k]:.3g} s" for k in stages if k in t]
    lines.append(f"time {out['seconds']:.3g} s: " + ", ".join(parts))
    if "start_up" in t:
        imaging = t.get("pixelate", 0.0) + t.get("bonds", 0.0)
        lines.append(f"one call: start-up {t['start_up']:.3g} s (Python and the imports), "
                     f"model {t['load_model']:.3g} s, imaging {imaging:.3g} s, "
                     f"network {t['predict']:.3g} s"
                     + (f", flag {t['flag']:.3g} s" if "flag" in t else ""))
    if output:
        lines.append(f"wrote {output}")
    return "\n".join(lines)


def _unpredicted(out):
    """The lines of a bed the surrogate could not predict: why, and its solve (--fallback)."""
    if out["source"] == "failed":
        return f"{out['bed']}: FAILED (not predicted): {out['error']}"
    return "\n".join([f"{out['bed']}: not predicted ({out['error']}); source: solver (PETSc, "
                      "--fallback); its constants:"]
                     + [f"  {k:6s} {_fmt(k, out['properties'][k]):>16s}" for k in NINE])


def _percent(fraction, width, sign):
    """A relative value as a percentage column; "-" for None (not finite)."""
    if fraction is None:
        return f"{'-':>{width + 1}s}"
    return f"{100 * fraction:{sign}{width}.2f}%"
