"""ParaView view of one amfe load case: the script ``amfe view`` runs, and the one to open by hand.

Not imported by amfe (it needs ParaView's ``paraview.simple``); it ships in the
package, and ``python -c "import amfe.viz, os; print(os.path.dirname(amfe.viz.__file__))"``
prints its folder. Render a PNG (what ``amfe view`` does, under ``xvfb-run -a``
without a display):

    pvpython amfe_view_pv.py out/case_xx.vtp --png view_xx.png [--color axial_force_N]
        [--title "axial force [N]"] [--range LO HI] [--warp F] [--size 1200 900] [--state x.pvsm]

Set the same view up interactively:

    pvpython amfe_view_pv.py out/case_xx.vtp --interactive           (a render window)
    AMFE_VIEW_FILE=out/case_xx.vtp paraview --script=amfe_view_pv.py   (the full GUI)
    paraview --state=view_xx.pvsm                                    (a state saved by --state)

Without --range/--warp the script computes them as amfe view does: the 2nd-98th
percentile of the colour array, and the warp factor that draws the largest
displacement as 5 % of the box. Needs only ParaView (5.11) and numpy.

Pipeline: reader -> Outline (undeformed box); reader -> Warp By Vector -> Tube
coloured by a cell array over a fixed range, and -> Glyph spheres at 0.3 R on
every point; Annotate Attribute Data shows the field ``case_label`` (ParaView's
time label says only "Time: k"). Frames of more than LARGE_LINES bonds draw
the bonds as lines and the particles as points instead: a bond is then about
a pixel, and tube and sphere geometry would cost a minute of software
rendering (measured on a 100 000-particle bed, docs/viewing.md).
"""
import os
import sys
import time

T_START = time.perf_counter()
from paraview.simple import (AnnotateAttributeData, ColorBy, GetActiveViewOrCreate,  # noqa: E402
                             GetColorTransferFunction, GetScalarBar, Glyph, Interact,
                             Outline, PassArrays, ResetCamera, SaveScreenshot,
                             SaveState, Show, Text, Tube, WarpByVector, XMLPolyDataReader)
from paraview import servermanager  # noqa: E402

SIGNED = ("axial_force_N", "torsion_Nm")
SPHERE_SHARE = 0.3
TUBE_SHARE = 0.12
LARGE_LINES = 100_000
TIMES = {}


def parse(argv):
    """Command-line options as a dict (no argparse: ParaView's GUI owns sys.argv)."""
    opts = {"file": os.environ.get("AMFE_VIEW_FILE"), "png": None, "color": "axial_force_N",
            "title": None, "range": None, "warp": None, "size": (1200, 900), "state": None,
            "interactive": False}
    it = iter(argv)
    for a in it:
        if a in ("--png", "--color", "--title", "--state"):
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
    import numpy as np
    from vtkmodules.numpy_interface import dataset_adapter as dsa

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


def build(opts):
    """Set the pipeline and the view up; returns the view."""
    t_start = time.perf_counter()
    reader = XMLPolyDataReader(registrationName=os.path.basename(opts["file"]),
                               FileName=[opts["file"]])
    reader.UpdatePipeline()
    t_read = time.perf_counter()
    warp, rng = opts["warp"], opts["range"]
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
        tubes = Tube(registrationName="bonds", Input=warped)
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

    label = AnnotateAttributeData(registrationName="case name", Input=reader)
    label.SelectInputArray = ["FIELD", "case_label"]
    label.Prefix = "case "
    _label(view, label, "Upper Left Corner", 20)
    shapes = "bonds as lines, particles as points" if large else \
        f"particles as spheres at {SPHERE_SHARE:g} R"
    _label(view, Text(registrationName="note",
                      Text=f"displacement x {warp:.3g} (largest = 5 % of box); {shapes}; grey "
                           "box: undeformed outline\ncolours: 2-98 percentile range of the "
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
        print("usage: pvpython amfe_view_pv.py CASE.vtp [--png OUT.png] [--interactive]",
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


if __name__ == "__main__":
    status = main(sys.argv[1:])
    # Debian's ParaView 5.11 under Xvfb dies in teardown with "GLXBadContext" and exit
    # status 1 after everything is written: leave without the teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
elif os.environ.get("AMFE_VIEW_FILE"):     # paraview --script=amfe_view_pv.py
    build(parse([]))
