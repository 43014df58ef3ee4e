"""Figures: time axes in seconds and monotone, units on every axis, legends off the data, maneuver shading only
where the runs share it, q plot on its axis, trajectory zoom, scope-frame ticks inside the frame, warning-chart
labels not cut, training curve naming its stages."""

import json
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from agents.evaluation import plots  # noqa: E402
from agents.evaluation.suites import draw_suite  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.episode import stack_episodes  # noqa: E402

TRACKERS = ("kf_low", "cmin", "clairvoyant")
UNIT = re.compile(r"\(.+\)|\[.+\]")
BUNDLED_CONFIG = Path(__file__).resolve().parents[1] / "agents" / "bundled" / "train_config.json"


@pytest.fixture(scope="module")
def suites():
    out = {}
    for name, runs in (("bizup2002", 3), ("random_radars", 4)):
        eps = draw_suite(name, runs, seed=123)
        out[name] = (stack_episodes(eps), {t: run_tracker(t, eps) for t in TRACKERS})
    return out


def _figures(suite, batch, runs):
    return [f for f in (plots.error_figure(suite, batch, runs), plots.trajectory_figure(suite, batch, runs),
                        plots.q_figure(suite, batch, runs), plots.features_figure(suite, batch, runs)) if f]


def _tracker_lines(ax):
    return [ln for ln in ax.get_lines() if ln.get_label() in TRACKERS]


def test_suite_figures_write_every_png(suites, tmp_path):
    batch, runs = suites["bizup2002"]
    files = plots.suite_figures("bizup2002", batch, runs, tmp_path)
    assert sorted(p.name for p in files) == [f"bizup2002_{k}.png" for k in ("errors", "features", "q", "trajectory")]
    assert all(p.stat().st_size > 0 for p in files)


def test_random_radars_runs_have_different_look_times(suites):
    """The premise of the binned error curves (each random-radar run has its own scan period)."""
    batch, _ = suites["random_radars"]
    assert not plots.shared_look_times(batch)
    assert plots.shared_look_times(suites["bizup2002"][0])


@pytest.mark.parametrize("suite", ["bizup2002", "random_radars"])
def test_error_curves_strictly_increasing_in_seconds(suites, suite):
    batch, runs = suites[suite]
    fig = plots.error_figure(suite, batch, runs)
    longest_s = max(batch.t_s[b, batch.n_looks[b] - 1] - batch.t_s[b, 0] for b in range(batch.batch_size))
    for ax in fig.axes:
        lines = _tracker_lines(ax)
        assert {ln.get_label() for ln in lines} == set(TRACKERS)
        for ln in lines:
            x = np.asarray(ln.get_xdata(), float)
            assert x.size > 5 and np.all(np.diff(x) > 0), ln.get_label()
            assert x[0] >= 0 and x[-1] <= longest_s + plots.error_bin_width_s(batch)
            assert np.all(np.isfinite(ln.get_ydata()))
    xlabel = fig.axes[-1].get_xlabel()
    assert ("track start" in xlabel) == (suite == "random_radars") and "(s)" in xlabel
    plt.close(fig)


def test_error_figure_leaves_failed_runs_out_and_says_so(suites):
    """A run whose estimate goes non-finite is left out of the tracker's curves whole (not silently dropped look by
    look, which would bias the mean), and the legend counts it; the other trackers' curves do not change."""
    import dataclasses
    batch, runs = suites["random_radars"]
    x = runs["kf_low"].x.copy()
    x[1, int(runs["kf_low"].start_index[1]) + 3, 0] = np.inf
    bad = dict(runs, kf_low=dataclasses.replace(runs["kf_low"], x=x))
    fig_ok = plots.error_figure("random_radars", batch, runs)
    fig = plots.error_figure("random_radars", batch, bad)
    labels = [ln.get_label() for ln in fig.axes[0].get_lines()]
    assert "kf_low (1 failed run(s) left out)" in labels
    ok_lines = {ln.get_label(): ln for ln in fig_ok.axes[0].get_lines()}
    for ln in fig.axes[0].get_lines():
        y = np.asarray(ln.get_ydata(), float)
        assert np.all(np.isfinite(y))
        if ln.get_label() in ok_lines and ln.get_label() != "kf_low":
            np.testing.assert_array_equal(y, ok_lines[ln.get_label()].get_ydata())
    # without run 1 the kf_low curve differs from the all-runs one
    changed = [ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("kf_low")][0]
    assert not np.array_equal(np.asarray(changed.get_ydata()), np.asarray(ok_lines["kf_low"].get_ydata()))
    plt.close(fig)
    plt.close(fig_ok)


def test_binned_error_stats_are_per_run_means_over_the_runs_in_each_bin():
    # run 0 looks every 2 s up to 22 s, run 1 every 5 s up to 15 s, run 2 every 3 s up to 9 s
    t = np.full((3, 12), np.nan)
    t[0, :12] = 2.0 * np.arange(12)
    t[1, :4] = 5.0 * np.arange(4)
    t[2, :4] = 3.0 * np.arange(4)
    rng = np.random.default_rng(0)
    err = np.where(np.isfinite(t), rng.uniform(1, 100, t.shape), np.nan)
    width, min_runs = 10.0, 2
    centres, mean, lo, hi = plots.binned_error_stats(t, err, width, min_runs)
    expect_c, expect_m = [], []
    for i in range(3):
        per_run = [np.mean(err[b][(t[b] >= i * width) & (t[b] < (i + 1) * width)]) for b in range(3)
                   if np.any((t[b] >= i * width) & (t[b] < (i + 1) * width))]
        if len(per_run) >= min_runs:
            expect_c.append((i + 0.5) * width)
            expect_m.append(np.mean(per_run))
    assert centres.tolist() == expect_c and np.allclose(mean, expect_m)
    assert np.all(lo <= mean) and np.all(mean <= hi)
    # the last bin (20-22 s) has run 0 only: hidden
    assert centres[-1] < 20.0


def test_maneuver_shading_only_where_runs_share_maneuver_times(suites):
    for suite, shaded in (("bizup2002", True), ("random_radars", False)):
        batch, runs = suites[suite]
        fig = plots.error_figure(suite, batch, runs)
        labels = [t.get_text() for lg in fig.legends for t in lg.get_texts()]
        assert any("maneuver" in s for s in labels) == shaded, suite
        if not shaded:
            assert "not shaded" in fig.axes[-1].get_xlabel()
        plt.close(fig)


@pytest.mark.parametrize("suite", ["bizup2002", "random_radars"])
def test_every_axis_labelled_with_units_and_legends_off_the_axes(suites, suite):
    batch, runs = suites[suite]
    for fig in _figures(suite, batch, runs):
        fig.canvas.draw()
        axes = fig.axes
        for ax in axes:
            assert UNIT.search(ax.get_ylabel()), (fig.axes[0].get_title(), ax.get_ylabel())
            if ax.get_subplotspec().is_last_row():
                assert UNIT.search(ax.get_xlabel()), (fig.axes[0].get_title(), ax.get_xlabel())
        legends = list(fig.legends) + [ax.get_legend() for ax in axes if ax.get_legend()]
        assert legends
        r = fig.canvas.get_renderer()
        for lg in legends:
            box = lg.get_window_extent(r)
            for ax in axes:
                assert not box.overlaps(ax.get_window_extent(r)), fig.axes[0].get_title()
        plt.close(fig)


def test_q_plot_keeps_every_series_on_its_axis_with_a_labelled_floor(suites):
    batch, runs = suites["bizup2002"]
    assert np.nanmin(runs["clairvoyant"].q_m_s2[0]) == 0.0    # the case to draw: q = 0 on a log axis
    fig = plots.q_figure("bizup2002", batch, runs)
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    for ln in ax.get_lines():
        y = np.asarray(ln.get_ydata(), float)
        y = y[np.isfinite(y)]
        assert y.size and np.all((y >= lo) & (y <= hi)), ln.get_label()
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(s.startswith("floor") and " g" in s for s in labels)
    assert any("clairvoyant" in s and "floor" in s for s in labels)
    plt.close(fig)


def test_trajectory_zoom_shows_the_first_maneuver(suites):
    batch, runs = suites["bizup2002"]
    fig = plots.trajectory_figure("bizup2002", batch, runs)
    full, zoom = fig.axes[:2]
    n = int(batch.n_looks[0])
    k = np.nonzero(batch.maneuvering[0, :n])[0]
    first = k[: np.argmax(np.diff(np.append(k, k[-1] + 2)) > 1) + 1]   # looks of the first maneuver
    xy = batch.truth[0, first, :2] / 1e3
    (x0, x1), (y0, y1) = zoom.get_xlim(), zoom.get_ylim()
    assert np.all((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
    fx, fy = full.get_xlim(), full.get_ylim()
    assert (x1 - x0) < 0.25 * (fx[1] - fx[0]) and (y1 - y0) < 0.25 * (fy[1] - fy[0])
    plt.close(fig)


def _texts_inside_figure(fig):
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    fb = fig.bbox
    out = []
    for ax in fig.axes:
        texts = [ax.xaxis.label, ax.yaxis.label]
        for axis in (ax.xaxis, ax.yaxis):    # tick labels matplotlib draws: those inside the view interval
            lo, hi = sorted(axis.get_view_interval())
            texts += [t for t, v in zip(axis.get_ticklabels(), axis.get_ticklocs())
                      if lo - 1e-9 * abs(hi - lo) <= v <= hi + 1e-9 * abs(hi - lo) and t.get_visible()]
        for t in texts:
            if not t.get_text():
                continue
            b = t.get_window_extent(r)
            out.append((t.get_text(), b.x0 >= fb.x0 - 0.5 and b.x1 <= fb.x1 + 0.5 and b.y0 >= fb.y0 - 0.5
                        and b.y1 <= fb.y1 + 0.5))
    return out


def test_scope_frame_ticks_readable_and_labelled_in_km():
    import gymnasium as gym
    import radar_env  # noqa: F401
    env = gym.make("RadarTrack-v0", scenario="bizup2002", render_mode="rgb_array")
    env.reset(seed=1)
    for _ in range(5):
        env.step(4)
    env.render()
    fig = env.unwrapped._fig
    ax = fig.axes[0]
    assert ax.get_xlabel() == "east (km)" and ax.get_ylabel() == "north (km)"
    texts = _texts_inside_figure(fig)
    assert sum(1 for _, _ in texts) >= 6 and all(ok for _, ok in texts), [t for t, ok in texts if not ok]
    env.close()


def test_warning_chart_labels_not_cut(tmp_path, monkeypatch):
    from agents.reports.report import warning_figure
    names = ["imm2", "alpha_beta_adaptive", "kf_low"]
    enc = {t: {"warning_lead_time_s": 150.0 + 10 * i, "ideal_lead_time_s": 170.0, "false_warning_rate": 0.01 * i,
               "missed_warning_rate": 0.02} for i, t in enumerate(names)}
    figs = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figs.append(fig))   # keep the figure to inspect it
    warning_figure(tmp_path / "w.png", {"encounters": {"trackers": enc}}, names)
    assert (tmp_path / "w.png").stat().st_size > 0
    texts = _texts_inside_figure(figs[0])
    assert all(ok for _, ok in texts), [t for t, ok in texts if not ok]
    assert all(UNIT.search(ax.get_xlabel()) for ax in figs[0].axes)
    monkeypatch.undo()
    plt.close(figs[0])


def test_training_curve_draws_the_bundled_stages_end_to_end(tmp_path):
    from agents.training.train import _bundled_stages, plot_training_curve
    cfg = json.loads(BUNDLED_CONFIG.read_text())
    stages = _bundled_stages(cfg)
    chain, c = [], cfg
    while c:
        chain.append(c)
        c = c.get("fine_tuned_from")
    assert len(stages) == len(chain) >= 2
    assert [len(h) for _, h, _ in stages] == [len(c["selection_history"]) for c in reversed(chain)]
    assert "from scratch" in stages[0][0] and all("fine-tuned" in s[0] for s in stages[1:])
    fig = plots.training_curve_figure(stages)
    ax = fig.axes[0]
    first = ax.get_lines()[0].get_color()      # the first suite's colour, kept across stages
    random = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 1 and ln.get_color() == first]
    x = np.concatenate([ln.get_xdata() for ln in random])
    assert len(random) == len(stages) and np.all(np.diff(x) > 0)     # one curve per stage, end to end
    assert all(any(s[0].split("\n")[0] in t.get_text() for t in ax.texts) for s in stages)
    assert UNIT.search(ax.get_xlabel()) and UNIT.search(ax.get_ylabel())
    plt.close(fig)
    png = plot_training_curve(BUNDLED_CONFIG, tmp_path / "curve.png")
    assert png.stat().st_size > 0


def test_training_curve_of_a_run_folder_names_the_run_and_its_origin(tmp_path, monkeypatch):
    from agents.training.train import plot_training_curve
    run = tmp_path / "ppo_x"
    (run / "best").mkdir(parents=True)
    hist = [{"timesteps": s, "random_ratio_imm2": 1.0 - s * 1e-7} for s in (1000, 2000, 3000)]
    (run / "summary.json").write_text(json.dumps({"selection_history": hist}))
    (run / "config.json").write_text(json.dumps({"init_from": "runs/a/best/policy.zip"}))
    (run / "best" / "selection.json").write_text(json.dumps(hist[1]))
    figs = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figs.append(fig))
    png = plot_training_curve(run)
    monkeypatch.undo()
    assert png == run / "training_curve.png" and png.stat().st_size > 0
    title = figs[0].axes[0].get_title()
    assert "ppo_x" in title and "fine-tuned from runs/a/best/policy.zip" in title
    plt.close(figs[0])
