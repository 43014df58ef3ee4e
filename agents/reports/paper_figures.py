"""Figures of the paper checks (``docs/figures/paper_*.png``), drawn from the arrays the checks computed. The
maneuver intervals they shade come from :func:`agents.evaluation.plots.maneuver_intervals_s`, as in the evaluation's
figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["bizup_figures", "kim_lee_figure"]

_STYLE = {"cmin": ("tab:blue", "-", 1.4, "KF using c_min"),
          "kf_low": ("0.45", "-", 3.0, "uniform-motion KF (0.03 g)"),
          "ckf": ("tab:red", ":", 1.6, "CKF at 5 NM (never switches: same as the uniform-motion KF)"),
          "imm2_bizup": ("tab:green", "-", 1.4, "2-mode IMM"),
          "ckf_tuned": ("tab:red", "--", 1.4, "CKF at {thr:.2f} km (variant, threshold chosen on other runs)")}


def _shade(ax, spans):
    """Shade the intervals where the truth maneuvers (only there)."""
    for j, (a, b) in enumerate(spans):
        ax.axvspan(a, b, color="0.88", zorder=0, label="truth maneuvering" if j == 0 else None)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _bottom_legend(fig, ax, ncol=3):
    h, lab = ax.get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=ncol, fontsize=8)


def bizup_figures(fig_dir, t, curves, spans, thr_m, runs):
    """Bizup fig. 7 (position error; full scale and zoomed) and fig. 8 (speed error: magnitude and vector)."""
    plt = _plt()
    fig_dir = Path(fig_dir)
    zoom = 1.15 * max(np.nanmax(curves[n]["pos_m"]["mean"] + curves[n]["pos_m"]["ci95"])
                      for n in curves if n not in ("kf_low", "ckf"))
    panels = [("paper_bizup_fig7_position.png",
               [("pos_m", "mean position error (m)", None), ("pos_m", "same, zoomed (m)", zoom)],
               f"Bizup fig. 7: position error, mean and 95 % CI of the mean over {runs} runs (bizup2002)"),
              ("paper_bizup_fig8_speed.png",
               [("speed_m_s", "speed-magnitude error\nabs(|v_est| - |v|) (m/s)", None),
                ("vel_m_s", "velocity-vector error\n|v_est - v| (m/s)", None)],
               f"Bizup fig. 8: speed error, mean and 95 % CI of the mean over {runs} runs (bizup2002)")]
    for fname, qs, title in panels:
        fig, axes = plt.subplots(len(qs), 1, figsize=(10, 3.3 * len(qs) + 0.8), sharex=True)
        for ax, (q, ylabel, top) in zip(axes, qs):
            _shade(ax, spans)
            for n, c in curves.items():
                col, ls, lw, lab = _STYLE[n]
                m, h = c[q]["mean"], c[q]["ci95"]
                ax.plot(t, m, color=col, ls=ls, lw=lw, label=lab.format(thr=thr_m / 1e3))
                ax.fill_between(t, m - h, m + h, color=col, alpha=0.15, lw=0)
            ax.set_ylabel(ylabel)
            ax.set_ylim(0, top)
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("time (s)")
        _bottom_legend(fig, axes[0], ncol=2)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout(rect=(0, 0.1, 1, 1))
        fig.savefig(fig_dir / fname, dpi=110)
        plt.close(fig)


def kim_lee_figure(path, t, curves, spans, title):
    """Kim & Lee figs. 3-5: RMSE of position and velocity and NPE against time, 1-D."""
    plt = _plt()
    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    specs = [("pos", "position RMSE (m)"), ("vel", "velocity RMSE (m/s)"), ("npe", "NPE (RMSE / RMS plot error)")]
    for ax, (q, ylabel) in zip(axes, specs):
        _shade(ax, spans)
        for lab, c in curves.items():
            if q in c:
                ax.plot(t, c[q], **{"lw": 1.3, **c.get("style", {})}, label=lab)
        if q == "npe":
            ax.axhline(1.0, color="k", lw=0.8, ls=":")
        ax.set_ylabel(ylabel)
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    axes[-1].set_xlabel("time (s)")
    _bottom_legend(fig, axes[0])
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit("error: agents.reports.paper_figures is a library module of the paper checks; run: python -m "
                     "agents.reports.paper_checks")
