"""`amfe view RESULT_DIR_or_PVD`: PNG pictures of the deformed frames (docs/viewing.md).

    amfe view out/ [-o DIR] [--case xx] [--color axial_force] [--backend auto]
        [--size 1200x900] [--state]

One PNG per load case (or only --case): bonds as tubes coloured over their
2nd-98th percentile range with a labelled colour bar, displacements scaled so
the largest is 5 % of the box (the factor is printed), the undeformed outline,
particles as spheres at 0.3 of their radius. Uses ParaView's pvpython when it
is installed (under xvfb-run without a display), matplotlib otherwise.
"""
import os
import time

from amfe.errors import AmfeError

BACKENDS = ("auto", "paraview", "matplotlib")
SIZE_RANGE = (16, 8192)


def register(sub):
    from amfe.viz.scene import COLOR_ARRAYS

    p = sub.add_parser("view", help="render PNGs of the deformed frames (ParaView or matplotlib)",
                       description=__doc__.split("\n\n")[0],
                       epilog="The same view in ParaView's window: see docs/viewing.md "
                              "(amfe_view_pv.py, shipped in amfe/viz/).")
    p.add_argument("target", metavar="RESULT_DIR_or_PVD",
                   help="directory of 'amfe homogenize --vtu DIR', its cases.pvd, or one .vtu")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="directory for the PNGs (default: beside the case files)")
    p.add_argument("--case", help="only this load case, e.g. xx (default: every case)")
    p.add_argument("--color", default="axial_force", metavar="QUANTITY",
                   help="bond quantity to colour by: " + ", ".join(COLOR_ARRAYS)
                        + " (default axial_force)")
    p.add_argument("--backend", default="auto", choices=BACKENDS,
                   help="auto (default): ParaView's pvpython when it can run here, else "
                        "matplotlib")
    p.add_argument("--size", default="1200x900", metavar="WxH",
                   help="PNG size in pixels (default 1200x900)")
    p.add_argument("--state", action="store_true",
                   help="ParaView only: also save view_<case>_<color>.pvsm beside each PNG "
                        "(open it with paraview --state=...)")
    p.set_defaults(func=run)


def parse_size(text):
    """``"1200x900"`` -> (1200, 900); AmfeError unless both sides lie in SIZE_RANGE pixels."""
    try:
        w, h = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise AmfeError(f"--size {text!r}: give WIDTHxHEIGHT in pixels, e.g. 1200x900") from None
    lo, hi = SIZE_RANGE
    if not (lo <= w <= hi and lo <= h <= hi):
        raise AmfeError(f"--size {text!r}: each side must lie in {lo}..{hi} pixels")
    return w, h


def plan(args):
    """Check every option before anything is written: (files, outdir, size, pvpython or None)."""
    from amfe.io.paths import check_output_dir
    from amfe.viz.pvrun import INSTALL_HINT, paraview_command
    from amfe.viz.scene import case_files, check_color, select_cases

    check_color(args.color)
    size = parse_size(args.size)
    files = select_cases(case_files(args.target), args.case)
    outdir = args.output or os.path.dirname(files[0][1])
    check_output_dir(outdir, option="-o")
    if args.state and args.backend == "matplotlib":
        raise AmfeError("--state saves a ParaView state; it needs --backend auto or paraview")
    cmd = paraview_command() if args.backend != "matplotlib" else None
    if cmd is None and args.backend == "paraview":
        raise AmfeError("--backend paraview needs pvpython, and a display or xvfb-run "
                        f"({INSTALL_HINT}); or use --backend matplotlib")
    return files, outdir, size, cmd


def run(args):
    from amfe.viz import pvrun
    from amfe.viz.scene import load_scene, png_name

    files, outdir, size, cmd = plan(args)
    os.makedirs(outdir, exist_ok=True)
    for name, path in files:
        t0 = time.perf_counter()
        scene = load_scene(name, path, args.color)
        png = png_name(outdir, name, args.color)
        used = None
        if cmd is not None:
            state = os.path.splitext(png)[0] + ".pvsm" if args.state else None
            if pvrun.render(cmd, scene, png, size, state):
                used = "paraview"
            elif args.backend == "paraview":
                raise AmfeError(f"pvpython could not render case {name} (its output is "
                                "above); try --backend matplotlib")
            else:
                print("amfe view: falling back to matplotlib", flush=True)
                cmd = None
        if used is None:
            from amfe.viz.render_mpl import render
            render(scene, png, size)
            used = "matplotlib"
        print(f"{scene.summary()}; {used}, {time.perf_counter() - t0:.2f} s")
        print(f"wrote {png}", flush=True)
    return 0
