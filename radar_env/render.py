"""Radar-scope picture of a RadarTrack-v0 episode (matplotlib, imported lazily by the env).

One frame shows the radar site(s) with range rings, the true path so far, the plots, the track with its
2-sigma position ellipse, and the current q and features as text. The view follows the track, so a site
outside it is marked at the frame's edge in its direction, with its range and bearing from the track.
``render_frame(env)`` returns an RGB array of shape ``FRAME_SHAPE`` for ``render_mode="rgb_array"`` (usable with
``gymnasium.wrappers.RecordVideo``), or draws into a window for ``"human"``.
"""

from __future__ import annotations

import numpy as np

from .common.units import G0_M_S2

__all__ = ["render_frame", "close_render", "FRAME_SHAPE", "human_display_problem"]

FRAME_SHAPE = (640, 640, 3)
_BG, _FG, _DIM = "#03140a", "#39ff88", "#1d6b3f"


def _import_matplotlib():
    try:
        import matplotlib
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ImportError("rendering RadarTrack-v0 needs matplotlib: pip install -e '.[plot]'") from e
    return matplotlib, Figure, FigureCanvasAgg


def human_display_problem():
    """Why ``render_mode="human"`` cannot show a window here (a phrase), or ``None`` if it can.

    The window is matplotlib's: with a non-interactive backend (Agg, which matplotlib falls back to when there is
    no display) ``plt.pause`` draws nothing, so the env refuses ``"human"`` at build time instead of rendering into
    the void."""
    import os
    import sys
    try:
        matplotlib, _, _ = _import_matplotlib()
        import matplotlib.pyplot as _pyplot  # noqa: F401 - resolves the default backend (Agg if headless)
    except ImportError as e:
        return str(e)
    backend = str(matplotlib.get_backend()).lower()
    try:
        from matplotlib.backends import BackendFilter, backend_registry
        non_interactive = backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE)
    except ImportError:  # pragma: no cover - matplotlib < 3.9
        from matplotlib.rcsetup import non_interactive_bk as non_interactive
    if backend not in {b.lower() for b in non_interactive}:
        return None
    headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return (f"matplotlib's backend is {backend!r}, which cannot open a window"
            + (" (no display: DISPLAY and WAYLAND_DISPLAY are unset)" if headless else ""))


def _ellipse(x, P, n_sigma=2.0, n=60):
    w, V = np.linalg.eigh(0.5 * (P[:2, :2] + P[:2, :2].T))
    a = np.linspace(0, 2 * np.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)])
    pts = V @ (np.sqrt(np.maximum(w, 0.0))[:, None] * circle) * n_sigma
    return x[0] + pts[0], x[1] + pts[1]


def _site_off_view(ax, centre, half, site):
    """Mark a radar site outside the view (a square of half-width ``half`` km around ``centre``) at the frame's
    edge in its direction; returns ``"radar 215 km at bearing 240 deg"`` (from the view's centre), or None if the
    site is in view (drawn there)."""
    d = np.asarray(site, float) - centre
    if np.all(np.abs(d) <= half):
        return None
    rng_km = float(np.hypot(*d))
    bearing = float(np.degrees(np.arctan2(d[0], d[1]))) % 360.0
    tip = centre + d * (0.97 * half / np.max(np.abs(d)))        # on the frame's edge, towards the site
    tail = centre + d * (0.80 * half / np.max(np.abs(d)))
    ax.annotate("", xy=tip, xytext=tail, arrowprops=dict(arrowstyle="-|>", color=_FG, lw=1.5))
    ax.text(*tail, f"radar\n{rng_km:.0f} km", color=_FG, fontsize=8, ha="center", va="center",
            bbox=dict(boxstyle="round,pad=0.2", fc=_BG, ec=_DIM))
    return f"radar {rng_km:.0f} km away at bearing {bearing:.0f} deg (arrow)"


def render_frame(env):
    """Draw the current state of ``env`` (a :class:`radar_env.envs.env.RadarTrackEnv`)."""
    _, Figure, FigureCanvasAgg = _import_matplotlib()
    st = env._render_state()
    if getattr(env, "_fig", None) is None:
        h, w, _ = FRAME_SHAPE
        env._fig = Figure(figsize=(w / 100, h / 100), dpi=100, facecolor=_BG)
        env._canvas = FigureCanvasAgg(env._fig)
    fig = env._fig
    fig.clear()
    ax = fig.add_axes([0.11, 0.08, 0.86, 0.86], facecolor=_BG)   # room at left and bottom for labelled ticks
    km = 1e-3
    truth, plots, est = st["truth"] * km, st["plots"] * km, st["estimates"] * km
    centre = est[-1, :2] if len(est) else truth[-1, :2]
    recent = truth[-12:, :2] if len(truth) else centre[None]
    half = float(np.clip(1.3 * np.max(np.abs(recent - centre)), 3.0, 60.0))   # the last ~12 looks fill the view
    ring_km = 10.0 if half > 10 else 2.0
    for s in st["sites"] * km:
        r_far = np.hypot(*(centre - s)) + half
        for r in np.arange(ring_km, r_far + ring_km, ring_km):
            a = np.linspace(0, 2 * np.pi, 361)
            ax.plot(s[0] + r * np.sin(a), s[1] + r * np.cos(a), color=_DIM, lw=0.6)
        ax.plot(*s, "^", color=_FG, ms=9)
    ax.plot(truth[:, 0], truth[:, 1], "-", color="white", lw=1.0, alpha=0.7, label="truth")
    ax.plot(plots[:, 0], plots[:, 1], ".", color="#ffd24d", ms=4, label="plots")
    if len(est):
        ax.plot(est[:, 0], est[:, 1], "-", color=_FG, lw=1.5, label="track")
        ex, ey = _ellipse(st["estimates"][-1], st["P"])
        ax.plot(ex * km, ey * km, "-", color="#ff5577", lw=1.2, label="2-sigma")
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    where = [_site_off_view(ax, centre, half, s) for s in st["sites"] * km]
    ax.tick_params(colors=_FG, labelcolor=_FG, labelsize=9)
    ax.set_xlabel("east (km)", color=_FG, fontsize=9)
    ax.set_ylabel("north (km)", color=_FG, fontsize=9)
    for sp in ax.spines.values():
        sp.set_color(_DIM)
    txt = (f"t = {st['time_s']:.0f} s   q = {st['q_m_s2'] / G0_M_S2:.3g} g   range rings {ring_km:g} km\n"
           + "".join(f"{w}\n" for w in where if w)
           + "\n".join(f"{k} = {v:.3g}" for k, v in st["features"].items()))
    ax.text(0.02, 0.98, txt, transform=ax.transAxes, va="top", ha="left", color=_FG, family="monospace",
            fontsize=8)
    ax.legend(loc="lower right", fontsize=7, facecolor=_BG, edgecolor=_DIM, labelcolor=_FG)
    env._canvas.draw()
    frame = np.asarray(env._canvas.buffer_rgba())[..., :3].copy()
    if env.render_mode == "human":
        import matplotlib.pyplot as plt
        if getattr(env, "_human_fig", None) is None:
            env._human_fig, env._human_ax = plt.subplots(figsize=(6.4, 6.4))
            env._human_was_interactive = plt.isinteractive()
            plt.ion()
        env._human_ax.clear()
        env._human_ax.imshow(frame)
        env._human_ax.axis("off")
        plt.pause(1.0 / env.metadata["render_fps"])
        return None
    return frame


def close_render(env):
    """Release what :func:`render_frame` made for ``env``: the ``human`` window (closed, and pyplot's interactive
    mode put back as it was before the window opened) and the off-screen figure. A later ``render()`` makes them
    again."""
    fig = getattr(env, "_human_fig", None)
    if fig is not None:
        import matplotlib.pyplot as plt
        plt.close(fig)
        if not getattr(env, "_human_was_interactive", True):
            plt.ioff()
    env._human_fig = env._human_ax = env._fig = env._canvas = None
