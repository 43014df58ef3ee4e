"""Per-scan maneuver features for the 4-state CV Kalman filter (float64, batched, no RNG).

Conventions (docs/architecture.md): SI units, x east / y north, state ``[x, y, vx, vy]``, ``H = [I2 0]``,
heading and bearing clockwise from north (``atan2(east, north)``), radial velocity positive when receding,
turn rate positive = clockwise = right turn. Every array has the batch axis first.

Two layers:

* pure formula functions (``wrap_angle``, ``nis``, ``c_min_m_s2``, ``kim_lee_phi_2d`` ...), each valid for any
  batch size, returning finite values for every finite input (the fallbacks are documented per function);
* :class:`FeatureBank`, a stateful batched bank holding the ring buffers the history-based features need
  (Adrian's turn-rate algorithms 1 and 2, Kim & Lee's sliding innovation window, Bizup's CKF fading-memory
  average). Its ``update`` is one compiled kernel call (:mod:`radar_env.filters.kernels`, the per-row code that the
  fused :meth:`radar_env.filters.tracking.Tracker.step` kernel runs too).

The formula functions are plain numpy: they are the readable reference of the kernels' per-row code (tests check
the bank against them) and are used by the paper checks and baselines (``wrap_angle``, ``kim_lee_variance``).

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

from . import kernels as _k

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


_HELD = _k.BANK_HELD[:-1]


class FeatureBank:
    """Batched per-track feature state (B rows), updated once per scan by :meth:`update`.

    Buffers (views into three packed per-row arrays ``_f`` (float), ``_i`` (int), ``_b`` (bool) that the kernels
    update in place; one ring-buffer write index per row):

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
        self._par = np.zeros(_k.W_PAR)
        self._par[[_k.PAR_N, _k.PAR_NKL, _k.PAR_KLMIN, _k.PAR_FMA_W, _k.PAR_FM_W, _k.PAR_SD2, _k.PAR_MIN_DT]] = (
            self.n, self.N, self.kim_lee_min_count, self.fma_weight, self.fm_weight, self.sigma_D2, self.min_dt_s)
        self._off = _k.bank_offsets(self.n, self.N)
        self._rows = np.arange(self.B)
        self._f = np.zeros((self.B, self._off[-1]))
        self._i = np.zeros((self.B, _k.W_BANK_I), dtype=np.int64)
        self._b = np.zeros((self.B, _k.W_BANK_B), dtype=bool)

    # ------------------------------------------------------------------ views of the packed state
    def _fcols(self, j, shape):
        a, b = self._off[j], self._off[j + 1]
        return self._f[:, a:b].reshape((self.B,) + shape)

    plot_xy = property(lambda s: s._fcols(0, (s.n + 2, 2)))
    plot_t = property(lambda s: s._fcols(1, (s.n + 2,)))
    head = property(lambda s: s._fcols(2, (s.n + 1,)))
    head_t = property(lambda s: s._fcols(3, (s.n + 1,)))
    outer = property(lambda s: s._fcols(4, (s.N, 2, 2)))
    fma = property(lambda s: s._f[:, s._off[5]])
    plot_idx = property(lambda s: s._i[:, _k.BI_PIDX])
    plot_count = property(lambda s: s._i[:, _k.BI_PCNT])
    head_idx = property(lambda s: s._i[:, _k.BI_HIDX])
    head_count = property(lambda s: s._i[:, _k.BI_HCNT])
    outer_idx = property(lambda s: s._i[:, _k.BI_OIDX])
    outer_count = property(lambda s: s._i[:, _k.BI_OCNT])
    n_detections = property(lambda s: s._i[:, _k.BI_NDET])

    @property
    def last(self):
        """Held feature values, name -> (B,) view."""
        o = self._off[6]
        return {k: self._f[:, o + j] for j, k in enumerate(_k.BANK_HELD)}

    @property
    def last_valid(self):
        """Validity flags of the held features, name -> (B,) view."""
        return {"nu": self._b[:, _k.BB_NU], "turn_rate_alg1": self._b[:, _k.BB_A1], "kim_lee": self._b[:, _k.BB_KL]}

    # ------------------------------------------------------------------ row subsets
    _ROW_ARRAYS = ("_f", "_i", "_b")
    _ROW_DICTS = ()

    def take_rows(self, rows):
        """A new bank holding copies of rows ``rows`` (index array) of this one, same parameters."""
        rows = np.asarray(rows, dtype=np.int64)
        sub = object.__new__(type(self))
        sub.__dict__.update({k: v for k, v in vars(self).items() if k not in self._ROW_ARRAYS})
        sub.B, sub._rows = int(rows.size), np.arange(rows.size)
        for name in self._ROW_ARRAYS:
            setattr(sub, name, getattr(self, name)[rows])
        return sub

    def put_rows(self, rows, other):
        """Write all rows of bank ``other`` into rows ``rows`` of this one."""
        rows = np.asarray(rows, dtype=np.int64)
        for name in self._ROW_ARRAYS:
            getattr(self, name)[rows] = getattr(other, name)

    # ------------------------------------------------------------------ reset
    def reset(self, mask=None, plots_xy=None, plot_times_s=None, x=None, t_s=None):
        """Re-initialise rows where ``mask`` (B,) is True (all rows if None); other rows are untouched.

        Optional seeding, e.g. from a two-hit track start: ``plots_xy`` (B, m, 2) and ``plot_times_s`` (B, m),
        oldest first, are pushed into the plot buffer (only the last n+2 kept); ``x`` (B,4) and ``t_s`` (B,)
        push the heading of the initial estimate into the algorithm-2 buffer. Only masked rows are read."""
        m = np.ones(self.B, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(self.B)
        rows = np.flatnonzero(m)
        if plots_xy is None:
            pz, pt = np.zeros((rows.size, 0, 2)), np.zeros((rows.size, 0))
        else:
            pz = _k.c_array(_f64(plots_xy)[rows])
            pt = _k.c_array(_f64(plot_times_s)[rows])
        if x is None:
            xs, ts = np.zeros((rows.size, 4)), np.zeros(rows.size)
        else:
            xs = _k.c_array(_f64(x)[rows])
            ts = _k.c_array(np.broadcast_to(_f64(t_s), (self.B,))[rows])
        _k.k_bank_reset(rows, self._f, self._i, self._b, self.n, pz, pt, pz.shape[1], xs, ts, x is not None)

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
        B = self.B

        def arr(a, tail):
            return _k.c_array(np.broadcast_to(_f64(a), (B,) + tail))

        det = _k.c_array(np.broadcast_to(np.asarray(detected, dtype=bool).reshape(-1), (B,)))
        of = np.empty((B, _k.W_BANK_OUT))
        ob = np.empty((B, _k.W_BANK_OUTB), dtype=bool)
        _k.k_bank_update(self._f, self._i, self._b, self._par, arr(x_prev, (4,)), arr(x_prior, (4,)),
                         arr(P_post_prev, (4, 4)), arr(F, (4, 4)), arr(R, (2, 2)), arr(nu, (2,)), arr(S, (2, 2)),
                         arr(x_post, (4,)), arr(z, (2,)), arr(t_s, ()), arr(dt_s, ()), arr(bearing_rad, ()),
                         arr(radial_velocity_m_s, ()), det, arr(site_xy, (2,)), of, ob)
        return bank_outputs(of, ob)


def bank_outputs(of, ob):
    """The feature dict of :meth:`FeatureBank.update` from the kernel's output blocks ``of (n, W_BANK_OUT)`` and
    ``ob (n, W_BANK_OUTB)`` (column views, no copies)."""
    out = {"turn_rate_alg2_rad_s": of[:, _k.FB_A2]}
    out.update(zip(_k.BANK_HELD, of[:, _k.FB_HELD:_k.FB_HELD + _k.N_HELD].T))
    out["speed_m_s"], out["heading_rad"], out["range_m"] = of[:, _k.FB_SPEED], of[:, _k.FB_HEAD], of[:, _k.FB_RANGE]
    out.update(zip(_k.BANK_FLAG_KEYS, ob.T))
    return out
