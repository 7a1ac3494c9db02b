"""The figures the plotting functions draw, kept open for checks a PNG cannot answer (where tick labels lie)."""
import contextlib


@contextlib.contextmanager
def kept_figure():
    """``with kept_figure() as shown: plot(...)``: the figure the plotting function closes, as ``shown["fig"]``,
    kept open inside the block and closed after it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    shown, close = {}, plt.close
    plt.close = lambda fig=None: shown.setdefault("fig", fig)
    try:
        yield shown
    finally:
        plt.close = close
        if "fig" in shown:
            plt.close(shown["fig"])


def overlapping_tick_labels(ax) -> list[str]:
    """The x axis's shown tick labels inside its view, left to right, where two neighbours overlap; [] where none do."""
    fig = ax.figure
    r = fig.canvas.get_renderer()
    lo, hi = sorted(ax.get_xlim())
    ticks = [t for t in ax.xaxis.get_major_ticks() + ax.xaxis.get_minor_ticks()
             if t.label1.get_visible() and t.label1.get_text() and lo <= t.get_loc() <= hi]
    boxes = sorted(((t.label1.get_window_extent(r), t.label1.get_text()) for t in ticks), key=lambda b: b[0].x0)
    return [] if all(a.x1 <= b.x0 for (a, _), (b, _) in zip(boxes, boxes[1:])) else [t for _, t in boxes]
