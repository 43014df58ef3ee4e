"""Comparison trackers: whole filters run on recorded measurement streams, batched over episodes.

Every tracker here starts exactly like the env (two-hit start, then the warm-up looks at 0.03 g, through
:class:`radar_env.filters.tracking.Tracker`), then runs its own logic on the same looks, and returns a :class:`TrackRun`:
per-look estimates and covariances in the same (B, K, ...) layout, so the evaluation compares them look by look on
identical plots (common random numbers).

Kinds:

* :func:`run_q_policy` -- the tracking chain with q chosen each look by a function of the observation: reference
  policies (:mod:`baselines.policies`) and learned stable-baselines3 policies run through it alike.
* :func:`run_imm` -- IMM with CV and coordinated-turn modes (:func:`radar_env.filters.kalman.imm_filter`).
* :func:`run_turn_rate_kf` -- Adrian's KF with ``F(omega)`` fed by algorithm 1 or 2.
* :func:`run_reinit` -- seed 002's re-initialising KF.
* :func:`run_clairvoyant` -- the known-input KF (the physical limit) and :func:`run_oracle_q` (q = |a_true|).

Each is the chain (a KF) plus a q-rule, or its own filter beside the chain behind the Tracker's cursor
(``next_look``, ``advance``, ``set_posterior``): no runner writes the Tracker's internals. ``cfg`` of every runner
is the common track start: a :class:`radar_env.filters.tracking.TrackStart`, an env config with a ``track_start`` (e.g.
:class:`radar_env.envs.config.EnvConfig`, whose ``features`` and ``q_levels_g`` also give a q-policy's observation),
or None for the defaults; the trackers' own parameters are their arguments.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from radar_env.envs.detectors import DetectorBank
from radar_env.filters.kalman import imm_filter, two_point_init
from radar_env.envs.observation import DEFAULT_FEATURES, DEFAULT_Q_LEVELS_G, FrameStack, ObservationLayout
from radar_env.filters.tracking import MAX_Q_M_S2, TrackStart, init_looks
from radar_env.common.units import DEG, G0_M_S2
from radar_env.common.validate import check_number, check_probabilities

from .tuned_params import param, tuned_parameters

__all__ = ["TrackRun", "run_q_policy", "run_imm", "run_turn_rate_kf", "run_reinit", "run_clairvoyant",
           "run_oracle_q", "IMMSpec", "IMM2_BIZUP", "IMM3_CT", "imm2_spec_from_params"]


@dataclass
class TrackRun:
    """Per-look output of one tracker on B episodes (K = longest episode; NaN / False where not produced).

    Attributes:
        name: tracker name.
        x: (B, K, 4) posterior estimates.
        P: (B, K, 4, 4) their covariances.
        start_index: (B,) first look after the track start (two hits + warm-up); metrics use looks >= it.
        q_m_s2: (B, K) process-noise level used for the look (NaN for trackers without one).
        declared: (B, K) bool maneuver declarations, or None for trackers that do not declare.
        extra: named (B, K) series for plots (c_min, turn rate, mode probability ...).
        error: why the tracker produced nothing (it raised; set by the evaluation), else None.
    """

    name: str
    x: np.ndarray
    P: np.ndarray
    start_index: np.ndarray
    q_m_s2: np.ndarray
    declared: np.ndarray | None = None
    extra: dict = field(default_factory=dict)
    error: str | None = None


def _start(cfg):
    """The common track start of ``cfg``: a :class:`radar_env.filters.tracking.TrackStart`, an env config (anything with a
    ``track_start``, e.g. :class:`radar_env.envs.config.EnvConfig`), or None (the defaults)."""
    if cfg is None:
        return TrackStart()
    return cfg if isinstance(cfg, TrackStart) else cfg.track_start


def _with_range_rate(cfg, radial_velocity):
    """``cfg``'s track start, with the range-rate update switched on if ``radial_velocity`` (else ``cfg``)."""
    return _start(cfg)._replace(radial_velocity=True) if radial_velocity else cfg


def range_rate_looks(tr, K):
    """The range-rate arguments of the filters (``radial_velocity_m_s``, ``site_xy_m``, ``radial_velocity_std_m_s``)
    from the first ``K`` looks of the started tracker ``tr``."""
    return {"radial_velocity_m_s": tr.look_data("radial_velocity_m_s")[:, :K],
            "site_xy_m": tr.look_data("site_xy_m")[:, :K],
            "radial_velocity_std_m_s": tr.look_data("radial_velocity_noise_std_m_s")[:, :K]}


_LAST_START = [None]
"""The last track start (:func:`_tracker`): ``(key, episodes, tracker, out)``."""


def _read_only(out):
    for v in list(out) + list(out.features.values()):
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    return out


def _tracker(episodes, cfg, known_input=False):
    """A :class:`radar_env.filters.tracking.Tracker` whose rows have started ``episodes`` (two-hit start and warm-up) and
    the last warm-up :class:`radar_env.filters.tracking.StepOutput` (read-only: runners share it).

    An evaluation runs every tracker on the same episodes, so the last start is kept (with the episode objects
    themselves, whose ids key it) and the next tracker on the same episodes and start gets a deep copy of the
    started Tracker: bit for bit what starting again gives, without the per-episode start-up."""
    start, episodes = _start(cfg), list(episodes)
    key = (tuple(map(id, episodes)), start, bool(known_input))
    last = _LAST_START[0]
    if last is None or last[0] != key:
        src = start.tracker(len(episodes))
        out = _read_only(src.load(np.arange(len(episodes)), episodes, known_input=known_input))
        _LAST_START[0] = last = (key, episodes, src, out)
    return copy.deepcopy(last[2]), last[3]


class _Recorder:
    def __init__(self, name, B, K, extra=()):
        self.run = TrackRun(name, np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan),
                            np.zeros(B, dtype=np.int64), np.full((B, K), np.nan))
        for e in extra:
            self.run.extra[e] = np.full((B, K), np.nan)

    def put(self, rows, k, x, P, q=None, **extra):
        run = self.run
        K = run.q_m_s2.shape[1]
        at = np.asarray(rows) * K + k          # flat (row, look) positions: one index array for every series
        run.x.reshape(-1, 4)[at] = x
        run.P.reshape(-1, 16)[at] = np.reshape(P, (-1, 16))
        if q is not None:
            run.q_m_s2.reshape(-1)[at] = q
        for name, v in extra.items():
            run.extra[name].reshape(-1)[at] = v


def _loop(tr, out, step_fn):
    """Step the rows still running (``step_fn(rows) -> StepOutput``) until every row has processed its last look."""
    active = ~out.done
    while active.any():
        rows = np.flatnonzero(active)
        active[rows] = ~step_fn(rows).done


# ------------------------------------------------------------------------------------------------ q policies
def observation_layout(cfg=None, features=None):
    """The observation a q-policy sees and the q levels (m/s^2): those of ``cfg`` (the env config a policy was
    trained with: anything with ``features`` and ``q_levels_g``), else the env's defaults; ``features``: only
    these entries (names), each scaled as in the full observation."""
    lv = np.asarray(getattr(cfg, "q_levels_g", DEFAULT_Q_LEVELS_G)) * G0_M_S2
    names = getattr(cfg, "features", DEFAULT_FEATURES) if features is None else features
    return ObservationLayout(names, lv[0], lv[-1]), lv


def run_q_policy(episodes, choose_q, name="policy", cfg=None, declare=None, features=None):
    """Run the tracking chain with ``q = choose_q(obs_rows)`` (m/s^2) each look.

    ``obs_rows`` (n, F) is the env's observation (``cfg.features``, scaled exactly as RadarTrack-v0 does, and
    ``cfg.frame_stack`` of them stacked newest first, (n, k F); the defaults without ``cfg``), so a learned policy
    sees here what it saw in training. ``features``: if ``choose_q`` reads only some entries of the newest frame
    (a rule), their names: ``obs_rows`` then holds just those, each with the value it has in the full observation
    (the scaling is per entry), and ``()`` gives an (n, 0) array (a constant q): the same q, without encoding
    the rest every look. ``declare(obs_rows) -> bool`` records maneuver declarations (optional). ``cfg`` also
    gives the track start (:func:`_start`).

    A recurrent policy is a stateful ``choose_q``: an object with ``reset(rows)`` is reset for every row (each row
    is one episode) before the first look and then called as ``choose_q(obs_rows, rows)``, so that it carries its
    state per row (e.g. :class:`agents.policies.recurrent.RecurrentQPolicy`). A ``choose_q`` whose ``turn_aware``
    attribute is true returns ``(q, omega)``: the look is predicted with ``F_ct(dt, omega)`` (rad/s, positive =
    clockwise; :meth:`radar_env.filters.tracking.Tracker.step`), recorded as ``extra["policy_turn_rate_deg_s"]``."""
    tr, out = _tracker(episodes, cfg)
    layout = None if features is not None and not len(features) else observation_layout(cfg, features)[0]
    B, K = tr.B, int(tr.n_looks.max())
    turn = bool(getattr(choose_q, "turn_aware", False))
    rec = _Recorder(name, B, K, extra=("c_min_g", "turn_rate_alg1_deg_s", "turn_rate_alg2_deg_s")
                    + (("policy_turn_rate_deg_s",) if turn else ()))
    declared = np.zeros((B, K), dtype=bool) if declare is not None else None
    q_prev = np.full(B, _start(cfg).warmup_q_m_s2)
    rows0 = np.arange(B)
    det = None
    if layout is not None and layout.uses_detectors:   # the env's detector features: the same IMMs, same looks
        det = DetectorBank(B)
        det.start(rows0, tr._st)
    obs = (layout.encode(out, q_prev, None if det is None else det.values) if layout is not None
           else np.zeros((B, 0), np.float32))
    k = int(getattr(cfg, "frame_stack", 1)) if features is None else 1
    frames = FrameStack(B, k, obs.shape[1]) if k > 1 else None   # as the env stacks them (frame_stack)
    if frames is not None:
        obs = frames.reset(rows0, obs)
    rec.put(rows0, out.look_index, out.x, out.P, out.q_m_s2, **_feature_extra(out))
    rec.run.start_index[:] = out.look_index + 1
    stateful = callable(getattr(choose_q, "reset", None))
    if stateful:
        choose_q.reset(rows0)

    def step(rows):
        o_rows = obs[rows]
        q = choose_q(o_rows, rows) if stateful else choose_q(o_rows)
        w = None
        if turn:
            q, w = q
            w = np.asarray(w, dtype=np.float64).reshape(rows.size)
            if not np.isfinite(w).all():
                raise ValueError(f"{name}: the policy's turn rate is not finite")
        q = np.clip(np.asarray(q, dtype=np.float64).reshape(rows.size), 0.0, 100 * G0_M_S2)
        if declared is not None:
            declared[rows, tr.k[rows]] = np.asarray(declare(o_rows), dtype=bool)
        if det is not None and det.step(tr._looks, tr._it, rows) != 0:   # before the chain: the look it takes
            raise RuntimeError("the detectors' IMMs refused a look the chain takes")   # a bug: same rows, looks
        o = tr.step(q, rows=None if rows.size == B else rows, turn_rate_rad_s=w)
        if layout is not None:
            enc = layout.encode(o, q, None if det is None else det.values[rows])
            obs[rows] = enc if frames is None else frames.push(rows, enc)
        rec.put(rows, o.look_index, o.x, o.P, q, **_feature_extra(o),
                **({} if w is None else {"policy_turn_rate_deg_s": np.degrees(w)}))
        return o

    _loop(tr, out, step)
    rec.run.declared = declared
    return rec.run


def _feature_extra(o):
    f = o.features
    return {"c_min_g": f["c_min_m_s2"] / G0_M_S2, "turn_rate_alg1_deg_s": np.degrees(f["turn_rate_alg1_rad_s"]),
            "turn_rate_alg2_deg_s": np.degrees(f["turn_rate_alg2_rad_s"])}


# ------------------------------------------------------------------------------------------------ IMM
@dataclass(frozen=True)
class IMMSpec:
    """IMM modes: process-noise levels (m/s^2), turn rates (rad/s, 0 = CV), transition matrix ``Pi[i, j] =
    P(j | i)`` per look, initial mode probabilities, and the index of the "maneuver" modes (for declarations)."""

    q_m_s2: tuple
    turn_rate_rad_s: tuple
    Pi: tuple
    mu0: tuple
    maneuver_modes: tuple

    def __post_init__(self):
        M = len(self.q_m_s2)
        if M < 1 or len(self.turn_rate_rad_s) != M or np.shape(self.Pi) != (M, M) or len(self.mu0) != M:
            raise ValueError(f"IMMSpec: q_m_s2, turn_rate_rad_s, Pi (M x M) and mu0 must agree on M >= 1 modes, got "
                             f"{M} q levels, {len(self.turn_rate_rad_s)} turn rates, Pi of shape "
                             f"{np.shape(self.Pi)} and {len(self.mu0)} initial probabilities")
        for j in range(M):
            check_number(f"IMMSpec.q_m_s2[{j}]", self.q_m_s2[j], 0.0, MAX_Q_M_S2)
            check_number(f"IMMSpec.turn_rate_rad_s[{j}]", self.turn_rate_rad_s[j], -np.pi, np.pi)
        check_probabilities("IMMSpec.Pi", self.Pi, (M, M))
        check_probabilities("IMMSpec.mu0", self.mu0, (M,))
        for j in self.maneuver_modes:
            check_number("IMMSpec.maneuver_modes entry", j, 0, M - 1, integer=True)


def imm2_spec_from_params(params):
    """The 2-mode CV IMM (:class:`IMMSpec`) from ``{"q_low_g", "q_high_g", "p_stay_low",
    "p_stay_high"}``: mode noises in g, per-look stay probabilities; starts at mode probabilities (0.9, 0.1)."""
    ql, qh = param(params, "q_low_g", "imm2"), param(params, "q_high_g", "imm2")
    sl, sh = param(params, "p_stay_low", "imm2"), param(params, "p_stay_high", "imm2")
    return IMMSpec(q_m_s2=(ql * G0_M_S2, qh * G0_M_S2), turn_rate_rad_s=(0.0, 0.0),
                   Pi=((sl, 1 - sl), (1 - sh, sh)), mu0=(0.9, 0.1), maneuver_modes=(1,))


IMM2_BIZUP = IMMSpec(q_m_s2=(0.03 * G0_M_S2, 2.0 * G0_M_S2), turn_rate_rad_s=(0.0, 0.0),
                     Pi=((0.9, 0.1), (0.9, 0.1)), mu0=(0.9, 0.1), maneuver_modes=(1,))
"""Bizup's 2-mode IMM: (0.03 g)^2 / (2 g)^2; "the a priori probability of a maneuver is always 0.1", read as a
memoryless transition matrix whose rows are both (0.9, 0.1)."""

IMM3_CT = IMMSpec(q_m_s2=(0.03 * G0_M_S2, 0.1 * G0_M_S2, 0.1 * G0_M_S2),
                  turn_rate_rad_s=(0.0, -3.0 * DEG, 3.0 * DEG),
                  Pi=((0.90, 0.05, 0.05), (0.10, 0.90, 0.0), (0.10, 0.0, 0.90)), mu0=(0.8, 0.1, 0.1),
                  maneuver_modes=(1, 2))
"""CV / CT-left / CT-right IMM at 3 deg/s (Adrian's description of common practice); the mode noises (0.03 g CV,
0.1 g CT as in Adrian's KF) and the transition matrix are our choices."""


def run_imm(episodes, spec: IMMSpec, name="imm", cfg=None, radial_velocity=False):
    """IMM on the recorded looks; starts from the common track start (all modes at the warm-up estimate), then
    runs as a separate filter on the chain's looks: every look of every row in one compiled call
    (:func:`radar_env.filters.kalman.imm_filter`, the look-by-look :func:`radar_env.filters.kalman.imm_step` bit for bit).
    ``radial_velocity``: every mode also updates on the plots' radial velocity (the track start too)."""
    cfg = _with_range_rate(cfg, radial_velocity)
    tr, out = _tracker(episodes, cfg)
    B, K, M = tr.B, int(tr.n_looks.max()), len(spec.q_m_s2)
    rows = np.arange(B)
    look = {f: tr.look_data(f)[:, :K] for f in ("t_s", "z_m", "R_m2", "detected")}
    log_mu0 = np.log(np.tile(np.asarray(spec.mu0, dtype=np.float64), (B, 1)))
    with np.errstate(divide="ignore"):
        log_Pi = np.log(np.asarray(spec.Pi, dtype=np.float64))
    rr = range_rate_looks(tr, K) if radial_velocity else {}
    x, P, log_mu = imm_filter(look["t_s"], look["z_m"], look["R_m2"], look["detected"], tr.n_looks, tr.k, tr.t_last,
                              log_mu0, np.repeat(tr.x[:, None], M, axis=1), np.repeat(tr.P[:, None], M, axis=1),
                              log_Pi, spec.q_m_s2, spec.turn_rate_rad_s, **rr)
    x[rows, out.look_index], P[rows, out.look_index] = out.x, out.P     # the start look, as every tracker records it
    p_man = np.exp(log_mu[..., list(spec.maneuver_modes)]).sum(axis=-1)     # NaN where not filtered
    return TrackRun(name, x, P, out.look_index + 1, np.full((B, K), np.nan), declared=p_man > 0.5,
                    extra={"maneuver_probability": p_man})


# ------------------------------------------------------------------------------------------------ Adrian
def run_turn_rate_kf(episodes, algorithm=2, q_m_s2=0.1 * G0_M_S2, name=None, cfg=None):
    """Adrian's turn-rate KF: predict with ``F(omega_{k-1})`` where omega is the latest estimate of algorithm 1
    (plot headings n apart) or 2 (filtered headings n apart), ``q`` = 0.1 g as in the paper; ``n`` is the track
    start's ``n_adrian``. Before an estimate is available the filter is CV."""
    if algorithm not in (1, 2):
        raise ValueError(f"algorithm must be 1 or 2, got {algorithm!r}")
    tr, out = _tracker(episodes, cfg)
    B, K = tr.B, int(tr.n_looks.max())
    rec = _Recorder(name or f"adrian{algorithm}", B, K, extra=("turn_rate_deg_s",))
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    rec.run.start_index[:] = out.look_index + 1
    key = f"turn_rate_alg{algorithm}_rad_s"
    omega = np.zeros(B)

    def step(rows):
        o = tr.step(np.full(rows.size, q_m_s2), rows=None if rows.size == B else rows,
                    turn_rate_rad_s=omega[rows])
        valid = o.features[f"turn_rate_alg{algorithm}_valid"]
        omega[rows] = np.where(valid, o.features[key], 0.0)
        rec.put(rows, o.look_index, o.x, o.P, o.q_m_s2, turn_rate_deg_s=np.degrees(omega[rows]))
        return o

    _loop(tr, out, step)
    return rec.run


# ------------------------------------------------------------------------------------------------ seed 002
def run_reinit(episodes, q_m_s2=0.03 * G0_M_S2, n_sigma=2.0, consecutive=4, name="reinit", cfg=None):
    """Seed 002's maneuver response: a KF at ``q``; when the Mahalanobis distance of the plot from the prediction
    exceeds ``n_sigma`` (``NIS > n_sigma^2``) on ``consecutive`` detected looks in a row, the maneuver is declared and
    the track re-initialised from the latest two plots (two-hit start; ``Tracker.set_posterior``)."""
    tr, out = _tracker(episodes, cfg)
    B, K = tr.B, int(tr.n_looks.max())
    rec = _Recorder(name, B, K)
    declared = np.zeros((B, K), dtype=bool)
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    rec.run.start_index[:] = out.look_index + 1
    run_len = np.zeros(B, dtype=np.int64)
    # the latest detected plot (z, R, t) per row, for the re-start: at first the last one before the warm-up ended
    det = tr.look_data("detected")
    before = det & (np.arange(det.shape[1]) < tr.k[:, None])
    i = det.shape[1] - 1 - np.argmax(before[:, ::-1], axis=1)
    rows0 = np.arange(B)
    last_plot, last_R, last_t = (tr.look_data(f)[rows0, i] for f in ("z_m", "R_m2", "t_s"))

    def step(rows):
        o = tr.step(np.full(rows.size, q_m_s2), rows=None if rows.size == B else rows)
        far = o.detected & (o.nis > n_sigma ** 2)
        run_len[rows] = np.where(o.detected, np.where(far, run_len[rows] + 1, 0), run_len[rows])
        fire = run_len[rows] >= consecutive
        x, P = o.x.copy(), o.P.copy()
        if fire.any():
            fr = rows[fire]
            ok = np.isfinite(last_t[fr]) & (o.t_s[fire] > last_t[fr])
            if ok.any():
                x0, P0 = two_point_init(last_plot[fr][ok], last_R[fr][ok], last_t[fr][ok], o.z_m[fire][ok],
                                        o.R_m2[fire][ok], o.t_s[fire][ok])
                idx = np.flatnonzero(fire)[ok]
                x[idx], P[idx] = x0, P0
                tr.set_posterior(fr[ok], x0, P0)
            run_len[fr] = 0
        declared[rows, o.look_index] = fire
        upd = o.detected
        last_plot[rows[upd]], last_R[rows[upd]], last_t[rows[upd]] = o.z_m[upd], o.R_m2[upd], o.t_s[upd]
        rec.put(rows, o.look_index, x, P, o.q_m_s2)
        return o

    _loop(tr, out, step)
    rec.run.declared = declared
    return rec.run


# ------------------------------------------------------------------------------------------------ bounds
def run_clairvoyant(episodes, name="clairvoyant", q_m_s2=0.0, cfg=None):
    """The physical limit for a q-chooser: a CV KF that is told the true maneuver as a known input
    ``u_k = x_true[k] - F(dt) x_true[k-1]`` (turn rate and speed change exactly), with ``q`` = 0, from the first
    warm-up look on (so a maneuver during the warm-up does not leave it a start-up error the others can correct).
    Its error is the measurement noise filtered by a CV filter that never lags."""
    tr, out = _tracker(episodes, cfg, known_input=True)
    B, K = tr.B, int(tr.n_looks.max())
    rec = _Recorder(name, B, K)
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    rec.run.start_index[:] = out.look_index + 1

    def step(rows):
        o = tr.step(np.full(rows.size, q_m_s2), rows=None if rows.size == B else rows, known_input=True)
        rec.put(rows, o.look_index, o.x, o.P, o.q_m_s2)
        return o

    _loop(tr, out, step)
    return rec.run


def run_oracle_q(episodes, name="oracle_q", floor_g=0.03, cfg=None):
    """A CV KF told the true acceleration magnitude every look: ``q = max(|a_true(t_k)|, floor)`` for the
    prediction to look k (it still does not know the direction, so it lags and is noisy like any q-chooser)."""
    tr, out = _tracker(episodes, cfg)
    B, K = tr.B, int(tr.n_looks.max())
    rec = _Recorder(name, B, K)
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    rec.run.start_index[:] = out.look_index + 1
    acc = tr.look_data("truth_accel_m_s2")

    def step(rows):
        a = acc[rows, tr.k[rows]]
        q = np.maximum(np.hypot(a[:, 0], a[:, 1]), floor_g * G0_M_S2)
        o = tr.step(q, rows=None if rows.size == B else rows)
        rec.put(rows, o.look_index, o.x, o.P, q)
        return o

    _loop(tr, out, step)
    return rec.run


# ------------------------------------------------------------------------------------------------ alpha-beta, Konle
def _common_start(episodes, cfg):
    """First look after the common track start (two hits + warm-up), per episode: where every other tracker's
    metrics start."""
    warmup = _start(cfg).warmup_scans
    return np.array([init_looks(e.detected, e.t_s)[1] + 1 + warmup for e in episodes], dtype=np.int64)


def run_alpha_beta_tracker(episodes, adaptive=False, q_m_s2=None, name=None, cfg=None, window=None,
                           q_max_m_s2=None):
    """Kim & Lee's alpha-beta trackers on the converted plots, one per axis (:func:`baselines.alpha_beta.
    run_alpha_beta`): the conventional one with fixed Kalata gains from ``q`` (default: the tuned constant-q KF's
    q) or the adaptive one (fudge factor from a ``window``-look innovation window, default the track start's
    ``window_kim_lee``, 12). Per-axis sigma from the plot's R. The adapted acceleration std is bounded by
    ``q_max_m_s2`` (default the largest q level of ``cfg`` or of the env's defaults: the largest q any q-chooser
    of the comparison may use). The alpha-beta starts from its own two-plot start; metrics use the same looks as
    every other tracker."""
    from radar_env.sim.episode import stack_episodes

    from .alpha_beta import run_alpha_beta

    batch = stack_episodes(episodes)
    q = tuned_parameters()["kf"]["q_g"] * G0_M_S2 if q_m_s2 is None else q_m_s2
    R = np.where(batch.detected[..., None, None], batch.R_m2, np.eye(2))
    if q_max_m_s2 is None:
        q_max_m_s2 = float(getattr(cfg, "q_levels_g", DEFAULT_Q_LEVELS_G)[-1]) * G0_M_S2
    res = run_alpha_beta(batch.t_s, batch.z_m, batch.detected, R_m2=R, q_m_s2=q, adaptive=adaptive,
                         window=_start(cfg).window_kim_lee if window is None else window,
                         q_max_m_s2=q_max_m_s2 if adaptive else None)
    nm = name or ("alpha_beta_adaptive" if adaptive else "alpha_beta")
    qq = res.q_m_s2.mean(axis=-1) if adaptive else np.full(batch.valid.shape, q)
    return TrackRun(nm, np.where(batch.valid[..., None], res.x, np.nan), res.P, _common_start(episodes, cfg),
                    np.where(batch.valid, qq, np.nan))


def run_konle_tracker(episodes, q_m_s2=None, weight=0.75, name="konle", cfg=None):
    """Konle's speed/heading EKF on differential plots of each sensor (:func:`baselines.konle.run_konle`), run
    beside the position KF (the tracking chain at ``q``, default the tuned constant q) and replacing ``weight``
    (75%) of the KF's speed and heading after every look (``Tracker.set_posterior``). The KF covariance is left as
    the KF computed it."""
    from radar_env.sim.episode import stack_episodes

    from .konle import blend_speed_heading, run_konle

    batch = stack_episodes(episodes)
    sr = np.where(batch.detected, batch.range_noise_std_m, 1.0)
    sb = np.where(batch.detected, batch.bearing_noise_std_rad, 1e-3)
    kon = run_konle(batch.t_s, batch.site_xy_m, np.nan_to_num(batch.range_m), np.nan_to_num(batch.bearing_rad),
                    batch.detected, range_std_m=sr, bearing_std_rad=sb, sensor_id=batch.site_index)
    q = tuned_parameters()["kf"]["q_g"] * G0_M_S2 if q_m_s2 is None else q_m_s2
    tr, out = _tracker(episodes, cfg)
    B, K = tr.B, int(tr.n_looks.max())
    rec = _Recorder(name, B, K)
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    rec.run.start_index[:] = out.look_index + 1

    def step(rows):
        o = tr.step(np.full(rows.size, q), rows=None if rows.size == B else rows)
        k = o.look_index
        x = blend_speed_heading(o.x, kon.speed_m_s[rows, k], kon.heading_rad[rows, k], weight)
        tr.set_posterior(rows, x)
        rec.put(rows, k, x, o.P, o.q_m_s2)
        return o

    _loop(tr, out, step)
    return rec.run
