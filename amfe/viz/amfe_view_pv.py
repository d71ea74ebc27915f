"""ParaView view of amfe's load cases: the script ``amfe view`` runs, and the one to open by hand.

Not imported by amfe (it needs ParaView's ``paraview.simple``); it ships in the
package, and ``python -c "import amfe.viz, os; print(os.path.dirname(amfe.viz.__file__))"``
prints its folder. Render a PNG (what ``amfe view`` does, under ``xvfb-run -a``
without a display):

    pvpython amfe_view_pv.py out/case_xx.vtu --png view_xx.png [--color axial_force_N]
        [--title "axial force [N]"] [--label "xx: eps_xx = 1"] [--range LO HI] [--warp F]
        [--size 1200 900] [--state x.pvsm]

Set the same view up interactively:

    pvpython amfe_view_pv.py out/case_xx.vtu --interactive           (a render window)
    AMFE_VIEW_FILE=out/cases.pvd paraview --script=amfe_view_pv.py   (the full GUI, every case)
    paraview --state=view_xx.pvsm                                    (a state saved by --state)

Without --range/--warp the script computes them as amfe view does: the 2nd-98th
percentile of the colour array, and the warp factor that draws the largest
displacement as 5 % of the box (of a .pvd: the smallest factor of its cases,
from cases.json, so that no case draws more). Needs only ParaView (5.11) and numpy.

Pipeline: reader (XML UnstructuredGrid, or the .pvd) -> Outline (undeformed box);
reader -> Warp By Vector -> Extract Surface -> Tube (Tube wants PolyData; the
case files are UnstructuredGrids) coloured by a cell array over a fixed range,
and Warp By Vector -> Glyph spheres at 0.3 R on every point. The case label
comes from ``cases.json`` beside the file (meshio writes no field data): a Text
of it, or for a .pvd a Python Annotation that follows the time slider
(ParaView's time label says only "Time: k"). Frames of more than LARGE_LINES bonds draw
the bonds as lines and the particles as points instead: a bond is then about
a pixel, and tube and sphere geometry would cost a minute of software
rendering (measured on a 100 000-particle bed, docs/viewing.md).
"""
import json
import os
import sys
import time

import numpy as np

T_START = time.perf_counter()
from paraview import servermanager  # noqa: E402
from paraview.simple import (  # noqa: E402
    ColorBy,
    ExtractSurface,
    GetActiveViewOrCreate,
    GetColorTransferFunction,
    GetScalarBar,
    Glyph,
    Interact,
    Outline,
    PassArrays,
    PVDReader,
    PythonAnnotation,
    ResetCamera,
    SaveScreenshot,
    SaveState,
    Show,
    Text,
    Tube,
    WarpByVector,
    XMLUnstructuredGridReader,
)

SIGNED = ("axial_force_N", "torsion_Nm")
SPHERE_SHARE = 0.3
TUBE_SHARE = 0.12
LARGE_LINES = 100_000
TIMES = {}


def parse(argv):
    """Command-line options as a dict (no argparse: ParaView's GUI owns sys.argv)."""
    opts = {"file": os.environ.get("AMFE_VIEW_FILE"), "png": None, "color": "axial_force_N",
            "title": None, "label": None, "range": None, "warp": None, "size": (1200, 900),
            "state": None, "interactive": False}
    it = iter(argv)
    for a in it:
        if a in ("--png", "--color", "--title", "--label", "--state"):
            opts[a[2:]] = next(it)
        elif a == "--range":
            opts["range"] = (float(next(it)), float(next(it)))
        elif a == "--warp":
            opts["warp"] = float(next(it))
        elif a == "--size":
            opts["size"] = (int(next(it)), int(next(it)))
        elif a == "--interactive":
            opts["interactive"] = True
        elif not a.startswith("-"):
            opts["file"] = a
    return opts


def measure(reader, color):
    """Warp factor and 2-98 percentile range from the data, as amfe view computes them."""
    from vtkmodules.numpy_interface import dataset_adapter as dsa  # noqa: PLC0415 (heavy or optional: loaded when used)

    data = dsa.WrapDataObject(servermanager.Fetch(reader))
    x = np.asarray(data.Points)
    u = np.asarray(data.PointData["displacement_m"])
    v = np.asarray(data.CellData[color])
    v = np.linalg.norm(v, axis=1) if v.ndim == 2 else v
    umax = float(np.linalg.norm(u, axis=1).max())
    warp = 0.05 * float(np.ptp(x, axis=0).max()) / umax if umax > 0 else 1.0
    lo, hi = (float(t) for t in np.percentile(v, (2, 98)))
    return warp, (lo, hi if hi > lo else lo + 1.0)


def _colour(display, view, opts, rng):
    ColorBy(display, ("CELLS", opts["color"], "Magnitude"))
    lut = GetColorTransferFunction(opts["color"])
    lut.AutomaticRescaleRangeMode = "Never"
    if opts["color"] in SIGNED and rng[0] < 0.0 < rng[1]:   # white at zero, as amfe view's
        lut.ApplyPreset("Cool to Warm", True)
        lut.RGBPoints = [rng[0], 0.23, 0.299, 0.754, 0.0, 0.865, 0.865, 0.865,
                         rng[1], 0.706, 0.016, 0.15]
    else:
        lut.ApplyPreset("Viridis (matplotlib)", True)
        lut.RescaleTransferFunction(*rng)
    bar = GetScalarBar(lut, view)
    bar.Title = opts["title"] or opts["color"]
    bar.ComponentTitle = ""
    bar.TitleColor = bar.LabelColor = [0, 0, 0]
    bar.Visibility = 1
    bar.WindowLocation = "Any Location"        # right, middle: clear of the note below
    bar.Position = [0.86, 0.2]
    bar.ScalarBarLength = 0.6
    bar.AddRangeLabels = 1
    bar.RangeLabelFormat = "%-.3g"


def _label(view, source, where, size):
    shown = Show(source, view)
    shown.WindowLocation = where
    shown.FontSize = size
    shown.Color = [0, 0, 0]


def sidecar(path):
    """The cases of the ``cases.json`` beside ``path`` (amfe.io.pvd), or [] without one."""
    try:
        with open(os.path.join(os.path.dirname(os.path.abspath(path)), "cases.json")) as fh:
            return json.load(fh)["cases"]
    except (OSError, ValueError, KeyError, TypeError):
        return []


def case_label(opts, cases):
    """A source that shows the case label: a Text, or for a .pvd one that follows the time."""
    if opts["file"].endswith(".pvd"):
        labels = ["case " + c.get("case_label", c.get("case_name", "?")) for c in cases]
        if labels:
            return PythonAnnotation(registrationName="case name", Input=opts["reader"],
                                    Expression=f"{labels!r}[t_index]")
    mine = [c for c in cases if c.get("file") == os.path.basename(opts["file"])]
    text = opts["label"] or (mine[0].get("case_label") if mine else None) or \
        os.path.basename(opts["file"])
    return Text(registrationName="case name", Text="case " + text)


def build(opts):
    """Set the pipeline and the view up; returns the view."""
    t_start = time.perf_counter()
    name = os.path.basename(opts["file"])
    if name.endswith(".pvd"):
        reader = PVDReader(registrationName=name, FileName=opts["file"])
    else:
        reader = XMLUnstructuredGridReader(registrationName=name, FileName=[opts["file"]])
    reader.UpdatePipeline()
    opts["reader"] = reader
    t_read = time.perf_counter()
    cases = sidecar(opts["file"])
    warp, rng = opts["warp"], opts["range"]
    if warp is None and name.endswith(".pvd") and cases:   # no case draws more than 5 %
        warp = min(float(c["warp_factor"]) for c in cases)
    if warp is None or rng is None:
        measured = measure(reader, opts["color"])
        warp, rng = measured[0] if warp is None else warp, rng or measured[1]
    rmean = sum(reader.PointData["radius_m"].GetRange()) / 2
    large = reader.GetDataInformation().GetNumberOfCells() > LARGE_LINES
    view = GetActiveViewOrCreate("RenderView")
    view.ViewSize = list(opts["size"])
    view.OrientationAxesVisibility = 1
    view.Background = [1, 1, 1]
    if hasattr(view, "UseColorPaletteForBackground"):
        view.UseColorPaletteForBackground = 0

    outline = Show(Outline(registrationName="undeformed outline", Input=reader), view)
    outline.AmbientColor = outline.DiffuseColor = [0.3, 0.3, 0.3]
    warped = WarpByVector(registrationName=f"warped x {warp:.3g}", Input=reader)
    warped.Vectors = ["POINTS", "displacement_m"]
    warped.ScaleFactor = warp
    if large:                                  # lines and points: a bond is about a pixel
        bonds = PassArrays(registrationName="bonds", Input=warped, PointDataArrays=[],
                           CellDataArrays=[opts["color"]], FieldDataArrays=[])
        _colour(Show(bonds, view), view, opts, rng)   # one array: less to copy to the GPU
        spheres = Show(PassArrays(registrationName="particles", Input=warped,
                                  PointDataArrays=[], CellDataArrays=[]), view)
    else:
        surface = ExtractSurface(registrationName="lines as PolyData", Input=warped)
        tubes = Tube(registrationName="bonds", Input=surface)
        tubes.Radius = TUBE_SHARE * rmean
        tubes.NumberofSides = 8
        _colour(Show(tubes, view), view, opts, rng)
        glyphs = Glyph(registrationName="particles", Input=warped, GlyphType="Sphere")
        glyphs.ScaleArray = ["POINTS", "radius_m"]
        glyphs.ScaleFactor = 2 * SPHERE_SHARE     # the source sphere has radius 0.5
        glyphs.GlyphMode = "All Points"           # the default samples at most 5000 points
        glyphs.GlyphType.ThetaResolution = 10
        glyphs.GlyphType.PhiResolution = 8
        spheres = Show(glyphs, view)
    ColorBy(spheres, ("POINTS", None))
    spheres.AmbientColor = spheres.DiffuseColor = [0.55, 0.55, 0.55]
    if large:
        spheres.SetRepresentationType("Points")
        spheres.PointSize = 2.0

    _label(view, case_label(opts, cases), "Upper Left Corner", 20)
    of_all = " of all cases" if name.endswith(".pvd") and opts["warp"] is None else ""
    shapes = "bonds as lines, particles as points" if large else \
        f"particles as spheres at {SPHERE_SHARE:g} R"
    _label(view, Text(registrationName="note",
                      Text=f"displacement x {warp:.3g} (largest{of_all} = 5 % of box); {shapes}; "
                           "grey box: undeformed outline\ncolours: 2-98 percentile range of the "
                           "bonds (beyond it: the end colours)"), "Lower Left Corner", 12)
    view.CameraFocalPoint = [0.0, 0.0, 0.0]     # z up, seen from -y, +x and above;
    view.CameraPosition = [1.0, -1.6, 1.0]      # ResetCamera keeps the direction and fits
    view.CameraViewUp = [0.0, 0.0, 1.0]
    ResetCamera(view)
    print(f"warp factor {warp:.4g}; range {rng[0]:.4g} .. {rng[1]:.4g}; {shapes}")
    TIMES.update(start_up=t_start - T_START, read=t_read - t_start,
                 pipeline=time.perf_counter() - t_read)
    return view


def main(argv):
    opts = parse(argv)
    if not opts["file"]:
        print("usage: pvpython amfe_view_pv.py CASE.vtu|cases.pvd [--png OUT.png] [--interactive]",
              file=sys.stderr)
        return 2
    view = build(opts)
    if opts["state"]:
        SaveState(opts["state"])
        print(f"wrote {opts['state']}")
    if opts["png"]:
        t0 = time.perf_counter()
        SaveScreenshot(opts["png"], view, ImageResolution=list(opts["size"]))
        TIMES["render_and_save"] = time.perf_counter() - t0
        print(f"wrote {opts['png']}")
    print("seconds: " + ", ".join(f"{k.replace('_', ' ')} {v:.2f}" for k, v in TIMES.items()))
    if opts["interactive"]:
        Interact(view)
    return 0


# paraview --script runs this file as __main__ too, with sys.argv == [""]: there it only
# builds the view (main's os._exit would close the GUI at once).
IN_GUI = not sys.argv or not sys.argv[0]
if __name__ == "__main__" and not IN_GUI:
    status = main(sys.argv[1:])
    # Debian's ParaView 5.11 under Xvfb dies in teardown with "GLXBadContext" and exit
    # status 1 after everything is written: leave without the teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
elif os.environ.get("AMFE_VIEW_FILE"):     # paraview --script=amfe_view_pv.py
    build(parse([]))
