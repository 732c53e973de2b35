"""map.png: a passenger's sensing drawn as the world counts it (the disc cut by the walls), the
stage labels of one spot merged, nothing hidden by the scale bar (it sits outside the map)."""
from __future__ import annotations

import numpy as np
import pytest

import world
from world.geometry import visible_region
from world.paths import REPO_ROOT


def test_the_sensing_disc_stops_at_walls():
    wall = np.array([[2.0, -5.0, 2.0, 5.0]])  # a wall at x = 2 across the disc
    seen = visible_region((0.0, 0.0), 5.0, wall, rays=360)
    assert seen[:, 0].max() == pytest.approx(2.0)  # nothing drawn past the wall
    assert seen[:, 0].min() == pytest.approx(-5.0)  # the open side reaches the radius
    assert np.hypot(*seen.T).max() == pytest.approx(5.0)
    open_field = visible_region((1.0, 1.0), 3.0, np.zeros((0, 4)), rays=90)
    assert np.allclose(np.hypot(*(open_field - 1.0).T), 3.0)


def test_stage_labels_of_one_spot_are_merged(tmp_path):
    from matplotlib import pyplot as plt

    from world.render import _stage_labels
    from world.stages import stage_geometry

    s = world.load_scenario(REPO_ROOT / "scenarios" / "six_carriers.yaml")
    geo = stage_geometry(s)
    fig, ax = plt.subplots()
    _stage_labels(ax, s, geo, 1.5)
    texts = [(t.xy, t.get_text(), t.xyann) for t in ax.texts]
    plt.close(fig)
    # one label per (spot, carrier): no two labels written at the same place
    assert len({(tuple(np.round(xy, 6)), off) for xy, _, off in texts}) == len(texts)
    assert sum(len(t.split(",")) if "-" not in t else 2 for _, t, _ in texts) <= int(geo.valid.sum())
    out = world.render_map(s, tmp_path / "map.png", title="six_carriers\nreward 1.000")
    assert out.stat().st_size > 10_000
