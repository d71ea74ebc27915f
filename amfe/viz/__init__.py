"""Pictures of solved frames: what ``amfe view`` draws (docs/viewing.md).

- :mod:`amfe.viz.scene`: finds a result's case files and decides, once for
  every renderer, the colour array, its clipped range, the warp factor and sizes;
- :mod:`amfe.viz.render_mpl`: the matplotlib fallback (a bare machine, no display);
- :mod:`amfe.viz.pvrun`: runs ParaView's pvpython (under xvfb-run without a
  display) on :mod:`amfe.viz.amfe_view_pv`, the shipped script that also sets the
  same view up interactively.

Layer: dataset (README, Layout): it reads files through amfe.io and imports
neither PETSc nor torch; matplotlib is imported only when the fallback draws.
"""
