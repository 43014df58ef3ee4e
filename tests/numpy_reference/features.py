"""Per-scan maneuver features for the 4-state CV Kalman filter (pure numpy, float64, batched, no RNG).

Conventions (docs/architecture.md): SI units, x east / y north, state ``[x, y, vx, vy]``, ``H = [I2 0]``,
heading and bearing clockwise from north (``atan2(east, north)``), radial velocity positive when receding,
turn rate positive = clockwise = right turn. Every array has the batch axis first.

Two layers:

* pure formula functions (``wrap_angle``, ``nis``, ``c_min_m_s2``, ``kim_lee_phi_2d`` ...), each valid for any
  batch size, returning finite values for every finite input (the fallbacks are documented per function);
* :class:`FeatureBank`, a stateful batched bank holding the ring buffers the history-based features need
  (Adrian's turn-rate algorithms 1 and 2, Kim & Lee's sliding innovation window, Bizup's CKF fading-memory
  average). Its ``update`` is vectorised over the batch (no Python loop over rows).

Readings of ambiguous paper items (see also /work/shared/seeds/README.md):

* Bizup eqs 3-6 (c_min) are garbled in the text. Used here: speed ``s`` and heading ``h_prev`` from the previous
  posterior; ``gamma = arccos(clip(rdot / s, -1, 1))`` with ``rdot`` positive receding, so that
  ``rdot = s cos(h - bearing)`` exactly; candidate final headings ``bearing +/- gamma``; each reachable by a right
  turn of ``d = (h_c - h_prev) mod 2pi`` or a left turn of ``2pi - d`` (four turns); centripetal acceleration of a
  turn of heading change ``D`` over the arc length ``s*dt`` is ``s^2 / radius = s^2 * D / (s*dt) = s*D/dt``
  (eq 6 as printed inverts the ratio); ``c_min`` is the smallest of the four. Bizup's "bearing does not change
  much" approximation is not needed: the bearing of the current plot is used as the final bearing.
* Bizup's CKF "FMA decay rate .1": read as weight 0.1 on the NEW sample,
  ``FMA_k = 0.9 FMA_{k-1} + 0.1 |nu_k|`` (an effective memory of ~10 scans). The other reading (weight 0.9 on
  the new sample) would make the FMA nearly the raw |nu| and contradict "the FMA test is slow to detect
  maneuvers". The sample is the position error |nu| (m), i.e. the innovation magnitude.
* Kim & Lee eq 16 sums i = k-N..k (N+1 terms) but divides by N; read as the mean of the last N outer products.
  Eq 15 is 1-D (alpha-beta tracker); for the 2-D KF it is generalised by the trace:
  ``phi = trace(S_hat - S0) / trace(H Q1 H^T)`` with ``S0 = H F P+ F^T H^T + R`` and ``Q1`` the process noise at
  q = 1 m/s^2, so ``H Q1 H^T = dt^4/4 I2`` and ``phi`` estimates ``q^2`` in (m/s^2)^2.
* Adrian algorithm 1 divides the heading difference by the scan period ``t``; with irregular plot times the
  divisor used is the difference of the two chord headings' mid-times, which equals T for a regular radar and
  makes the estimate exact for a noise-free constant turn (a chord's heading is the heading at its mid-time).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "wrap_angle",
    "heading_rad",
    "nis",
    "normalized_innovation_along_cross",
    "c_min_m_s2",
    "fading_memory_average",
    "adrian_heading_from_plots",
    "adrian_mid_time_dt_s",
    "adrian_turn_rate_alg1_rad_s",
    "adrian_turn_rate_alg2_rad_s",
    "innovation_cov_without_process_noise",
    "kim_lee_phi_2d",
    "kim_lee_phi_1d",
    "kim_lee_variance",
    "FeatureBank",
]

TWO_PI = 2.0 * np.pi
MIN_SPEED_M_S = 1e-6
"""Below this estimated speed the heading is undefined: headings fall back to 0 (north) and c_min to 0."""
MIN_DT_S = 1e-3
"""Time differences are floored at this value in rate formulas (turn rates, c_min, Kim & Lee) so that
coincident updates (two sites, same time) give large but finite values."""


def _f64(a):
    return np.asarray(a, dtype=np.float64)


def wrap_angle(a):
    """Wrap angles (rad) to the half-open interval (-pi, pi]: ``pi - ((pi - a) mod 2pi)``; exact identity for
    angles already in (-pi, pi]."""
    a = _f64(a)
    r = np.pi - np.mod(np.pi - a, TWO_PI)
    # mod can round up to exactly 2pi for tiny negative arguments -> r == -pi; move it to +pi.
    r = np.where(r <= -np.pi, r + TWO_PI, r)
    # angles already inside are returned unchanged (pi - (pi - a) loses up to 1 ulp of a).
    return np.where((a > -np.pi) & (a <= np.pi), a, r)


def heading_rad(vx, vy):
    """Heading (rad, clockwise from north) of velocity ``(vx, vy)``: ``atan2(vx, vy)`` in (-pi, pi].

    Zero velocity gives 0 (north), numpy's ``atan2(0, 0)``; no warning is raised."""
    return np.arctan2(_f64(vx), _f64(vy))


def nis(nu, S):
    """Normalised innovation squared ``nu^T S^-1 nu`` (dimensionless), shapes (B,2), (B,2,2) -> (B,).

    Closed-form 2x2 inverse: with ``S = [[a, b], [c, d]]``, ``det = ad - bc``,
    ``nis = (d nu0^2 - (b + c) nu0 nu1 + a nu1^2) / det``.
    Fallback: 0 where ``det <= 0`` (S not positive definite / degenerate)."""
    nu = _f64(nu)
    S = _f64(S)
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    n0, n1 = nu[..., 0], nu[..., 1]
    det = a * d - b * c
    ok = det > 0.0
    num = d * n0 * n0 - (b + c) * n0 * n1 + a * n1 * n1
    return np.where(ok, num / np.where(ok, det, 1.0), 0.0)


def _along_cross_units(velocity):
    """Unit along-track ``u_a = v/|v|`` and cross-track ``u_c = (vy, -vx)/|v|`` (right of track), (B,2) each.

    Below MIN_SPEED_M_S: along = north (0, 1), cross = east (1, 0) (east is right of north)."""
    v = _f64(velocity)
    vx, vy = v[..., 0], v[..., 1]
    s = np.hypot(vx, vy)
    ok = s > MIN_SPEED_M_S
    inv = np.where(ok, 1.0 / np.where(ok, s, 1.0), 0.0)
    ax = np.where(ok, vx * inv, 0.0)
    ay = np.where(ok, vy * inv, 1.0)
    return ax, ay, ay, -ax  # cross = (ay, -ax)


def normalized_innovation_along_cross(nu, S, velocity):
    """Innovation components along and across the estimated track, each normalised to ~N(0, 1).

    ``u_a = v / |v|`` (along-track), ``u_c = (vy, -vx) / |v|`` (cross-track, positive to the RIGHT of the track,
    i.e. where a right turn pulls the target); ``nu_a = u_a . nu / sqrt(u_a^T S u_a)``, likewise ``nu_c``.
    ``velocity`` (B,2) is normally the prior velocity (the prediction the innovation refers to); nu (B,2) in m;
    S (B,2,2) in m^2. Returns (B,2) ``[nu_along, nu_cross]`` (dimensionless).

    Fallbacks: speed <= MIN_SPEED_M_S -> axes north (along) / east (cross); projected variance <= 0 -> 0."""
    nu = _f64(nu)
    S = _f64(S)
    ax, ay, cx, cy = _along_cross_units(velocity)
    n0, n1 = nu[..., 0], nu[..., 1]
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    pa = ax * n0 + ay * n1
    pc = cx * n0 + cy * n1
    va = a * ax * ax + (b + c) * ax * ay + d * ay * ay
    vc = a * cx * cx + (b + c) * cx * cy + d * cy * cy
    oka = va > 0.0
    okc = vc > 0.0
    na = np.where(oka, pa / np.sqrt(np.where(oka, va, 1.0)), 0.0)
    nc = np.where(okc, pc / np.sqrt(np.where(okc, vc, 1.0)), 0.0)
    return np.stack([na, nc], axis=-1)


def c_min_m_s2(x_prev, bearing_rad, radial_velocity_m_s, dt_s, min_dt_s=MIN_DT_S, min_speed_m_s=MIN_SPEED_M_S):
    """Bizup's minimum centripetal acceleration statistic c_min (m/s^2, >= 0), shapes (B,4), (B,), (B,), (B,).

    Speed ``s = |(vx, vy)|`` and heading ``h_prev = atan2(vx, vy)`` from the previous posterior ``x_prev``
    (the estimate at time ``t - dt_s``); ``bearing_rad`` and ``radial_velocity_m_s`` (``rdot``, positive
    receding) from the current plot, measured from the site that made it:

        gamma = arccos(clip(rdot / s, -1, 1))                    (eq 4, so rdot = s cos(h - bearing))
        h_c   = bearing +/- gamma                                 (two candidate final headings)
        d_c   = (h_c - h_prev) mod 2pi ; turns {d_c (right), 2pi - d_c (left)}   (eq 5: four turns)
        c     = s^2 / radius = s^2 * D / (s dt) = s D / dt        (eq 6, arc length s*dt)
        c_min = min over the four turns.

    The true turn is one of the four, so c_min <= true centripetal acceleration ``s |omega|`` (for
    ``|omega dt| < pi``), with equality unless the mirror candidate (reflection of the true heading about the
    bearing line) is closer to ``h_prev``; that happens when the heading is near-radial (gamma small: the two
    candidates nearly coincide), so c_min under-reports turns flown near the radial direction.
    Not divided by g: the caller converts. Fallbacks: ``s <= min_speed_m_s`` -> 0; ``dt_s`` floored at
    ``min_dt_s``."""
    x_prev = _f64(x_prev)
    vx, vy = x_prev[..., 2], x_prev[..., 3]
    s = np.hypot(vx, vy)
    ok = s > min_speed_m_s
    s_safe = np.where(ok, s, 1.0)
    h_prev = np.arctan2(vx, vy)
    gamma = np.arccos(np.clip(_f64(radial_velocity_m_s) / s_safe, -1.0, 1.0))
    b = _f64(bearing_rad)
    d0 = np.mod(b + gamma - h_prev, TWO_PI)
    d1 = np.mod(b - gamma - h_prev, TWO_PI)
    dmin = np.minimum(np.minimum(d0, TWO_PI - d0), np.minimum(d1, TWO_PI - d1))
    dt = np.maximum(_f64(dt_s), min_dt_s)
    return np.where(ok, s * dmin / dt, 0.0)


def fading_memory_average(previous, value, weight):
    """Fading-memory average ``FMA_k = (1 - weight) FMA_{k-1} + weight * value`` (units of ``value``).

    Bizup's CKF: value = |nu| (position error, m), "decay rate 0.1" read as ``weight = 0.1`` on the new sample
    (see module docstring)."""
    w = _f64(weight)
    return (1.0 - w) * _f64(previous) + w * _f64(value)


def adrian_heading_from_plots(z_new, z_old):
    """Measurement heading (rad) of the chord from plot ``z_old`` to plot ``z_new`` (each (B,2), m):
    ``atan2(dx, dy)``, clockwise from north. Coincident plots give 0."""
    z_new = _f64(z_new)
    z_old = _f64(z_old)
    return np.arctan2(z_new[..., 0] - z_old[..., 0], z_new[..., 1] - z_old[..., 1])


def adrian_mid_time_dt_s(t_k, t_km1, t_kmn, t_km1mn):
    """Time between the mid-times of two successive n-apart chords (s):
    ``(t_k + t_{k-n})/2 - (t_{k-1} + t_{k-1-n})/2`` (= T for a regular radar)."""
    return 0.5 * (_f64(t_k) + _f64(t_kmn)) - 0.5 * (_f64(t_km1) + _f64(t_km1mn))


def _rate(dh, dt, min_dt_s):
    return wrap_angle(dh) / np.maximum(_f64(dt), min_dt_s)


def adrian_turn_rate_alg1_rad_s(z_seq, t_seq, min_dt_s=MIN_DT_S):
    """Adrian's algorithm 1 (measurement headings n plots apart), rad/s, positive = right turn.

    ``z_seq`` (B, n+2, 2) and ``t_seq`` (B, n+2): the last n+2 plots, oldest first (index 0 = plot k-1-n,
    index -1 = plot k). ``h_k = atan2`` of chord (k-n -> k), ``h_{k-1}`` of chord (k-1-n -> k-1);
    ``omega = wrap(h_k - h_{k-1}) / dt_mid`` with ``dt_mid`` from :func:`adrian_mid_time_dt_s`
    (floored at ``min_dt_s``). Exact for a noise-free constant turn with ``|omega dt_mid| < pi``."""
    z = _f64(z_seq)
    t = _f64(t_seq)
    h_k = adrian_heading_from_plots(z[:, -1], z[:, 1])
    h_km1 = adrian_heading_from_plots(z[:, -2], z[:, 0])
    return _rate(h_k - h_km1, adrian_mid_time_dt_s(t[:, -1], t[:, -2], t[:, 1], t[:, 0]), min_dt_s)


def adrian_turn_rate_alg2_rad_s(v_new, v_old, t_new_s, t_old_s, min_dt_s=MIN_DT_S):
    """Adrian's algorithm 2 (smoothed = filtered headings), rad/s, positive = right turn:
    ``wrap(heading(v_k) - heading(v_{k-n})) / (t_k - t_{k-n})`` with ``v`` (B,2) filtered velocities
    (``n t`` in the paper for a regular radar). Time difference floored at ``min_dt_s``; zero velocity has
    heading 0."""
    v_new = _f64(v_new)
    v_old = _f64(v_old)
    dh = heading_rad(v_new[..., 0], v_new[..., 1]) - heading_rad(v_old[..., 0], v_old[..., 1])
    return _rate(dh, _f64(t_new_s) - _f64(t_old_s), min_dt_s)


def innovation_cov_without_process_noise(F, P_post_prev, R):
    """``S0 = H F P+ F^T H^T + R`` (m^2), (B,4,4), (B,4,4), (B,2,2) -> (B,2,2): the innovation covariance the
    CV filter would have with zero process noise (Kim & Lee eq 14 without the ``phi Q`` term)."""
    F2 = _f64(F)[..., :2, :]
    return F2 @ _f64(P_post_prev) @ np.swapaxes(F2, -1, -2) + _f64(R)


def kim_lee_phi_2d(S_hat, S0, dt_s, min_dt_s=MIN_DT_S):
    """Kim & Lee fudge factor generalised to the 2-D CV KF by the trace, (m/s^2)^2 = m^2/s^4:

        phi = trace(S_hat - S0) / trace(H Q1 H^T),   H Q1 H^T = dt^4/4 I2  =>  trace = dt^4 / 2,

    where ``Q1`` is the piecewise-constant white acceleration Q at q = 1 m/s^2 (eq 15 with the matrix "division"
    replaced by the ratio of traces), so ``phi`` estimates ``q^2``. Can be negative (eq 17 handles that, see
    :func:`kim_lee_variance`). ``dt_s`` floored at ``min_dt_s``."""
    S_hat = _f64(S_hat)
    S0 = _f64(S0)
    tr = (S_hat[..., 0, 0] + S_hat[..., 1, 1]) - (S0[..., 0, 0] + S0[..., 1, 1])
    dt = np.maximum(_f64(dt_s), min_dt_s)
    return tr / (0.5 * dt ** 4)


def kim_lee_phi_1d(S_hat, FPF11, R, T_s, min_dt_s=MIN_DT_S):
    """Kim & Lee eq 15 for the 1-D alpha-beta tracker, (m/s^2)^2:
    ``phi = (S_hat - (F P_o F^T)_11 - R) / (T^4 / 4)`` with S_hat the windowed mean squared innovation (m^2),
    ``(F P_o F^T)_11`` the predicted position variance without process noise (m^2), R the measurement
    variance (m^2), T the scan period (s, floored at ``min_dt_s``)."""
    T = np.maximum(_f64(T_s), min_dt_s)
    return (_f64(S_hat) - _f64(FPF11) - _f64(R)) / (0.25 * T ** 4)


def kim_lee_variance(phi, sigma_D2):
    """Kim & Lee eq 17: ``phi`` where ``phi >= 0``, else the predefined maneuverability variance ``sigma_D2``."""
    phi = _f64(phi)
    return np.where(phi >= 0.0, phi, _f64(sigma_D2))


_HELD = ("nu_along", "nu_cross", "nis", "c_min_m_s2", "turn_rate_alg1_rad_s", "fma_innovation_m",
         "kim_lee_phi_m2_s4", "nu_along_fm", "nu_cross_fm", "nis_fm")


class FeatureBank:
    """Batched per-track feature state (B rows), updated once per scan by :meth:`update`.

    Buffers (numpy arrays, one ring-buffer write index per row as an int array):

    * ``plot_xy (B, n+2, 2)``, ``plot_t (B, n+2)``: last n+2 DETECTED plot positions (m) and times (s), for
      Adrian's algorithm 1;
    * ``head (B, n+1)``, ``head_t (B, n+1)``: last n+1 filtered (posterior) headings (rad) and times, for
      algorithm 2, pushed on every update, detected or not;
    * ``outer (B, N, 2, 2)``: last N innovation outer products ``nu nu^T`` (m^2) of detected scans, and their
      count, for Kim & Lee's S_hat (eq 16);
    * ``fma (B,)``: fading-memory average of |nu| (m), starting at 0 after reset (Bizup's CKF);
    * fading-memory averages (weight ``fm_weight`` on the new sample, 0 after reset) of the signed normalised
      innovations along and across track and of the NIS (Bar-Shalom's fading-memory NIS, alpha = 1 - weight):
      a persistent bias (the track lagging after a turn at too low a q) shows in the signed means, a noise level
      above its 2-dof expectation in the NIS average.

    Missed detections (``detected`` False): the measurement-based features (``nu_along``, ``nu_cross``, ``nis``,
    ``c_min_m_s2``, ``turn_rate_alg1_rad_s``, ``fma_innovation_m``, ``kim_lee_phi_m2_s4``/``kim_lee_q2_m2_s4``,
    ``nu_along_fm``, ``nu_cross_fm``, ``nis_fm``)
    hold their last value and their buffers are not touched; algorithm 2, ``speed_m_s``, ``heading_rad`` and
    ``range_m`` update from the filter output. Before a feature is available its value is 0 and its
    ``*_valid`` flag False. All outputs are finite float64 (flags bool), shape (B,).
    """

    def __init__(self, batch_size, n_adrian=4, window_kim_lee=12, fma_weight=0.1, sigma_D2_m2_s4=0.0,
                 kim_lee_min_count=None, min_dt_s=MIN_DT_S, fm_weight=0.2):
        """``n_adrian``: plot / heading interval n of Adrian's algorithms (paper: 3 or 4 best).
        ``window_kim_lee``: N of eq 16 (paper: 12). ``fma_weight``: weight of the new |nu| sample (Bizup 0.1).
        ``sigma_D2_m2_s4``: eq 17 fallback variance for ``kim_lee_q2_m2_s4``. ``kim_lee_min_count``: number of
        detected scans in the window before phi is reported (default N, a full window). ``fm_weight``: weight of
        the new sample in the signed-innovation and NIS fading-memory averages (Bar-Shalom's alpha = 0.8)."""
        self.B = int(batch_size)
        self.n = int(n_adrian)
        if self.n < 1:
            raise ValueError("n_adrian must be >= 1")
        self.N = int(window_kim_lee)
        if self.N < 1:
            raise ValueError("window_kim_lee must be >= 1")
        self.fma_weight = float(fma_weight)
        self.fm_weight = float(fm_weight)
        if not 0.0 < self.fm_weight <= 1.0:
            raise ValueError(f"fm_weight must be in (0, 1], got {fm_weight!r}")
        self.sigma_D2 = float(sigma_D2_m2_s4)
        self.kim_lee_min_count = self.N if kim_lee_min_count is None else int(kim_lee_min_count)
        self.min_dt_s = float(min_dt_s)
        B, n, N = self.B, self.n, self.N
        self._rows = np.arange(B)
        self.plot_xy = np.zeros((B, n + 2, 2))
        self.plot_t = np.zeros((B, n + 2))
        self.plot_idx = np.zeros(B, dtype=np.int64)  # next write slot
        self.plot_count = np.zeros(B, dtype=np.int64)
        self.head = np.zeros((B, n + 1))
        self.head_t = np.zeros((B, n + 1))
        self.head_idx = np.zeros(B, dtype=np.int64)
        self.head_count = np.zeros(B, dtype=np.int64)
        self.outer = np.zeros((B, N, 2, 2))
        self.outer_idx = np.zeros(B, dtype=np.int64)
        self.outer_count = np.zeros(B, dtype=np.int64)
        self.fma = np.zeros(B)
        self.n_detections = np.zeros(B, dtype=np.int64)
        self.last = {k: np.zeros(B) for k in _HELD}
        self.last["kim_lee_q2_m2_s4"] = np.zeros(B)
        self.last_valid = {k: np.zeros(B, dtype=bool) for k in ("nu", "turn_rate_alg1", "kim_lee")}

    # ------------------------------------------------------------------ row subsets
    _ROW_ARRAYS = ("plot_xy", "plot_t", "plot_idx", "plot_count", "head", "head_t", "head_idx", "head_count",
                   "outer", "outer_idx", "outer_count", "fma", "n_detections")
    _ROW_DICTS = ("last", "last_valid")

    def take_rows(self, rows):
        """A new bank holding copies of rows ``rows`` (index array) of this one, same parameters."""
        rows = np.asarray(rows, dtype=np.int64)
        sub = object.__new__(type(self))
        sub.__dict__.update({k: v for k, v in vars(self).items()
                             if k not in self._ROW_ARRAYS + self._ROW_DICTS})
        sub.B, sub._rows = int(rows.size), np.arange(rows.size)
        for name in self._ROW_ARRAYS:
            setattr(sub, name, getattr(self, name)[rows])
        for name in self._ROW_DICTS:
            setattr(sub, name, {k: v[rows] for k, v in getattr(self, name).items()})
        return sub

    def put_rows(self, rows, other):
        """Write all rows of bank ``other`` into rows ``rows`` of this one."""
        rows = np.asarray(rows, dtype=np.int64)
        for name in self._ROW_ARRAYS:
            getattr(self, name)[rows] = getattr(other, name)
        for name in self._ROW_DICTS:
            mine = getattr(self, name)
            for k, v in getattr(other, name).items():
                mine[k][rows] = v

    # ------------------------------------------------------------------ reset
    def reset(self, mask=None, plots_xy=None, plot_times_s=None, x=None, t_s=None):
        """Re-initialise rows where ``mask`` (B,) is True (all rows if None); other rows are untouched.

        Optional seeding, e.g. from a two-hit track start: ``plots_xy`` (B, m, 2) and ``plot_times_s`` (B, m),
        oldest first, are pushed into the plot buffer (only the last n+2 kept); ``x`` (B,4) and ``t_s`` (B,)
        push the heading of the initial estimate into the algorithm-2 buffer. Only masked rows are read."""
        m = np.ones(self.B, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(self.B)
        for arr in (self.plot_xy, self.plot_t, self.head, self.head_t, self.outer, self.fma):
            arr[m] = 0.0
        for arr in (self.plot_idx, self.plot_count, self.head_idx, self.head_count, self.outer_idx,
                    self.outer_count, self.n_detections):
            arr[m] = 0
        for v in self.last.values():
            v[m] = 0.0
        for v in self.last_valid.values():
            v[m] = False
        if plots_xy is not None:
            pz = _f64(plots_xy)
            pt = _f64(plot_times_s)
            for j in range(pz.shape[1]):  # loop over seed plots (m ~ 2), not over rows
                self._push_plot(m, pz[:, j], pt[:, j])
        if x is not None:
            x = _f64(x)
            self._push_heading(m, heading_rad(x[:, 2], x[:, 3]), _f64(t_s))

    # ------------------------------------------------------------------ ring buffers
    def _push_plot(self, m, z, t):
        r, i = self._rows, self.plot_idx
        self.plot_xy[r, i] = np.where(m[:, None], z, self.plot_xy[r, i])
        self.plot_t[r, i] = np.where(m, t, self.plot_t[r, i])
        L = self.n + 2
        self.plot_idx = np.where(m, (i + 1) % L, i)
        self.plot_count = np.where(m, np.minimum(self.plot_count + 1, L), self.plot_count)

    def _push_heading(self, m, h, t):
        r, i = self._rows, self.head_idx
        self.head[r, i] = np.where(m, h, self.head[r, i])
        self.head_t[r, i] = np.where(m, t, self.head_t[r, i])
        L = self.n + 1
        self.head_idx = np.where(m, (i + 1) % L, i)
        self.head_count = np.where(m, np.minimum(self.head_count + 1, L), self.head_count)

    # ------------------------------------------------------------------ update
    def update(self, x_prev, x_prior, P_post_prev, F, R, nu, S, x_post, z, t_s, dt_s, bearing_rad,
               radial_velocity_m_s, detected, site_xy):
        """One scan for every row. Shapes: ``x_prev, x_prior, x_post (B,4)``; ``P_post_prev, F (B,4,4)`` (F may
        be (4,4)); ``R, S (B,2,2)``; ``nu, z, site_xy (B,2)`` (site_xy may be (2,)); ``t_s, dt_s, bearing_rad,
        radial_velocity_m_s (B,)``; ``detected (B,) bool``.

        ``x_prev`` is the posterior at ``t_s - dt_s`` (the state c_min's turn starts from and the P+ of the
        Kim & Lee S0); ``bearing_rad``/``radial_velocity_m_s`` are the plot's, from the site ``site_xy``.

        Returns a dict of (B,) arrays: ``nu_along``, ``nu_cross`` (~N(0,1), cross positive = right of track),
        ``nis``, ``c_min_m_s2``, ``turn_rate_alg1_rad_s``, ``turn_rate_alg2_rad_s``, ``fma_innovation_m``,
        ``kim_lee_phi_m2_s4`` (raw eq 15, may be < 0), ``kim_lee_q2_m2_s4`` (eq 17 applied), ``speed_m_s``,
        ``heading_rad`` (posterior), ``range_m`` (posterior to site_xy), ``nu_along_fm``, ``nu_cross_fm``,
        ``nis_fm`` (fading-memory averages), and bool flags ``nu_valid`` (also for
        nis and c_min: at least one detection since reset), ``turn_rate_alg1_valid`` (n+2 plots),
        ``turn_rate_alg2_valid`` (n+1 headings), ``fma_valid``, ``kim_lee_valid``."""
        det = np.asarray(detected, dtype=bool).reshape(self.B)
        x_post = _f64(x_post)
        x_prior = _f64(x_prior)
        nu = _f64(nu)
        t = _f64(t_s)
        last = self.last
        out = {}

        # --- innovation features (held on misses)
        nac = normalized_innovation_along_cross(nu, S, x_prior[:, 2:4])
        last["nu_along"] = np.where(det, nac[:, 0], last["nu_along"])
        last["nu_cross"] = np.where(det, nac[:, 1], last["nu_cross"])
        last["nis"] = np.where(det, nis(nu, S), last["nis"])
        for key, sample in (("nu_along_fm", nac[:, 0]), ("nu_cross_fm", nac[:, 1]), ("nis_fm", last["nis"])):
            last[key] = np.where(det, fading_memory_average(last[key], sample, self.fm_weight), last[key])
        cm = c_min_m_s2(x_prev, bearing_rad, radial_velocity_m_s, dt_s, self.min_dt_s)
        last["c_min_m_s2"] = np.where(det, cm, last["c_min_m_s2"])
        self.n_detections = self.n_detections + det
        nu_valid = self.n_detections > 0

        # --- FMA of |nu|
        self.fma = np.where(det, fading_memory_average(self.fma, np.hypot(nu[:, 0], nu[:, 1]),
                                                       self.fma_weight), self.fma)
        last["fma_innovation_m"] = self.fma

        # --- Adrian algorithm 1 (plots)
        self._push_plot(det, _f64(z), t)
        L = self.n + 2
        r, i = self._rows, self.plot_idx  # i = oldest slot = plot k-1-n when full
        zk, zkm1 = self.plot_xy[r, (i - 1) % L], self.plot_xy[r, (i - 2) % L]
        zkmn, zkm1mn = self.plot_xy[r, (i + 1) % L], self.plot_xy[r, i]
        tk, tkm1 = self.plot_t[r, (i - 1) % L], self.plot_t[r, (i - 2) % L]
        tkmn, tkm1mn = self.plot_t[r, (i + 1) % L], self.plot_t[r, i]
        a1_ok = self.plot_count >= L
        a1 = _rate(adrian_heading_from_plots(zk, zkmn) - adrian_heading_from_plots(zkm1, zkm1mn),
                   adrian_mid_time_dt_s(tk, tkm1, tkmn, tkm1mn), self.min_dt_s)
        a1_new = det & a1_ok
        last["turn_rate_alg1_rad_s"] = np.where(a1_new, a1, last["turn_rate_alg1_rad_s"])
        self.last_valid["turn_rate_alg1"] = self.last_valid["turn_rate_alg1"] | a1_new

        # --- Adrian algorithm 2 (filtered headings, every update)
        h_post = heading_rad(x_post[:, 2], x_post[:, 3])
        self._push_heading(np.ones(self.B, dtype=bool), h_post, t)
        j = self.head_idx  # oldest slot = heading k-n when full
        a2_ok = self.head_count >= self.n + 1
        a2 = _rate(h_post - self.head[r, j], t - self.head_t[r, j], self.min_dt_s)
        out["turn_rate_alg2_rad_s"] = np.where(a2_ok, a2, 0.0)

        # --- Kim & Lee (window of detected innovations)
        k = self.outer_idx
        op = nu[:, :, None] * nu[:, None, :]
        self.outer[r, k] = np.where(det[:, None, None], op, self.outer[r, k])
        self.outer_idx = np.where(det, (k + 1) % self.N, k)
        self.outer_count = np.where(det, np.minimum(self.outer_count + 1, self.N), self.outer_count)
        cnt = self.outer_count
        S_hat = self.outer.sum(axis=1) / np.maximum(cnt, 1)[:, None, None]
        phi = kim_lee_phi_2d(S_hat, innovation_cov_without_process_noise(F, P_post_prev, R), dt_s, self.min_dt_s)
        kl_new = det & (cnt >= self.kim_lee_min_count)
        last["kim_lee_phi_m2_s4"] = np.where(kl_new, phi, last["kim_lee_phi_m2_s4"])
        last["kim_lee_q2_m2_s4"] = np.where(kl_new, kim_lee_variance(phi, self.sigma_D2), last["kim_lee_q2_m2_s4"])
        self.last_valid["kim_lee"] = self.last_valid["kim_lee"] | kl_new

        for key, v in last.items():
            out[key] = v.copy()
        out["speed_m_s"] = np.hypot(x_post[:, 2], x_post[:, 3])
        out["heading_rad"] = h_post
        site = np.broadcast_to(_f64(site_xy), (self.B, 2))
        out["range_m"] = np.hypot(x_post[:, 0] - site[:, 0], x_post[:, 1] - site[:, 1])
        out["nu_valid"] = nu_valid
        out["fma_valid"] = nu_valid.copy()
        out["turn_rate_alg1_valid"] = self.last_valid["turn_rate_alg1"].copy()
        out["turn_rate_alg2_valid"] = a2_ok
        out["kim_lee_valid"] = self.last_valid["kim_lee"].copy()
        return out
