"""Figures: time axes in seconds and monotone, units on every axis, legends off the data, maneuver shading only
where the runs share it and at the scenario's own segment times (the same in the paper figures), truth maneuvers
drawn as steps, no percentile band from fewer than 20 runs, off-scale trackers left out and said so, q plot on its
axis, trajectory zoom (east/north for a turn, speed for a speed change) on the exact path, scope frame showing
where the radar is, warning-chart labels not cut, training curve naming its stages inside the axes."""

import json
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from agents.evaluation import plots  # noqa: E402
from agents.evaluation.suites import draw_suite, run_scenario  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.sim.episode import stack_episodes  # noqa: E402

TRACKERS = ("kf_low", "cmin", "clairvoyant")
UNIT = re.compile(r"\(.+\)|\[.+\]")
BUNDLED_CONFIG = Path(__file__).resolve().parents[1] / "agents" / "bundled" / "policy" / "training.json"


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


def _legend_texts(fig):
    return [t.get_text() for lg in fig.legends for t in lg.get_texts()]


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
    """The median curves (left panels) of every tracker, in seconds and increasing; a tracker missing from a
    panel is one far below the others, and its legend entry says it is not drawn there."""
    batch, runs = suites[suite]
    fig = plots.error_figure(suite, batch, runs)
    longest_s = max(batch.t_s[b, batch.n_looks[b] - 1] - batch.t_s[b, 0] for b in range(batch.batch_size))
    legend = _legend_texts(fig)
    for ax in (fig.axes[0], fig.axes[2]):                     # position and velocity, in metres and m/s
        lines = _tracker_lines(ax)
        drawn = {ln.get_label() for ln in lines}
        assert "kf_low" in drawn                              # the reference (no imm2 here) is always drawn
        for missing in set(TRACKERS) - drawn:
            assert any(t.startswith(missing) and "not drawn" in t for t in legend), (missing, legend)
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
        if ln.get_label().startswith("_"):        # the reference's runs, one thin line each (NaN where absent)
            continue
        y = np.asarray(ln.get_ydata(), float)
        assert np.all(np.isfinite(y))
        if ln.get_label() in ok_lines and ln.get_label() != "kf_low":
            np.testing.assert_array_equal(y, ok_lines[ln.get_label()].get_ydata())
    # without run 1 the kf_low curve differs from the all-runs one
    changed = [ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("kf_low")][0]
    assert not np.array_equal(np.asarray(changed.get_ydata()), np.asarray(ok_lines["kf_low"].get_ydata()))
    plt.close(fig)
    plt.close(fig_ok)


def test_binned_error_stats_are_medians_of_per_run_means_over_the_runs_in_each_bin():
    # run 0 looks every 2 s up to 22 s, run 1 every 5 s up to 15 s, run 2 every 3 s up to 9 s
    t = np.full((3, 12), np.nan)
    t[0, :12] = 2.0 * np.arange(12)
    t[1, :4] = 5.0 * np.arange(4)
    t[2, :4] = 3.0 * np.arange(4)
    rng = np.random.default_rng(0)
    err = np.where(np.isfinite(t), rng.uniform(1, 100, t.shape), np.nan)
    width, min_runs = 10.0, 2
    centres, med, lo, hi = plots.binned_error_stats(t, err, width, min_runs)
    expect_c, expect_m, expect_lo = [], [], []
    for i in range(3):
        per_run = [np.mean(err[b][(t[b] >= i * width) & (t[b] < (i + 1) * width)]) for b in range(3)
                   if np.any((t[b] >= i * width) & (t[b] < (i + 1) * width))]
        if len(per_run) >= min_runs:
            expect_c.append((i + 0.5) * width)
            expect_m.append(np.median(per_run))
            expect_lo.append(np.percentile(per_run, plots.BAND_PERCENTILES[0]))
    assert centres.tolist() == expect_c and np.allclose(med, expect_m) and np.allclose(lo, expect_lo)
    assert np.all(lo <= med) and np.all(med <= hi)
    # the last bin (20-22 s) has run 0 only: hidden
    assert centres[-1] < 20.0


def test_maneuver_shading_only_where_runs_share_maneuver_times(suites):
    for suite, shaded in (("bizup2002", True), ("random_radars", False)):
        batch, runs = suites[suite]
        fig = plots.error_figure(suite, batch, runs)
        labels = _legend_texts(fig)
        assert any("maneuver" in s for s in labels) == shaded, suite
        if not shaded:
            assert any("not shaded" in ax.get_xlabel() for ax in fig.axes)
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
    labels = _legend_texts(fig)
    floor = [s for s in labels if s.startswith("0 g") and "drawn on this line" in s]
    assert floor, labels                                       # the floor says, in words, what lies on it
    value = ax.get_lines()[-1].get_ydata()[0]
    assert f"{value:g} g" in floor[0]
    clair = next(ln for ln in ax.get_lines() if ln.get_label() == "q of clairvoyant")
    q = runs["clairvoyant"].q_m_s2[0, :int(batch.n_looks[0])]
    y = np.asarray(clair.get_ydata(), float)[:q.size]
    assert np.all(y[q == 0] == value)                          # its q of 0 is drawn on the floor, visibly dashed
    assert clair.get_linestyle() == "--"
    plt.close(fig)


def test_q_plot_labels_a_corrections_q_as_its_bases(suites):
    """A window correction reports its base's q (it chooses none): the legend says whose q it is."""
    import dataclasses
    batch, runs = suites["bizup2002"]
    base = runs["clairvoyant"]
    extra = {**base.extra, "correction_m": np.zeros(base.q_m_s2.shape)}
    corrected = dataclasses.replace(base, name="corr", extra=extra)
    fig = plots.q_figure("bizup2002", batch, {"clairvoyant": base, "corr": corrected})
    labels = _legend_texts(fig)
    assert "q of corr (its base's)" in labels and "q of clairvoyant" in labels, labels
    plt.close(fig)


def test_truth_maneuvers_drawn_as_steps_at_the_scenarios_segment_times(suites):
    """bizup2002 turns over 290-330 s and 610-640 s (its segments): the shading of every figure set and the
    truth's |a| and turn-rate steps start and end there, not at the looks around them."""
    batch, runs = suites["bizup2002"]
    sc = run_scenario("bizup2002", 123)
    assert plots.maneuver_intervals_s(sc) == [(290.0, 330.0), (610.0, 640.0)]
    for make in (plots.error_figure, plots.q_figure, plots.features_figure):
        fig = make("bizup2002", batch, runs, scenario=sc)
        spans = sorted({(round(p.get_x(), 6), round(p.get_x() + p.get_width(), 6)) for p in fig.axes[0].patches
                        if type(p).__name__ == "Rectangle"})          # axvspan's rectangles
        assert (290.0, 330.0) in spans and (610.0, 640.0) in spans, (make.__name__, spans)
        plt.close(fig)
    fig = plots.features_figure("bizup2002", batch, runs, scenario=sc)
    steps = [p for ax in fig.axes for p in ax.patches if type(p).__name__ == "StepPatch"]
    assert len(steps) == 2                                      # |a| and turn rate
    for p in steps:
        edges = p.get_data().edges
        assert 290.0 in edges and 330.0 in edges and 610.0 in edges and 640.0 in edges
    acc = steps[0].get_data().values
    assert acc.max() == pytest.approx(2.0, rel=1e-6)            # the 2 g turns, in g
    plt.close(fig)
    # without the scenario (or with another flight's) the figures fall back on the looks
    assert plots.truth_model(run_scenario("bizup2002", 123), batch) is not None
    assert plots.truth_model(run_scenario("kim_lee_accel", 123), batch) is None


def test_paper_figure_shades_the_same_intervals(tmp_path, monkeypatch):
    """The Bizup paper figures take their maneuver intervals from the same helper as the evaluation figures."""
    from agents.reports import paper_figures
    seen = []
    monkeypatch.setattr(paper_figures, "_shade", lambda ax, spans: seen.append(list(spans)))
    t = np.arange(0.0, 940.0, 10.0)
    curve = {q: {"mean": np.ones_like(t), "ci95": np.zeros_like(t)} for q in ("pos_m", "speed_m_s", "vel_m_s")}
    spans = plots.maneuver_intervals_s(run_scenario("bizup2002"))
    paper_figures.bizup_figures(tmp_path, t, {"cmin": curve, "imm2_bizup": curve}, spans, 1000.0, 3)
    assert seen and all(s == [(290.0, 330.0), (610.0, 640.0)] for s in seen)


def test_no_percentile_band_from_fewer_than_20_runs(suites):
    batch, runs = suites["bizup2002"]                           # 3 runs
    assert batch.batch_size < plots.FEW_RUNS
    fig = plots.error_figure("bizup2002", batch, runs)
    assert not [c for ax in fig.axes for c in ax.collections if type(c).__name__ in ("PolyCollection",
                                                                                     "FillBetweenPolyCollection")]
    assert any("each of its 3 runs" in s for s in _legend_texts(fig))
    thin = [ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("_") and ln.get_linewidth() < 1]
    assert len(thin) >= 3                                       # the reference's runs, one line each
    plt.close(fig)


def test_error_panels_keep_the_scale_of_the_real_trackers(suites):
    """The log axes span the trackers that are drawn (no 1e-6 axis for the clairvoyant's velocity error)."""
    for suite in ("bizup2002", "random_radars"):
        batch, runs = suites[suite]
        fig = plots.error_figure(suite, batch, runs)
        for ax in (fig.axes[0], fig.axes[2]):
            lo, hi = ax.get_ylim()
            assert hi / lo < 1e5, (suite, ax.get_ylabel(), lo, hi)     # at most 5 decades
        assert "|v_est - v|" in fig.axes[2].get_ylabel() and "velocity" in fig.axes[2].get_ylabel()
        plt.close(fig)


def test_trajectory_zoom_shows_the_first_maneuver(suites):
    batch, runs = suites["bizup2002"]
    fig = plots.trajectory_figure("bizup2002", batch, runs, scenario=run_scenario("bizup2002", 123))
    full, zoom = fig.axes[:2]
    n = int(batch.n_looks[0])
    k = np.nonzero(batch.maneuvering[0, :n])[0]
    first = k[: np.argmax(np.diff(np.append(k, k[-1] + 2)) > 1) + 1]   # looks of the first maneuver
    xy = batch.truth[0, first, :2] / 1e3
    (x0, x1), (y0, y1) = zoom.get_xlim(), zoom.get_ylim()
    assert np.all((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
    fx, fy = full.get_xlim(), full.get_ylim()
    assert (x1 - x0) < 0.25 * (fx[1] - fx[0]) and (y1 - y0) < 0.25 * (fy[1] - fy[0])
    assert "290-330 s" in zoom.get_title() and "looks" not in zoom.get_title()
    # the overview: the exact path (the turn sampled every degree, more points than looks) and the plots on top
    truth = next(ln for ln in full.get_lines() if ln.get_label().startswith("truth"))
    plots_ = next(ln for ln in full.get_lines() if ln.get_label().startswith("plots"))
    assert len(truth.get_xdata()) > n and plots_.get_zorder() > truth.get_zorder()
    assert not [ln for ln in full.get_lines() if ln.get_label() in runs]    # tracks only in the zoom
    plt.close(fig)


def test_radial_speed_change_gets_a_speed_view():
    eps = draw_suite("kim_lee_accel", 2, seed=5)
    batch = stack_episodes(eps)
    runs = {t: run_tracker(t, eps) for t in ("kf_low", "clairvoyant")}
    fig = plots.trajectory_figure("kim_lee_accel", batch, runs, scenario=run_scenario("kim_lee_accel", 5))
    view = fig.axes[1]
    assert view.get_ylabel() == "speed (m/s)" and "(s)" in view.get_xlabel()
    assert "25-35 s" in view.get_title()
    assert any("range rate" in s for s in _legend_texts(fig))
    truth = view.get_lines()[0]
    assert np.nanmax(truth.get_ydata()) == pytest.approx(120 + 10 * 5 * 9.80665, rel=1e-6)   # 610 m/s after
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
    # the radar (at the origin, ~200 km away) is outside the view: an arrow at the edge and its range say where
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert not (x0 <= 0 <= x1 and y0 <= 0 <= y1)
    words = [t.get_text() for t in ax.texts]
    assert any(w.startswith("radar") and "km" in w for w in words), words
    assert any("bearing" in w for w in words)
    env.close()


def test_scope_frame_draws_a_radar_in_view():
    import gymnasium as gym
    import radar_env  # noqa: F401
    env = gym.make("RadarTrack-v0", scenario="adrian_flower", render_mode="rgb_array")  # radar at the centre
    env.reset(seed=1)
    for _ in range(40):
        env.step(4)
    env.render()
    ax = env.unwrapped._fig.axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    site = env.unwrapped._render_state()["sites"][0] / 1e3
    if x0 <= site[0] <= x1 and y0 <= site[1] <= y1:
        assert not any("bearing" in t.get_text() for t in ax.texts)
        assert any(ln.get_marker() == "^" for ln in ax.get_lines())
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
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    box = ax.get_window_extent(r)
    for i, s in enumerate(stages, 1):     # "stage i" inside the axes, its full name under the figure
        t = next(t for t in ax.texts if t.get_text() == f"stage {i}")
        b = t.get_window_extent(r)
        assert box.x0 <= b.x0 and b.x1 <= box.x1 and box.y0 <= b.y0 and b.y1 <= box.y1, s[0]
        assert any(s[0].split("\n")[0] in ft.get_text() for ft in fig.texts)
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


def test_maneuver_figure_shows_the_imms_and_the_learned_imms_parameters():
    """Only trackers with a maneuver probability; a panel of per-look parameter factors per learned IMM (the
    bundled policy_imm_bp moves them by more than 2x somewhere); the truth's turns shaded at the segment times."""
    from agents.evaluation.runner import run_policy
    from agents.policies.loading import load_policy
    from agents.policies.bundle import BUNDLED_LEARNED_IMM

    eps = draw_suite("bizup2002", 2, seed=123)
    batch = stack_episodes(eps)
    sc = run_scenario("bizup2002", 123)
    runs = {t: run_tracker(t, eps) for t in ("kf_low", "imm2", "imm_cv_ct")}
    fig = plots.maneuver_figure("bizup2002", batch, runs, scenario=sc)
    assert len(fig.axes) == 2
    labels = [ln.get_label() for ln in fig.axes[0].get_lines()]
    assert labels == ["imm2", "imm_cv_ct"]                      # kf_low has no maneuver probability
    spans = {(round(p.get_x(), 6), round(p.get_x() + p.get_width(), 6)) for p in fig.axes[0].patches
             if type(p).__name__ == "Rectangle"}
    assert (290.0, 330.0) in spans and (610.0, 640.0) in spans
    plt.close(fig)
    choose, cfg = load_policy(BUNDLED_LEARNED_IMM)
    runs["policy_imm_bp"] = run_policy("policy_imm_bp", eps, choose, cfg)
    fig = plots.maneuver_figure("bizup2002", batch, runs, scenario=sc)
    assert len(fig.axes) == 3
    params = {ln.get_label(): ln.get_ydata() for ln in fig.axes[2].get_lines() if not ln.get_label().startswith("_")}
    assert len(params) == 7 and all(np.nanmin(v) > 0 for v in params.values())
    assert any(np.nanmax(np.abs(np.log(v))) > np.log(2) for v in params.values())   # it does move them
    assert plots.maneuver_figure("bizup2002", batch, {"kf_low": runs["kf_low"]}) is None
    plt.close(fig)


def test_maneuver_figure_of_a_long_run_shows_a_window_from_its_first_maneuver(monkeypatch):
    eps = draw_suite("bizup2002", 1, seed=123)
    batch = stack_episodes(eps)
    runs = {t: run_tracker(t, eps) for t in ("imm2", "imm_cv_ct")}
    monkeypatch.setattr(plots, "MANEUVER_WINDOW_LOOKS", 20)
    fig = plots.maneuver_figure("bizup2002", batch, runs, scenario=run_scenario("bizup2002", 123))
    t = batch.t_s[0]
    first = int(np.flatnonzero(batch.maneuvering[0])[0])       # the 290 s turn, after the track start
    k0 = first - 2
    assert fig.axes[0].get_xlim() == (t[k0], t[k0 + 19])
    assert f"looks {k0}-{k0 + 19} of {int(batch.n_looks[0])}" in fig.axes[0].get_title()
    assert all(len(ln.get_xdata()) == 20 for ln in fig.axes[0].get_lines())
    plt.close(fig)


def test_the_not_drawn_note_stays_on_one_line_and_counts_what_it_leaves_out():
    names = ["policy_bp_rdot", "policy_imm_bp_rdot", "kf_tuned_rdot", "imm2_rdot", "imm_cv_ct_rdot", "clairvoyant"]
    assert plots._not_drawn(names[:1], 70) == "(not drawn: policy_bp_rdot)"
    text = plots._not_drawn(names, 70)
    assert text == "(not drawn: policy_bp_rdot, policy_imm_bp_rdot and 4 more)" and len(text) <= 70
    assert plots._not_drawn(names, 200) == f"(not drawn: {', '.join(names)})"
    assert plots._not_drawn(names, 10) == "(not drawn: 6 trackers)"


def test_the_main_jobs_trackers_each_have_their_own_colour():
    """Every tracker the main job draws has a colour no other one has (the legend names each line once)."""
    from agents.evaluation.options import DEFAULT_TRACKERS
    from agents.evaluation.plots import _colors
    colors = _colors(list(DEFAULT_TRACKERS))
    assert len(set(colors.values())) == len(DEFAULT_TRACKERS)
