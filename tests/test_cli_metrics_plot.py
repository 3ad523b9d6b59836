"""metrics.png as the retarget writes it: a title by default, the contact count on its own axis."""

import numpy as np
import pytest

from solver.retarget.metrics import Intersections, plot_metrics

pytest.importorskip("matplotlib")


@pytest.fixture
def figures(monkeypatch):
    """The figures plot_metrics saves."""
    from matplotlib.figure import Figure

    saved = []
    savefig = Figure.savefig

    def keep(self, *args, **kwargs):
        saved.append(self)
        return savefig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved


def test_the_contact_count_has_its_own_axis_and_the_plot_a_title(tmp_path, figures):
    F = 240
    t = np.arange(F)
    marker = 0.01 + 0.002 * np.sin(t / 20)  # metres: about 1 cm
    contact = np.where((t > 60) & (t < 180), 0.003, np.nan)
    count = np.where((t > 60) & (t < 180), 1500, 0)
    inter = Intersections(np.abs(np.sin(t / 30)), 0.1 * np.ones(F), np.zeros(F), np.ones(F))
    kwargs = dict(marker_distance=marker, contact_distance=contact, contact_count=count, intersections=inter)
    plot_metrics(tmp_path / "metrics.png", 120.0, **kwargs)  # as save_result calls it: no title given
    [fig] = figures
    assert fig._suptitle.get_text() == "retargeting metrics: 240 frames (2.0 s at 120 fps)"
    distance, intersections, counts = fig.axes
    assert distance.get_ylabel() == "distance (cm)"
    # The distance axis holds distances only: its range is the centimetres', not 1500 contacts'.
    assert not distance.collections and distance.get_ylim()[1] < 2
    assert "contacts" in counts.get_ylabel() and "count" in counts.get_ylabel()
    assert counts.get_ylim() == pytest.approx((0, 1.05 * 1500))
    [band] = counts.collections
    assert band.get_paths()[0].vertices[:, 1].max() == pytest.approx(1500)  # drawn as counts
    assert counts.get_shared_x_axes().joined(counts, distance)  # the same time axis, its own y axis
    assert [text.get_text() for text in distance.get_legend().get_texts()] == [
        "marker distance",
        "contact distance",
        "contacts (right axis)",
    ]
    assert intersections.get_xlabel() == "time (s)" and distance.get_xlabel() == ""
    # A caller's title; "" for none.
    plot_metrics(tmp_path / "a.png", 120.0, title="grasp.npz: 240 frames onto alien (scale 1)", **kwargs)
    plot_metrics(tmp_path / "b.png", 120.0, title="", **kwargs)
    assert figures[1]._suptitle.get_text() == "grasp.npz: 240 frames onto alien (scale 1)"
    assert figures[2]._suptitle is None
