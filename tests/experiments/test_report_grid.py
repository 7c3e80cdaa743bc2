"""The comparison report's image grids: every title sits clear of the images above it."""
import numpy as np
import pytest

from dyngi.experiments import report
from dyngi.metrics.hdrflip import flip


@pytest.mark.parametrize("res, rows", [((160, 120), 2), ((320, 180), 3), ((96, 54), 1), ((64, 96), 2)])
def test_grid_titles_clear_of_images(tmp_path, monkeypatch, res, rows):
    import matplotlib.pyplot as plt

    w, h = res
    rng = np.random.default_rng(0)
    images = {f"tech{r}:key=value{r}": [rng.random((h, w, 3)).astype(np.float32)] for r in range(rows)}
    refs = [rng.random((h, w, 3)).astype(np.float32)]
    figs = []
    real_close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figs.append(fig))
    try:
        path = report._grid(str(tmp_path), 0, images, refs, flip)
    finally:
        monkeypatch.setattr(plt, "close", real_close)
    assert (tmp_path / "grid_0000.png").exists() and path.endswith("grid_0000.png")
    fig = figs[0]
    fig.canvas.draw()
    rend = fig.canvas.get_renderer()
    axes = np.array(fig.axes).reshape(rows, 3)
    sup = fig._suptitle.get_window_extent(rend)
    for r in range(rows):
        for c in range(3):
            title = axes[r, c].title.get_window_extent(rend)
            img = axes[r, c].get_window_extent(rend)
            assert title.y0 >= img.y1 - 1, "a title overlaps its own image"
            if r == 0:
                assert sup.y0 >= title.y1 - 1, "the frame title overlaps a row title"
            else:
                above = axes[r - 1, c].get_window_extent(rend)
                assert title.y1 <= above.y0 + 1, f"row {r}'s title overlaps the image above it"
    real_close(fig)
