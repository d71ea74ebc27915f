"""Learning curves as PNG (matplotlib, Agg backend): loss and validation error per epoch."""
import os

import numpy as np

from amfe.io.atomic import atomic_write
from amfe.vocab import LABEL_NAMES


def plot_learning_curves(runs, path, title=""):
    """Write a PNG: loss (train solid, validation dashed) and validation mean relative error.

    runs: {name: history} or {name: [histories]} (an ensemble: every member
    drawn, the first labelled); a history is amfe.training.train's dict.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, (name, hists) in enumerate(runs.items()):
        hists = hists if isinstance(hists, list) else [hists]
        col = colors[c % len(colors)]
        for k, h in enumerate(hists):
            ep = np.arange(1, len(h["train_loss"]) + 1)
            alpha = 1.0 if k == 0 else 0.35
            ax1.semilogy(ep, h["train_loss"], color=col, alpha=alpha,
                         label=f"{name} train" if k == 0 else None)
            if h["val_loss"]:
                ax1.semilogy(ep, h["val_loss"], "--", color=col, alpha=alpha,
                             label=f"{name} validation" if k == 0 else None)
        h = hists[0]
        if h["val_mre"]:
            err = 100 * np.asarray(h["val_mre"])
            if len(runs) == 1:
                for j, prop in enumerate(LABEL_NAMES):
                    ax2.semilogy(np.arange(1, len(err) + 1), err[:, j], label=prop)
            else:
                ax2.semilogy(np.arange(1, len(err) + 1), err[:, :3].mean(1), color=col,
                             label=f"{name} moduli")
                ax2.semilogy(np.arange(1, len(err) + 1), err[:, 3:].mean(1), ":", color=col,
                             label=f"{name} Poisson ratios")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("MSE of the normalised labels")
    ax1.set_title("loss")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7)
    ax2.set_xlabel("epoch")
    ax2.set_ylabel("validation mean relative error [%]")
    ax2.set_title("validation error per property")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    try:   # atomically: an interrupted or failed write leaves no half picture
        atomic_write(path, lambda fh: fig.savefig(fh, dpi=110, format=fmt))
    finally:
        plt.close(fig)
    return path
