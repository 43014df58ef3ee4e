"""The tracking chain, written once: look -> dt -> F, Q(q) -> predict -> update -> features.

:class:`Tracker` runs B tracks side by side (batch axis first), one per episode row. Every consumer uses it: the
single env is a Tracker of batch 1, the native vector env a Tracker of batch N, the q-choosing classical trackers
and learned policies are stepped through it by the evaluation, and the IMM and the clairvoyant bound start from
its track initiation.

One step of row ``b`` processes the next look ``k`` of its episode::

    dt        = t[k] - t_last                           (s; irregular with several sites, 0 allowed)
    F         = F_cv(dt)             or F_ct(dt, omega) when a turn rate is supplied (Adrian's turn-rate KF)
    Q         = q^2 Gamma Gamma^T    (q from the caller: the agent's action, a rule, or the warm-up level)
    x-, P-    = predict(x, P, F, Q [, u])               (u: known input, only for the clairvoyant bound)
    x+, P+    = update(x-, P-, z[k], R[k], detected[k]) (a missed look predicts through)
    x+, P+    = update_rdot(x+, P+, rdot[k], site[k])   (only with radial_velocity=True: the EKF range-rate update)
    features  = FeatureBank.update(...)                 (normalised innovations, c_min, turn rates, ...)
    preview   = preview_next_plot(x+, P+, look k+1)      (the next plot against the q-free prediction)

The preview lets the q for look k+1 be chosen *after* plot k+1 is seen, as an IMM weighs its modes with the plot
itself: for a CV model the predicted mean ``F x`` does not depend on q (only ``P-`` does), so the innovation of the
next plot is known before q is chosen, and the estimate at k+1 still uses plots up to k+1 only (causal).

Track start (Bizup section 3.3, used for every tracker so that comparisons are apart from start-up): two-hit
initialisation from the first two detected looks (position from the second, velocity by differencing), then
``warmup_scans`` looks filtered at ``warmup_q_m_s2`` (Bizup: 12 at 0.03 g). :meth:`Tracker.load` does both and
returns the output of the last warm-up look, from which the first choice of q is made.

Implementation: the whole step (predict, update, features, preview) of all stepped rows is one compiled kernel
call (:func:`radar_env.filters.kernels.k_tracker_step`), and the track start another (:func:`radar_env.filters.kernels.k_track_start`,
then the warm-up as ``k_tracker_step`` with ``n_rep = warmup_scans``). The state lives in preallocated arrays that
the kernels update in place: ``x (B,4)``, ``P (B,4,4)`` and ``t_last`` are views of one packed float array, ``k`` and
``n_looks (B,)`` of one int array (:data:`radar_env.filters.kernels.S_X` ...), beside the feature bank's packed ring buffers
and the episodes' looks packed as ``(B, K_cap, W_LOOK)`` float64 rows (:data:`radar_env.filters.kernels.LOOK_COLUMNS`). The
env runs the same row step (:func:`radar_env.filters.kernels._step_row`) from its own kernel
(:mod:`radar_env.envs.env_kernels`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import kernels as _k
from .features import FeatureBank
from ..sim.looks import init_looks, looks_for_track_start  # noqa: F401  (the two-hit start's looks)
from ..common.units import G0_M_S2

__all__ = ["Tracker", "StepOutput", "init_looks", "looks_for_track_start", "preview_next_plot", "MAX_Q_M_S2"]

MAX_Q_M_S2 = 100.0 * G0_M_S2
"""Largest process-noise level the chain accepts (m/s^2)."""

class StepOutput(NamedTuple):
    """What one step produced for the stepped rows (leading axis = those rows)."""

    look_index: np.ndarray      # (n,) index k of the look just processed
    t_s: np.ndarray             # (n,)
    dt_s: np.ndarray            # (n,) time since the previous look
    q_m_s2: np.ndarray          # (n,) process-noise level used for this prediction
    x_prior: np.ndarray         # (n,4)
    P_prior: np.ndarray         # (n,4,4)
    x: np.ndarray               # (n,4) posterior
    P: np.ndarray               # (n,4,4)
    nu: np.ndarray              # (n,2) innovation (0 where missed)
    S: np.ndarray               # (n,2,2)
    nis: np.ndarray             # (n,) (0 where missed)
    detected: np.ndarray        # (n,) bool
    z_m: np.ndarray             # (n,2) converted plot (NaN where missed)
    R_m2: np.ndarray            # (n,2,2)
    site_xy_m: np.ndarray       # (n,2)
    range_m: np.ndarray         # (n,) measured polar values of the plot (NaN where missed)
    bearing_rad: np.ndarray     # (n,)
    radial_velocity_m_s: np.ndarray  # (n,)
    range_noise_std_m: np.ndarray      # (n,) sigmas of the site that looked
    bearing_noise_std_rad: np.ndarray  # (n,)
    truth: np.ndarray           # (n,4) -- for rewards and metrics only, never for the policy
    truth_accel_m_s2: np.ndarray  # (n,2)
    maneuvering: np.ndarray     # (n,) bool
    features: dict              # name -> (n,) arrays (see FeatureBank.update and preview_next_plot)
    done: np.ndarray            # (n,) bool, the episode's last look was processed
    feature_block: np.ndarray | None = None  # (n, W_FEAT) float features in kernel column order (FEATURE_FLOAT_KEYS)


FEATURE_FLOAT_KEYS = _k.BANK_FLOAT_KEYS + _k.PREVIEW_KEYS
"""Column names of ``StepOutput.feature_block`` (the float features; the flags are only in ``features``)."""


def preview_next_plot(x_post, P_post, t_s, next_look):
    """Features of the next look's plot against the process-noise-free prediction (batched, no state).

    With ``dt = t_next - t_s``, ``x^ = F(dt) x_post`` (independent of q) and ``S0 = H F P_post F^T H^T + R_next``
    (q = 0), the innovation is ``nu = z_next - H x^``. Returns a dict of (n,) arrays:

    * ``next_nu_along``, ``next_nu_cross``: ``nu`` along/across the predicted track normalised by ``S0`` (sigma);
    * ``next_nis``: ``nu^T S0^-1 nu``;
    * ``next_q_fit_m_s2``: the q that explains this one innovation, ``sqrt(max(phi, 0))`` with Kim & Lee's
      ``phi = trace(nu nu^T - S0) / trace(H Q1 H^T)`` (their eq 15 with a window of one plot);
    * ``next_c_min_m_s2``: Bizup's c_min from the next plot's bearing and radial velocity;
    * ``next_los_accel_m_s2``: the radial-velocity innovation over dt, ``(rdot_next - rdot(x^)) / dt`` with
      ``rdot(x^) = (p^ - site) . v^ / |p^ - site|``: the line-of-sight acceleration the plot implies (Bizup's
      point that radial velocity sees a maneuver before position does, without his turn model; it sees speed
      changes too). ``dt`` floored at 1 ms;
    * ``next_rdot_nu``: the same radial-velocity innovation in sigmas, ``(rdot_next - rdot(x^)) / sqrt(s_r)`` with
      ``s_r = h F P_post F^T h^T + sigma_rdot^2`` and ``h = d rdot / d x = [(v^ - rdot(x^) u) / r, u]`` (``u`` the
      unit line of sight): scale-free across radars, where ``next_los_accel`` is dominated by noise at short dt;
    * ``next_meas_std_m``: per-axis RMS noise of the next plot, ``sqrt(trace(R_next) / 2)`` (the scale that
      turns a q in g into a maneuver index; differs between radars and sites);
    * ``next_dt_s``, ``next_detected`` (0 where there is no next look).

    Every plot feature is 0 where the next look is missed or does not exist (``next_look["detected"]`` False).
    """
    det = _k.c_array(np.asarray(next_look["detected"], dtype=bool).reshape(-1))
    n = det.size

    def arr(name, tail):
        return _k.c_array(np.broadcast_to(np.asarray(next_look[name], dtype=np.float64), (n,) + tail))

    x_post = _k.c_array(x_post, np.float64)
    of = np.empty((n, _k.W_PREVIEW))
    _k.k_preview(x_post, _k.c_array(P_post, np.float64),
                 _k.c_array(np.broadcast_to(np.asarray(t_s, dtype=np.float64), (n,))), det,
                 arr("t_s", ()), arr("z_m", (2,)), arr("R_m2", (2, 2)), arr("bearing_rad", ()),
                 arr("radial_velocity_m_s", ()), arr("radial_velocity_noise_std_m_s", ()), arr("site_xy_m", (2,)),
                 _k.MIN_DT_S, of)
    return dict(zip(_k.PREVIEW_KEYS, of.T))


_EMPTY_ROWS = np.zeros(0, dtype=np.int64)
_NO_TURN = np.zeros(0)
_O, _OF = _k.W_OUT, _k.W_OUT + _k.W_BANK_OUT


def _outputs(o, ob, oi):
    """StepOutput of the kernels' output blocks (column views, no copies)."""
    n = o.shape[0]
    feats = dict(zip(FEATURE_FLOAT_KEYS, o[:, _O:].T))
    feats.update(zip(_k.BANK_FLAG_KEYS, ob[:, _k.W_OUTB:].T))
    return StepOutput(
        look_index=oi, t_s=o[:, _k.O_T], dt_s=o[:, _k.O_DT], q_m_s2=o[:, _k.O_Q],
        x_prior=o[:, _k.O_XPR:_k.O_XPR + 4], P_prior=o[:, _k.O_PPR:_k.O_PPR + 16].reshape(n, 4, 4),
        x=o[:, _k.O_X:_k.O_X + 4], P=o[:, _k.O_P:_k.O_P + 16].reshape(n, 4, 4), nu=o[:, _k.O_NU:_k.O_NU + 2],
        S=o[:, _k.O_S:_k.O_S + 4].reshape(n, 2, 2), nis=o[:, _k.O_NIS], detected=ob[:, _k.OB_DET],
        z_m=o[:, _k.O_Z:_k.O_Z + 2], R_m2=o[:, _k.O_R:_k.O_R + 4].reshape(n, 2, 2),
        site_xy_m=o[:, _k.O_SITE:_k.O_SITE + 2], range_m=o[:, _k.O_RANGE], bearing_rad=o[:, _k.O_BEAR],
        radial_velocity_m_s=o[:, _k.O_RDOT], range_noise_std_m=o[:, _k.O_RSTD],
        bearing_noise_std_rad=o[:, _k.O_BSTD], truth=o[:, _k.O_TRUTH:_k.O_TRUTH + 4],
        truth_accel_m_s2=o[:, _k.O_TACC:_k.O_TACC + 2], maneuvering=ob[:, _k.OB_MAN], features=feats,
        done=ob[:, _k.OB_DONE], feature_block=o[:, _O:])


def _episode_rows(e):
    """One episode's looks as a (K, W_LOOK) float64 block (the packed look layout)."""
    K = e.n_looks
    blk = np.empty((K, _k.W_LOOK))
    for f, (c, tail) in _k.LOOK_COLUMNS.items():
        w = int(np.prod(tail)) if tail else 1
        blk[:, c:c + w] = np.asarray(getattr(e, f), dtype=np.float64).reshape(K, w)
    return blk


def _packed(array, col, width, shape, doc):
    """A property viewing ``width`` columns from ``col`` of the packed state array named ``array``, shaped
    ``(B,) + shape``; assigning to it writes into the state."""
    def get(self):
        a = getattr(self, array)
        return a[:, col] if width == 1 else a[:, col:col + width].reshape((self.B,) + shape)

    def put(self, v):
        a = getattr(self, array)
        if width == 1:
            a[:, col] = v
        else:
            a[:, col:col + width] = np.broadcast_to(v, (self.B,) + shape).reshape(self.B, width)
    return property(get, put, doc=doc)


class Tracker:
    """B Kalman tracks over B episodes, stepped together (see module docstring).

    Args:
        batch_size: number of rows B.
        warmup_scans: looks filtered at ``warmup_q_m_s2`` after the two-hit start (Bizup: 12), >= 1 (the first
            observation needs the features of one filtered look).
        warmup_q_m_s2: process-noise level during warm-up (Bizup: 0.03 g).
        n_adrian, window_kim_lee, fma_weight: passed to :class:`radar_env.filters.features.FeatureBank`.
        radial_velocity: after the position update, an EKF update with the plot's radial velocity (its noise the
            radar's; :func:`radar_env.filters.kernels._rdot_update`), warm-up included. Default False: position
            plots only, as every result before the range-rate trackers.
    """

    def __init__(self, batch_size, warmup_scans=12, warmup_q_m_s2=0.03 * G0_M_S2, n_adrian=4, window_kim_lee=12,
                 fma_weight=0.1, radial_velocity=False):
        self.B = int(batch_size)
        if self.B < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size!r}")
        self.warmup_scans = int(warmup_scans)
        if not 1 <= self.warmup_scans <= 1000:
            raise ValueError(f"warmup_scans must be in [1, 1000], got {warmup_scans!r}")
        self.warmup_q_m_s2 = float(warmup_q_m_s2)
        if not 0.0 <= self.warmup_q_m_s2 <= MAX_Q_M_S2:
            raise ValueError(f"warmup_q_m_s2 must be in [0, {MAX_Q_M_S2}], got {warmup_q_m_s2!r}")
        self.bank = FeatureBank(self.B, n_adrian=n_adrian, window_kim_lee=window_kim_lee, fma_weight=fma_weight)
        self.radial_velocity = bool(radial_velocity)
        self.bank._par[_k.PAR_RDOT] = 1.0 if self.radial_velocity else 0.0   # the chain's option (kernels.PAR_RDOT)
        self._cap = 0
        self._looks = np.zeros((self.B, 0, _k.W_LOOK))   # packed look rows (B, K_cap, W_LOOK)
        # packed state (kernels.S_* / I_*): x, P, t_last and k, n_looks are views into these two arrays
        self._st = np.zeros((self.B, _k.W_ST))
        self._st[:, _k.S_P:_k.S_P + 16] = np.eye(4).reshape(16)
        self._it = np.zeros((self.B, _k.W_IT), dtype=np.int64)
        self.names = [""] * self.B

    # views of the packed state (properties, so that a copy or a pickle of the tracker keeps them joined)
    x = _packed("_st", _k.S_X, 4, (4,), "(B, 4) posterior means (a view: writes go to the state).")
    P = _packed("_st", _k.S_P, 16, (4, 4), "(B, 4, 4) posterior covariances (a view).")
    t_last = _packed("_st", _k.S_T, 1, (), "(B,) time of the last processed look (a view).")
    k = _packed("_it", _k.I_K, 1, (), "(B,) index of the next look to process (a view).")
    n_looks = _packed("_it", _k.I_N, 1, (), "(B,) looks in each row's episode (a view).")

    # ------------------------------------------------------------------------------------------ episode data
    def _ensure_capacity(self, K, headroom=1.0):
        """Room for ``K`` looks per row; when it grows, to ``ceil(headroom * K)`` looks. Refused (one line) before
        any allocation when the looks alone would not fit the machine."""
        if K <= self._cap:
            return
        from ..sim.radar import MAX_LOOKS
        need = self.B * K * _k.W_LOOK * 8           # before any allocation: rows x looks x the look record
        mem = _physical_memory()
        if K > MAX_LOOKS or (mem is not None and need > mem / 2):
            raise ValueError(f"RadarSite.scan_period_s: episodes of {K:,} looks in {self.B} rows need "
                             f"{need / 2**30:.3g} GiB for their looks alone, more than this machine can hold (at most "
                             f"{MAX_LOOKS:,} looks per episode, half of its memory); give a longer scan_period_s, a "
                             "shorter flight or fewer rows")
        self._grow(max(K, math.ceil(headroom * K)))

    def load(self, rows, episodes, known_input=False):
        """Put ``episodes`` into ``rows``, start their tracks (two-hit + warm-up) and return the last warm-up
        :class:`StepOutput` for those rows (in the order of ``rows``). ``known_input`` is passed to the warm-up
        steps (only the clairvoyant bound uses it)."""
        rows = _k.c_array(np.asarray(rows, dtype=np.int64).reshape(-1))
        i1s, i2s = self._put(rows, episodes)
        return self._start(rows, i1s, i2s, known_input)

    def _put(self, rows, episodes):
        """Check ``episodes`` for the track start and pack them into the looks of ``rows`` (int64 array); returns
        the looks of their two hits ``(i1s, i2s)``."""
        episodes = list(episodes)
        if rows.size != len(episodes):
            raise ValueError(f"got {rows.size} rows and {len(episodes)} episodes")
        i1s, i2s = np.empty(rows.size, np.int64), np.empty(rows.size, np.int64)
        for j, e in enumerate(episodes):   # checked before anything is written
            i1, i2 = i1s[j], i2s[j] = init_looks(e.detected, e.t_s)
            need = i2 + 1 + self.warmup_scans
            if e.n_looks < need:
                raise ValueError(f"episode {e.name!r} has {e.n_looks} looks; the track start needs {need} "
                                 f"(two hits at looks {i1} and {i2}, then {self.warmup_scans} warm-up looks)")
        self._ensure_capacity(max(e.n_looks for e in episodes))
        L = self._looks
        for r, e in zip(rows, episodes):
            K = e.n_looks
            blk = _episode_rows(e)
            L[r, :K] = blk
            L[r, K:] = blk[-1]          # pad: repeat the last look, not detected
            L[r, K:, _k.L_DET] = 0.0
            self.n_looks[r], self.names[r] = K, e.name
        return i1s, i2s

    def _start(self, rows, i1s, i2s, known_input=False):
        """Two-hit start of ``rows`` (episodes already in the look arrays) and the warm-up; the last warm-up
        StepOutput."""
        b = self.bank
        _k.k_track_start(rows, i1s, i2s, self._st, self._it, self._looks, b._f, b._i, b._b, b._par)
        return self._step(np.full(rows.size, self.warmup_q_m_s2), rows, False, None, known_input, self.warmup_scans)

    @staticmethod
    def _out_blocks(n):
        return (np.empty((n, _k.W_OUT + _k.W_FEAT)), np.empty((n, _k.W_OUTB + _k.W_BANK_OUTB), dtype=bool),
                np.empty(n, dtype=np.int64))

    # ------------------------------------------------------------------------------------------ the chain
    def step(self, q_m_s2, rows=None, turn_rate_rad_s=None, known_input=False) -> StepOutput:
        """Process the next look of ``rows`` (all rows if None) with process-noise level ``q_m_s2`` (m/s^2).

        Args:
            q_m_s2: (n,) or scalar, in [0, MAX_Q_M_S2]; a ``ValueError`` names the bad value otherwise.
            rows: index array of the rows to step (default all).
            turn_rate_rad_s: (n,) or None, finite (a ``ValueError`` otherwise). If given, predict with the
                coordinated-turn ``F_ct(dt, omega)``.
            known_input: if True, add the true motion not explained by ``F`` (``u = x_true[k] - F x_true[k-1]``):
                the clairvoyant bound's known-input KF. Never used by a policy.
        """
        return self._step(q_m_s2, rows, rows is None, turn_rate_rad_s, known_input, 1)

    def _step(self, q_m_s2, rows, all_rows, turn_rate_rad_s, known_input, n_rep):
        if all_rows:
            n, sel = self.B, _EMPTY_ROWS
        else:
            sel = _k.c_array(np.asarray(rows, dtype=np.int64).reshape(-1))
            n = sel.size
        q = np.asarray(q_m_s2, dtype=np.float64)
        q = _k.c_array(q if q.shape == (n,) else np.broadcast_to(q, (n,)))
        if turn_rate_rad_s is None:
            w = _NO_TURN
        else:
            w = _k.c_array(np.broadcast_to(np.asarray(turn_rate_rad_s, dtype=np.float64), (n,)))
            if not np.isfinite(w).all():      # a NaN turn rate would corrupt the row's state for good
                raise ValueError(f"turn_rate_rad_s must be finite, got {w[~np.isfinite(w)][0]!r}")
        o, ob, oi = self._out_blocks(n)
        b = self.bank
        status, i = _k.k_tracker_step(sel, all_rows, q, w, turn_rate_rad_s is not None, bool(known_input), MAX_Q_M_S2,
                                      n_rep, self._st, self._it, self._looks, b._f, b._i, b._b, b._par, o, ob, oi)
        if status == 1:
            raise ValueError(f"q_m_s2 must be finite and in [0, {MAX_Q_M_S2:.1f}] m/s^2, got {q[i]!r}")
        if status == 2:
            raise ValueError("step() called on a row whose episode has ended; load a new episode first")
        return _outputs(o, ob, oi)

    # ------------------------------------------------------------------------------------------ helpers
    def copy_rows_from(self, src: "Tracker", src_rows, dst_rows):
        """Copy whole track rows (episode data, filter state, feature-bank state) from another Tracker with the
        same configuration. Lets a caller start tracks in one large batch and hand them out row by row."""
        src_rows = np.asarray(src_rows, dtype=np.int64)
        dst_rows = np.asarray(dst_rows, dtype=np.int64)
        self._ensure_capacity(src._cap)
        c = src._cap
        self._looks[dst_rows, :c] = src._looks[src_rows]
        if self._cap > c:
            self._looks[dst_rows, c:] = src._looks[src_rows, -1:]
            self._looks[dst_rows, c:, _k.L_DET] = 0.0
        self._st[dst_rows] = src._st[src_rows]
        self._it[dst_rows] = src._it[src_rows]
        for d, s_ in zip(dst_rows, src_rows):
            self.names[d] = src.names[s_]
        self.bank.put_rows(dst_rows, src.bank.take_rows(src_rows))

    def _grow(self, K):
        c = self._cap
        new = np.zeros((self.B, K, _k.W_LOOK))
        new[:, :c] = self._looks
        if c:
            new[:, c:] = self._looks[:, -1:]
            new[:, c:, _k.L_DET] = 0.0
        self._looks, self._cap = new, K

    def remaining_looks(self):
        """(B,) looks left to process per row."""
        return self.n_looks - self.k

    _FLAG_COLUMNS = {"detected": _k.L_DET, "maneuvering": _k.L_MAN}

    def look_data(self, name):
        """The stored (B, K_cap, ...) array of one look field (read-only), e.g. ``"truth"``: a view of the packed
        looks, or for the flags ``detected`` / ``maneuvering`` a bool array made from them."""
        if name in self._FLAG_COLUMNS:
            v = self._looks[:, :, self._FLAG_COLUMNS[name]] != 0.0
        else:
            c, tail = _k.LOOK_COLUMNS[name]
            w = int(np.prod(tail)) if tail else 1
            v = self._looks[:, :, c:c + w].reshape((self.B, self._cap) + tail)
        v.flags.writeable = False
        return v

    def look_window(self, start, n):
        """The looks ``start[b] .. start[b] + n - 1`` of every row (clipped to the stored looks, as a column past a
        row's episode reads its padding), copied in one gather: returns ``get(name)``, which gives field ``name``
        over that window, ``(B, n, ...)``, as :meth:`look_data` over all stored looks. For a trainer reading a chunk
        of looks: ``look_data("detected")`` compares the whole store (B x capacity looks) on every call.

        Args:
            start: (B,) int, each row's first look. n: looks per row (>= 1).
        """
        start = np.asarray(start, dtype=np.int64).reshape(-1)
        if start.shape != (self.B,) or int(n) < 1:
            raise ValueError(f"look_window: need start of shape ({self.B},) and n >= 1")
        cols = np.minimum(start[:, None] + np.arange(int(n))[None, :], max(self._cap - 1, 0))
        blk = self._looks[np.arange(self.B)[:, None], cols]           # (B, n, W_LOOK), a copy

        def get(name):
            if name in self._FLAG_COLUMNS:
                return blk[:, :, self._FLAG_COLUMNS[name]] != 0.0
            c, tail = _k.LOOK_COLUMNS[name]
            w = int(np.prod(tail)) if tail else 1
            return blk[:, :, c:c + w].reshape((self.B, int(n)) + tail)
        return get

    def _look_field(self, rows, k, name):
        """Field ``name`` of look ``k[i]`` of row ``rows[i]`` (n, ...), read from the packed looks."""
        if name in self._FLAG_COLUMNS:
            return self._looks[rows, k, self._FLAG_COLUMNS[name]] != 0.0
        c, tail = _k.LOOK_COLUMNS[name]
        w = int(np.prod(tail)) if tail else 1
        return self._looks[rows, k, c:c + w].reshape((rows.size,) + tail)

    # ------------------------------------------------------------------------------------------ cursor
    # For filters that run beside the chain on the same looks (the IMM, re-initialisation, Konle's blend): they read
    # the next look, and either record their own posterior for it (advance) or replace the chain's posterior after
    # a step (set_posterior). Built only on x, P, k, t_last, n_looks and look_data.
    _CURSOR_FIELDS = ("t_s", "z_m", "R_m2", "detected", "site_xy_m", "range_m", "bearing_rad", "radial_velocity_m_s",
                      "range_noise_std_m", "bearing_noise_std_rad", "radial_velocity_noise_std_m_s")

    def _cursor_rows(self, rows):
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if np.any(self.k[rows] >= self.n_looks[rows]):
            raise ValueError("a row's episode has ended; load a new episode first")
        return rows

    def next_look(self, rows, fields=None):
        """The next look of ``rows`` (index array), not processed: a dict of (n, ...) arrays ``k`` (its index),
        ``dt_s`` (since the row's last processed look) and the look fields ``fields`` (default: ``t_s``, ``z_m``,
        ``R_m2``, ``detected``, ``site_xy_m``, the measured polar values and the sigmas of the site that looked)."""
        rows = self._cursor_rows(rows)
        k = self.k[rows]
        look = {f: self._look_field(rows, k, f) for f in (self._CURSOR_FIELDS if fields is None else fields)}
        look["k"] = k
        look["dt_s"] = self._looks[rows, k, _k.L_T] - self.t_last[rows]
        return look

    def advance(self, rows, x, P):
        """Record the posterior ``x`` (n, 4), ``P`` (n, 4, 4) that a separate filter computed for the next look of
        ``rows`` and move their cursors past it (``k``, ``t_last``). Returns (n,) bool: the episode has ended. The
        feature bank is not updated (the chain's features are not produced for these looks)."""
        rows = self._cursor_rows(rows)
        k = self.k[rows]
        self.x[rows], self.P[rows] = x, P
        self.t_last[rows] = self._looks[rows, k, _k.L_T]
        self.k[rows] = k + 1
        return self.k[rows] >= self.n_looks[rows]

    def detached(self, row) -> "Tracker":
        """A 1-row Tracker holding row ``row``'s filter and feature-bank state and no looks: a track that goes on
        with plots as they come (:meth:`feed`), not from an episode."""
        row = int(row)
        out = object.__new__(type(self))
        out.__dict__.update({k: v for k, v in vars(self).items() if k not in ("bank", "_looks", "_st", "_it",
                                                                               "names", "B", "_cap")})
        out.B, out._cap, out._looks = 1, 0, np.zeros((1, 0, _k.W_LOOK))
        out._st, out._it, out.names = self._st[[row]].copy(), self._it[[row]].copy(), [self.names[row]]
        out.bank = self.bank.take_rows([row])
        return out

    def feed(self, rows, looks):
        """Make the packed look rows ``looks (n, W_LOOK)`` (:data:`radar_env.sim.looks.LOOK_COLUMNS`) the next and
        only remaining look of ``rows``: the next :meth:`step` processes it, with no next look to preview (its
        preview features 0, :func:`preview_next_plot` gives them once the next plot is known)."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        looks = np.asarray(looks, dtype=np.float64).reshape(rows.size, _k.W_LOOK)
        self._ensure_capacity(1)
        self._looks[rows, 0] = looks
        self._looks[rows, 1:] = looks[:, None]
        self._looks[rows, 1:, _k.L_DET] = 0.0
        self.k[rows], self.n_looks[rows] = 0, 1

    def set_posterior(self, rows, x, P=None):
        """Replace the posterior of ``rows`` after a step (re-initialisation, a blend with another estimate); the
        next step predicts from it. ``P=None`` keeps the covariance."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        self.x[rows] = x
        if P is not None:
            self.P[rows] = P


class TrackStart(NamedTuple):
    """The parameters of the common track start and of the chain's features, shared by the env and every tracker
    (see the module docstring): ``warmup_scans`` looks at ``warmup_q_g`` after the two-hit start, and the
    :class:`radar_env.filters.features.FeatureBank` parameters ``n_adrian``, ``window_kim_lee``, ``fma_weight``. Checked
    by :meth:`checked`; :class:`radar_env.envs.config.EnvConfig` builds one from its arguments (``track_start``).
    ``radial_velocity``: the filter also updates on each detected plot's radial velocity (from the warm-up on;
    :class:`Tracker`)."""

    warmup_scans: int = 12
    warmup_q_g: float = 0.03
    n_adrian: int = 4
    window_kim_lee: int = 12
    fma_weight: float = 0.1
    radial_velocity: bool = False

    def checked(self, prefix=""):
        """``self`` if every field is in range; else ``ValueError`` naming the field (after ``prefix``)."""
        from ..common.validate import check_number
        check_number(prefix + "warmup_scans", self.warmup_scans, 1, 1000, integer=True)
        check_number(prefix + "warmup_q_g", self.warmup_q_g, 0.0, 100.0)
        check_number(prefix + "n_adrian", self.n_adrian, 1, 50, integer=True)
        check_number(prefix + "window_kim_lee", self.window_kim_lee, 1, 1000, integer=True)
        check_number(prefix + "fma_weight", self.fma_weight, 1e-6, 1.0)
        if not isinstance(self.radial_velocity, (bool, np.bool_)):
            raise ValueError(f"{prefix}radial_velocity must be True or False, got {self.radial_velocity!r}")
        return self

    @property
    def warmup_q_m_s2(self):
        return self.warmup_q_g * G0_M_S2

    def tracker(self, batch_size):
        """A :class:`Tracker` of ``batch_size`` rows with these parameters."""
        return Tracker(batch_size, warmup_scans=self.warmup_scans, warmup_q_m_s2=self.warmup_q_m_s2,
                       n_adrian=self.n_adrian, window_kim_lee=self.window_kim_lee, fma_weight=self.fma_weight,
                       radial_velocity=bool(self.radial_velocity))


def _physical_memory():
    """The machine's physical memory in bytes (None if the OS does not say)."""
    import os
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None
