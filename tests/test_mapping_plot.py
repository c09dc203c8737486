"""map.png: trees, trajectory and start drawn where they are, on equal axes, for local and
georeferenced (7-digit) coordinates."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from forestslam.mapping.plot import _MapCanvas, _nice_step, plot_map

GREEN, BLUE = (44, 160, 44), (31, 119, 180)


@pytest.mark.parametrize("offset", [0.0, 6543210.5])
def test_trees_and_trajectory_are_drawn_at_their_positions(tmp_path, offset):
    trees = np.array([[5.0, 5.0], [-8.0, 3.0], [2.0, -9.0]]) + offset
    dbh = np.array([0.3, np.nan, 0.4])  # unknown DBH: drawn at 0.1 m
    t = np.linspace(0, np.pi, 50)
    traj = np.column_stack([6 * np.cos(t), 6 * np.sin(t)]) + offset
    plot_map(tmp_path / "map.png", traj, traj + 0.2, trees, dbh, title="t")
    image = np.asarray(Image.open(tmp_path / "map.png").convert("RGB"))
    assert image.shape == (960, 960, 3)
    canvas = _MapCanvas(traj, traj + 0.2, trees)  # the same mapping as plot_map's
    for u, v in canvas.px(trees).round().astype(int):
        assert tuple(image[v, u]) == GREEN
    u, v = canvas.px(traj[25]).round().astype(int)[0]
    patch = image[v - 1 : v + 2, u - 1 : u + 2].reshape(-1, 3)
    assert any(tuple(p) == BLUE for p in patch)
    assert canvas.px([[1.0 + offset, 0.0]])[0, 0] - canvas.px([[offset, 0.0]])[0, 0] == (
        pytest.approx(canvas.px([[0.0, offset]])[0, 1] - canvas.px([[0.0, 1.0 + offset]])[0, 1])
    )  # equal axes, y up


def test_empty_map_is_still_a_figure(tmp_path):
    plot_map(tmp_path / "map.png", np.zeros((0, 2)), None, np.zeros((0, 2)), np.zeros(0))
    assert Image.open(tmp_path / "map.png").size == (960, 960)


@pytest.mark.parametrize(("raw", "step"), [(0.7, 1.0), (1.3, 2.0), (3.0, 5.0), (7.0, 10.0)])
def test_tick_steps_are_one_two_five(raw, step):
    assert _nice_step(raw) == pytest.approx(step)
