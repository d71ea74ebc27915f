"""What the report's writers share: matplotlib on the Agg backend, a PNG written atomically,
and seconds as a table shows them (run/report/write.py and rve_write.py import it)."""
import io

from amfe.io.atomic import atomic_write


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    _plt().close(fig)
    atomic_write(path, lambda fh: fh.write(buf.getvalue()))
    return path


def _s(x):
    """Seconds for a table: 3 significant digits, minutes/hours when long."""
    if x >= 3600:
        return f"{x / 3600:.2f} h"
    if x >= 120:
        return f"{x / 60:.1f} min"
    return f"{x:.3g} s"
