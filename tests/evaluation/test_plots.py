"""The comparison figures: what each line draws (the mean over runs), checked on the figure."""

import numpy as np

from lhf_hf.evaluation import plots


def _capture(monkeypatch) -> list:
    figures = []
    monkeypatch.setattr(plots, "save_figure_atomic", lambda fig, path: figures.append(fig))
    return figures


def test_sweep_figure_has_a_panel_per_backbone_and_a_line_per_value(monkeypatch, tmp_path):
    figures = _capture(monkeypatch)
    base = np.array([[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]])  # (runs, episodes)
    panels = {
        "AD": {"baseline": base, "lam=0": base + 1, "lam=1": base * 2},
        "DICP": {"baseline": base, "lam=0": base, "lam=1": base},
    }
    plots.plot_sweep(panels, tmp_path / "sweep.png", "darkroom")
    (fig,) = figures
    assert [ax.get_title() for ax in fig.axes] == ["AD", "DICP"]
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    assert list(lines) == ["baseline", "lam=0", "lam=1"]
    np.testing.assert_allclose(lines["baseline"].get_ydata(), [2.0, 3.0, 4.0])  # mean over runs
    np.testing.assert_allclose(lines["lam=1"].get_ydata(), [4.0, 6.0, 8.0])
    assert lines["baseline"].get_linestyle() == "--" and lines["lam=0"].get_linestyle() == "-"
    np.testing.assert_allclose(lines["lam=0"].get_xdata(), [1, 2, 3])  # test episodes from 1


def test_comparison_figure_draws_baseline_dashed_and_lhf_solid(monkeypatch, tmp_path):
    figures = _capture(monkeypatch)
    rows = {"AD": {"baseline": np.array([[0.0, 2.0]]), "lhf": np.array([[1.0, 3.0], [3.0, 5.0]])}}
    plots.plot_comparison(rows, tmp_path / "c.png", "darkroom")
    lines = {line.get_label(): line for line in figures[0].axes[0].get_lines()}
    assert lines["AD"].get_linestyle() == "--" and lines["AD (LHF)"].get_linestyle() == "-"
    np.testing.assert_allclose(lines["AD (LHF)"].get_ydata(), [2.0, 4.0])
