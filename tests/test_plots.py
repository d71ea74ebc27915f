"""The docs' plot helpers (amfe.training.plots): plain log ticks, whole epochs, labels apart."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from amfe.training.plots import integer_epochs, plain_log_axis, spread_labels  # noqa: E402


def test_percent_ticks_plain_and_inside_the_view():
    fig, ax = plt.subplots()
    ax.semilogy([1, 2], [4.5, 48])
    plain_log_axis(ax.yaxis, " %")
    fig.canvas.draw()
    lo, hi = ax.get_ylim()
    ticks = [t for t in ax.get_yticks() if lo <= t <= hi]
    labels = [t.get_text() for t in ax.get_yticklabels() if t.get_text()]
    assert labels == [f"{t:g} %" for t in ticks] and 3 <= len(ticks) <= 8
    assert "5 %" in labels and "10 %" in labels
    assert not [t.get_text() for t in ax.get_yminorticklabels() if t.get_text()]
    plt.close(fig)


def test_integer_epochs_on_a_short_run():
    fig, ax = plt.subplots()
    ax.plot(np.arange(1, 4), [3, 2, 1])
    integer_epochs(ax)
    fig.canvas.draw()
    assert all(float(t).is_integer() for t in ax.get_xticks())
    plt.close(fig)


def test_labels_of_crowded_points_do_not_overlap():
    fig, ax = plt.subplots(figsize=(4, 3))
    x = np.array([1.0, 1.02, 1.04, 1.06, 1.08])
    y = np.array([1.0, 1.01, 1.0, 1.01, 1.0])
    ax.plot(x, y, "o-")
    ax.set_xlim(0.8, 1.3)
    ax.set_ylim(0.9, 1.1)
    spread_labels(ax, list(zip(x, y)), [f"1e-0{k}" for k in range(5)], fontsize=6)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.texts]
    assert len(boxes) == 5
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    plt.close(fig)
