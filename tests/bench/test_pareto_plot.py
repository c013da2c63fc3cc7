"""pareto.png: log axes labelled at 1, 2, 5 per decade, minor ticks unlabelled."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from tactilesnn.app.plots import log_ticks


def test_an_axis_spanning_less_than_a_decade_gets_readable_labels():
    fig, ax = plt.subplots()
    ax.plot([0.21, 0.8], [0.1, 1.0])
    ax.set_xscale("log")
    ax.set_yscale("log")
    log_ticks(ax)
    fig.canvas.draw()
    lo, hi = ax.get_xlim()
    x_labels = [
        t.get_text()
        for t in ax.get_xticklabels()
        if t.get_text() and lo <= t.get_position()[0] <= hi
    ]
    minor = [t.get_text() for t in ax.xaxis.get_minorticklabels() if t.get_text()]
    plt.close(fig)
    assert x_labels == ["0.2", "0.5"] and minor == []  # was 2x10^-1 ... 8x10^-1 overlapping
