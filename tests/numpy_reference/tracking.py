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
    features  = FeatureBank.update(...)                 (normalised innovations, c_min, turn rates, ...)
    preview   = preview_next_plot(x+, P+, look k+1)      (the next plot against the q-free prediction)

The preview lets the q for look k+1 be chosen *after* plot k+1 is seen, as an IMM weighs its modes with the plot
itself: for a CV model the predicted mean ``F x`` does not depend on q (only ``P-`` does), so the innovation of the
next plot is known before q is chosen, and the estimate at k+1 still uses plots up to k+1 only (causal).

Track start (Bizup section 3.3, used for every tracker so that comparisons are apart from start-up): two-hit
initialisation from the first two detected looks (position from the second, velocity by differencing), then
``warmup_scans`` looks filtered at ``warmup_q_m_s2`` (Bizup: 12 at 0.03 g). :meth:`Tracker.load` does both and
returns the output of the last warm-up look, from which the first choice of q is made.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radar_env.sim.episode import Episode
from .features import MIN_DT_S, FeatureBank, c_min_m_s2, kim_lee_phi_2d, nis, normalized_innovation_along_cross
from .filters import predict, process_noise, transition_ct, transition_cv, two_point_init, update
from radar_env.common.units import G0_M_S2

__all__ = ["Tracker", "StepOutput", "init_looks", "looks_for_track_start", "preview_next_plot", "MAX_Q_M_S2"]

MAX_Q_M_S2 = 100.0 * G0_M_S2
"""Largest process-noise level the chain accepts (m/s^2)."""

_LOOK_FIELDS = ("t_s", "site_xy_m", "range_m", "range_noise_std_m", "bearing_noise_std_rad",
                "radial_velocity_noise_std_m_s", "truth", "truth_accel_m_s2", "truth_turn_rate_rad_s", "maneuvering",
                "detected", "bearing_rad", "radial_velocity_m_s", "z_m", "R_m2")


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


def init_looks(detected, t_s):
    """Indices of the two looks used for the two-hit start: the first detection and the next detection at a
    strictly later time. Returns ``(i1, i2)`` or raises ``ValueError`` if there are not two."""
    det = np.flatnonzero(detected)
    if det.size < 2:
        raise ValueError("an episode needs at least two detected looks for the two-hit track start")
    i1 = int(det[0])
    later = det[t_s[det] > t_s[i1]]
    if later.size == 0:
        raise ValueError("an episode needs two detected looks at different times for the two-hit track start")
    return i1, int(later[0])


def looks_for_track_start(detected, t_s, warmup_scans):
    """Number of looks an episode needs so that the track start (two hits, then ``warmup_scans`` warm-up looks)
    leaves at least one look for a policy to act on: index of the second hit + 2 + ``warmup_scans``. ``None`` if
    the episode has no two hits at different times."""
    try:
        _, i2 = init_looks(detected, t_s)
    except ValueError:
        return None
    return i2 + 2 + int(warmup_scans)


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
    det = np.asarray(next_look["detected"], dtype=bool)
    dt = next_look["t_s"] - t_s
    F = transition_cv(dt)
    x_hat = np.einsum("bij,bj->bi", F, x_post)
    FP = F @ P_post
    S0 = np.einsum("bij,bkj->bik", FP[:, :2], F[:, :2]) + next_look["R_m2"]
    S0 = np.where(det[:, None, None], S0, np.eye(2))
    nu = np.where(det[:, None], next_look["z_m"] - x_hat[:, :2], 0.0)
    nac = normalized_innovation_along_cross(nu, S0, x_hat[:, 2:4])
    phi = kim_lee_phi_2d(nu[:, :, None] * nu[:, None, :], S0, dt)
    rdot = np.where(det, next_look["radial_velocity_m_s"], 0.0)
    cm = c_min_m_s2(x_post, np.where(det, next_look["bearing_rad"], 0.0), rdot, dt)
    los = x_hat[:, :2] - next_look["site_xy_m"]
    rng = np.maximum(np.hypot(los[:, 0], los[:, 1]), 1.0)
    rdot_hat = (los[:, 0] * x_hat[:, 2] + los[:, 1] * x_hat[:, 3]) / rng
    los_accel = np.where(det, (rdot - rdot_hat) / np.maximum(dt, MIN_DT_S), 0.0)
    u = los / rng[:, None]
    h = np.concatenate([(x_hat[:, 2:4] - rdot_hat[:, None] * u) / rng[:, None], u], axis=1)
    s_r = np.einsum("bi,bij,bj->b", h, FP @ np.swapaxes(F, 1, 2), h) + next_look["radial_velocity_noise_std_m_s"] ** 2
    rdot_nu = np.where(det, (rdot - rdot_hat) / np.sqrt(s_r), 0.0)
    return {"next_nu_along": nac[:, 0], "next_nu_cross": nac[:, 1], "next_nis": nis(nu, S0),
            "next_q_fit_m_s2": np.where(det, np.sqrt(np.maximum(phi, 0.0)), 0.0),
            "next_c_min_m_s2": np.where(det, cm, 0.0), "next_los_accel_m_s2": los_accel,
            "next_rdot_nu": rdot_nu, "next_dt_s": dt,
            "next_meas_std_m": np.where(det, np.sqrt(0.5 * (next_look["R_m2"][:, 0, 0] + next_look["R_m2"][:, 1, 1])),
                                        0.0), "next_detected": det.astype(np.float64)}


def _bank_update(bank, rows, **inputs):
    """``bank.update(**inputs)`` for a subset of rows (index array; None = all rows): the rows' feature state is
    taken out, updated and put back, so the other rows are untouched (track start of freshly reset rows)."""
    if rows is None:
        return bank.update(**inputs)
    sub = bank.take_rows(rows)
    out = sub.update(**inputs)
    bank.put_rows(rows, sub)
    return out


class Tracker:
    """B Kalman tracks over B episodes, stepped together (see module docstring).

    Args:
        batch_size: number of rows B.
        warmup_scans: looks filtered at ``warmup_q_m_s2`` after the two-hit start (Bizup: 12), >= 1 (the first
            observation needs the features of one filtered look).
        warmup_q_m_s2: process-noise level during warm-up (Bizup: 0.03 g).
        n_adrian, window_kim_lee, fma_weight: passed to :class:`radar_env.filters.features.FeatureBank`.
    """

    def __init__(self, batch_size, warmup_scans=12, warmup_q_m_s2=0.03 * G0_M_S2, n_adrian=4, window_kim_lee=12,
                 fma_weight=0.1):
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
        self._cap = 0
        self._data = {}
        self.n_looks = np.zeros(self.B, dtype=np.int64)
        self.k = np.zeros(self.B, dtype=np.int64)          # next look to process
        self.t_last = np.zeros(self.B)
        self.x = np.zeros((self.B, 4))
        self.P = np.tile(np.eye(4), (self.B, 1, 1))
        self.names = [""] * self.B

    # ------------------------------------------------------------------------------------------ episode data
    def _ensure_capacity(self, K, like: Episode):
        if K > self._cap:
            self._grow(K, {f: getattr(like, f)[None] for f in _LOOK_FIELDS})

    def load(self, rows, episodes, known_input=False):
        """Put ``episodes`` into ``rows``, start their tracks (two-hit + warm-up) and return the last warm-up
        :class:`StepOutput` for those rows (in the order of ``rows``). ``known_input`` is passed to the warm-up
        steps (only the clairvoyant bound uses it)."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        episodes = list(episodes)
        if rows.size != len(episodes):
            raise ValueError(f"got {rows.size} rows and {len(episodes)} episodes")
        self._ensure_capacity(max(e.n_looks for e in episodes), episodes[0])
        z1, R1, t1, z2, R2, t2 = [], [], [], [], [], []
        for r, e in zip(rows, episodes):
            i1, i2 = init_looks(e.detected, e.t_s)
            need = i2 + 1 + self.warmup_scans
            if e.n_looks < need:
                raise ValueError(f"episode {e.name!r} has {e.n_looks} looks; the track start needs {need} "
                                 f"(two hits at looks {i1} and {i2}, then {self.warmup_scans} warm-up looks)")
            K = e.n_looks
            for f in _LOOK_FIELDS:
                self._data[f][r, :K] = getattr(e, f)
                self._data[f][r, K:] = self._data[f][r, K - 1]   # pad: repeat the last look, not detected
            self._data["detected"][r, K:] = False
            self.n_looks[r], self.names[r] = K, e.name
            self.k[r], self.t_last[r] = i2 + 1, e.t_s[i2]
            z1.append(e.z_m[i1]); R1.append(e.R_m2[i1]); t1.append(e.t_s[i1])
            z2.append(e.z_m[i2]); R2.append(e.R_m2[i2]); t2.append(e.t_s[i2])
        z1, R1, t1, z2, R2, t2 = map(np.array, (z1, R1, t1, z2, R2, t2))
        x0, P0 = two_point_init(z1, R1, t1, z2, R2, t2)
        self.x[rows], self.P[rows] = x0, P0
        mask = np.zeros(self.B, dtype=bool)
        mask[rows] = True
        plots = np.zeros((self.B, 2, 2))
        times = np.zeros((self.B, 2))
        plots[rows, 0], plots[rows, 1], times[rows, 0], times[rows, 1] = z1, z2, t1, t2
        xfull = np.zeros((self.B, 4))
        tfull = np.zeros(self.B)
        xfull[rows], tfull[rows] = x0, t2
        self.bank.reset(mask, plots_xy=plots, plot_times_s=times, x=xfull, t_s=tfull)
        out = None
        for _ in range(self.warmup_scans):
            out = self.step(np.full(rows.size, self.warmup_q_m_s2), rows=rows, known_input=known_input)
        return out

    # ------------------------------------------------------------------------------------------ the chain
    def step(self, q_m_s2, rows=None, turn_rate_rad_s=None, known_input=False) -> StepOutput:
        """Process the next look of ``rows`` (all rows if None) with process-noise level ``q_m_s2`` (m/s^2).

        Args:
            q_m_s2: (n,) or scalar, in [0, MAX_Q_M_S2]; a ``ValueError`` names the bad value otherwise.
            rows: index array of the rows to step (default all).
            turn_rate_rad_s: (n,) or None. If given, predict with the coordinated-turn ``F_ct(dt, omega)``.
            known_input: if True, add the true motion not explained by ``F`` (``u = x_true[k] - F x_true[k-1]``):
                the clairvoyant bound's known-input KF. Never used by a policy.
        """
        sel = np.arange(self.B) if rows is None else np.asarray(rows, dtype=np.int64).reshape(-1)
        n = sel.size
        q = np.broadcast_to(np.asarray(q_m_s2, dtype=np.float64), (n,))
        if not np.all(np.isfinite(q)) or np.any(q < 0) or np.any(q > MAX_Q_M_S2):
            bad = q[~(np.isfinite(q) & (q >= 0) & (q <= MAX_Q_M_S2))][0]
            raise ValueError(f"q_m_s2 must be finite and in [0, {MAX_Q_M_S2:.1f}] m/s^2, got {bad!r}")
        k = self.k[sel]
        if np.any(k >= self.n_looks[sel]):
            raise ValueError("step() called on a row whose episode has ended; load a new episode first")
        d = self._data
        look = {f: d[f][sel, k] for f in _LOOK_FIELDS}
        t = look["t_s"]
        dt = t - self.t_last[sel]
        F = transition_cv(dt) if turn_rate_rad_s is None else transition_ct(dt, turn_rate_rad_s)
        Q = process_noise(dt, q)
        x_prev, P_prev = self.x[sel], self.P[sel]
        u = None
        if known_input:
            prev_truth = d["truth"][sel, k - 1]
            u = look["truth"] - np.einsum("bij,bj->bi", F, prev_truth)
        x_prior, P_prior = predict(x_prev, P_prev, F, Q, u)
        det = look["detected"]
        det2 = det[:, None]
        upd = update(x_prior, P_prior, look["z_m"], look["R_m2"], det)
        feats = _bank_update(
            self.bank, None if rows is None else sel, x_prev=x_prev, x_prior=x_prior, P_post_prev=P_prev, F=F,
            R=np.where(det2[:, :, None], look["R_m2"], 0.0),
            nu=upd.nu, S=upd.S, x_post=upd.x, z=np.where(det2, look["z_m"], 0.0), t_s=t, dt_s=dt,
            bearing_rad=np.where(det, look["bearing_rad"], 0.0),
            radial_velocity_m_s=np.where(det, look["radial_velocity_m_s"], 0.0), detected=det,
            site_xy=look["site_xy_m"])
        self.x[sel], self.P[sel], self.t_last[sel] = upd.x, upd.P, t
        self.k[sel] = k + 1
        has_next = k + 1 < self.n_looks[sel]
        kn = np.minimum(k + 1, self._cap - 1)
        nxt = {f: d[f][sel, kn] for f in ("t_s", "z_m", "R_m2", "bearing_rad", "radial_velocity_m_s",
                                           "radial_velocity_noise_std_m_s", "site_xy_m")}
        nxt["detected"] = d["detected"][sel, kn] & has_next
        nxt["t_s"] = np.where(has_next, nxt["t_s"], t)
        feats.update(preview_next_plot(upd.x, upd.P, t, nxt))
        return StepOutput(
            look_index=k, t_s=t, dt_s=dt, q_m_s2=q.copy(), x_prior=x_prior, P_prior=P_prior, x=upd.x, P=upd.P,
            nu=upd.nu, S=upd.S, nis=upd.nis, detected=look["detected"], z_m=look["z_m"], R_m2=look["R_m2"],
            site_xy_m=look["site_xy_m"], range_m=look["range_m"], bearing_rad=look["bearing_rad"],
            radial_velocity_m_s=look["radial_velocity_m_s"], range_noise_std_m=look["range_noise_std_m"],
            bearing_noise_std_rad=look["bearing_noise_std_rad"], truth=look["truth"], truth_accel_m_s2=look["truth_accel_m_s2"],
            maneuvering=look["maneuvering"], features=feats, done=self.k[sel] >= self.n_looks[sel])

    # ------------------------------------------------------------------------------------------ helpers
    def copy_rows_from(self, src: "Tracker", src_rows, dst_rows):
        """Copy whole track rows (episode data, filter state, feature-bank state) from another Tracker with the
        same configuration. Lets a caller start tracks in one large batch and hand them out row by row."""
        src_rows = np.asarray(src_rows, dtype=np.int64)
        dst_rows = np.asarray(dst_rows, dtype=np.int64)
        if src._cap > self._cap:
            like = {f: src._data[f][:1, :1] for f in _LOOK_FIELDS}
            self._grow(src._cap, like)
        for f in _LOOK_FIELDS:
            self._data[f][dst_rows, : src._cap] = src._data[f][src_rows]
            if self._cap > src._cap:
                self._data[f][dst_rows, src._cap:] = src._data[f][src_rows, -1:]
        self._data["detected"][dst_rows, src._cap:] = False
        for name in ("n_looks", "k", "t_last", "x", "P"):
            getattr(self, name)[dst_rows] = getattr(src, name)[src_rows]
        for d, s_ in zip(dst_rows, src_rows):
            self.names[d] = src.names[s_]
        self.bank.put_rows(dst_rows, src.bank.take_rows(src_rows))

    def _grow(self, K, like):
        new = {}
        for f in _LOOK_FIELDS:
            a = like[f]
            arr = np.zeros((self.B, K) + a.shape[2:], dtype=a.dtype)
            if f in self._data:
                arr[:, : self._cap] = self._data[f]
                arr[:, self._cap:] = self._data[f][:, -1:] if self._cap else 0
            new[f] = arr
        if self._cap and "detected" in new:
            new["detected"][:, self._cap:] = False
        self._data, self._cap = new, K

    def remaining_looks(self):
        """(B,) looks left to process per row."""
        return self.n_looks - self.k

    def look_data(self, name):
        """The stored (B, K_cap, ...) array of one look field (read-only view), e.g. ``"truth"``."""
        v = self._data[name].view()
        v.flags.writeable = False
        return v
