"""Real aircraft trajectories from ADS-B: loading, cleaning, projection and smoothing.

The shipped data set (``radar_env/data/adsb/*.csv.gz``, see ``ATTRIBUTION.md`` there) holds 24 navaid-calibration
flights recorded by the OpenSky Network and distributed with the ``traffic`` library (MIT). They contain orbits,
procedure turns and approaches, sampled every 5 s (``nice``: 10 s). ``scripts/convert_traffic_samples.py`` made them.

File format (gzip-compressed or plain CSV, header required, extra columns ignored)::

    t_s,lat_deg,lon_deg,alt_m,groundspeed_m_s,track_deg

``t_s`` in seconds (any origin, e.g. the Unix epoch), WGS84 latitude/longitude in degrees, track in degrees
clockwise from north. ``lat_deg``/``lon_deg`` may be empty (missing position); ``alt_m``, ``groundspeed_m_s`` and
``track_deg`` may be empty too.

Pipeline (:func:`load_trajectory`): :func:`load_raw` -> :func:`clean` (drop missing and stale positions, check time,
optionally drop slow rows) -> :func:`split_segments` (at gaps and drop short pieces) -> :func:`project_local_en`
(local tangent plane) -> :func:`smooth_segment` (smoothing spline per axis, velocity from its derivative, regular
grid) -> :class:`AdsbTrajectory`, whose arrays feed :class:`radar_env.sim.scenario.TrajectoryScenario`.

Measured on the shipped flights (longest segment, defaults; spline velocity vs reported values at the raw
times): RMS speed difference 2.8-12.6 m/s per flight (liege_sprimont 3.6, brussels_vor 2.8, munich 6.5,
kota_kinabalu 12.6); RMS vector difference against ground speed + track 8-38 m/s. The second is larger because the
reported track in these samples is often offset from the course flown by tens of degrees over a few rows (it looks
sampled at other instants than the positions), and 22 files needed an 8-bit wrap repair of the track (see the
conversion script). Velocities are therefore built from positions only.

Runtime dependencies: stdlib, numpy, scipy.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import UnivariateSpline

__all__ = [
    "DATA_DIR",
    "COLUMNS",
    "RawFlight",
    "Piece",
    "AdsbTrajectory",
    "list_flights",
    "flight_path",
    "load_raw",
    "clean",
    "split_segments",
    "project_local_en",
    "smooth_segment",
    "velocity_check",
    "load_trajectory",
    "place_radar",
]

DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "adsb"
"""Folder of the shipped flights."""

COLUMNS = ("t_s", "lat_deg", "lon_deg", "alt_m", "groundspeed_m_s", "track_deg")
SWAP_CHECK_RMS_M_S = 8.0
"""Speed-check RMS (m/s) above which :func:`load_trajectory` also tries the file with latitude and longitude
exchanged."""
SWAP_RATIO = 1.2
"""Factor by which the exchanged columns must fit the reported ground speed better for the file to be refused."""
WARN_SPEED_RMS_M_S = 20.0
"""Speed-check RMS (m/s) above which a flight loads with a warning (the shipped flights: at most 12.6)."""
REQUIRED_COLUMNS = ("t_s", "lat_deg", "lon_deg")

# WGS84
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)


# ------------------------------------------------------------------------------------------------------ reading
@dataclass(frozen=True)
class RawFlight:
    """The columns of one flight file as float64 arrays (NaN where a cell is empty).

    Attributes
    ----------
    t_s, lat_deg, lon_deg, alt_m, groundspeed_m_s, track_deg : numpy.ndarray
        One value per row, in file order. Optional columns absent from the file are all NaN.
    source : str
        File path (used in error messages).
    """

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    groundspeed_m_s: np.ndarray
    track_deg: np.ndarray
    source: str

    def __len__(self):
        return int(self.t_s.size)

    def take(self, idx):
        """Rows ``idx`` (index array or boolean mask) as a new :class:`RawFlight`."""
        return RawFlight(*(getattr(self, c)[idx] for c in COLUMNS), source=self.source)


def list_flights(data_dir=None):
    """Ids of the flights available in the shipped data set (or in ``data_dir``).

    Parameters
    ----------
    data_dir : str or Path, optional
        Folder to list instead of :data:`DATA_DIR`.

    Returns
    -------
    list of str
        Sorted file stems of the ``*.csv.gz`` / ``*.csv`` files, e.g. ``"ajaccio"``.
    """
    d = Path(data_dir) if data_dir is not None else DATA_DIR
    ids = {p.name[: -len(".csv.gz")] for p in d.glob("*.csv.gz")}
    ids |= {p.stem for p in d.glob("*.csv")}
    return sorted(ids)


def flight_path(flight):
    """Path of a flight given its id (shipped data set) or a path to a file."""
    p = Path(flight)
    if p.suffix in (".gz", ".csv") or p.is_file():
        return p
    for cand in (DATA_DIR / f"{flight}.csv.gz", DATA_DIR / f"{flight}.csv"):
        if cand.is_file():
            return cand
    raise ValueError(f"unknown ADS-B flight {str(flight)!r}: not a file and not one of the shipped flights "
                     f"{list_flights()}")


def _read_text(path):
    """The text of a flight file (gzip-compressed if its name ends in ``.gz``, UTF-8 / ASCII); ``ValueError`` naming
    the file and the reason for a truncated or corrupt gzip stream, a file that is not gzip, or bytes that are not
    text."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ValueError(f"{path}: cannot read ({e.strerror or e})") from None
    if path.name.endswith(".gz"):
        try:
            raw = gzip.decompress(raw)
        except EOFError:
            raise ValueError(f"{path}: truncated gzip file (the compressed stream ends early); copy or download it "
                             "again") from None
        except (gzip.BadGzipFile, zlib.error, OSError) as e:
            raise ValueError(f"{path}: not a readable gzip file ({e}); a plain CSV must not end in '.gz'") from None
    from .scenario import decode_utf8
    return decode_utf8(raw, path)


def load_raw(flight):
    """Read a flight file into float64 arrays, without cleaning.

    Parameters
    ----------
    flight : str or Path
        A shipped flight id (see :func:`list_flights`) or a path to a ``.csv`` / ``.csv.gz`` file.

    Returns
    -------
    RawFlight

    Raises
    ------
    ValueError
        Unknown flight, empty file, missing required column (``t_s``, ``lat_deg``, ``lon_deg``) or a cell that is
        not a number; the message names the file, line and column.
    """
    path = flight_path(flight)
    if not path.is_file():
        raise ValueError(f"ADS-B file {str(path)!r} does not exist")
    text = _read_text(path)
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ValueError(f"{path}: empty file; expected header {','.join(COLUMNS)}") from None
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: line 1: missing column(s) {missing}; expected header {','.join(COLUMNS)}")
    pos = {c: header.index(c) for c in COLUMNS if c in header}
    cols = {c: [] for c in COLUMNS}
    for line_no, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        for c in COLUMNS:
            j = pos.get(c)
            cell = row[j].strip() if j is not None and j < len(row) else ""
            if cell == "" or cell.lower() == "nan":
                if c == "t_s":
                    raise ValueError(f"{path}: line {line_no}: empty t_s")
                cols[c].append(math.nan)
                continue
            try:
                cols[c].append(float(cell))
            except ValueError:
                raise ValueError(f"{path}: line {line_no}, column {c!r}: cannot read {cell!r} as a number") from None
    arrays = {c: np.asarray(v, dtype=np.float64) for c, v in cols.items()}
    if arrays["t_s"].size == 0:
        raise ValueError(f"{path}: no data rows")
    return RawFlight(**arrays, source=str(path))


# ----------------------------------------------------------------------------------------------------- cleaning
def clean(raw, min_groundspeed_m_s=None):
    """Remove unusable rows and check the time column.

    Steps, in order:

    1. rows whose ``t_s`` is not finite raise; time must be strictly increasing over the file (checked on all
       rows, before anything is dropped), else ``ValueError`` naming the file and the (1-based data) row;
    2. rows with a missing (NaN) or out-of-range latitude/longitude are dropped;
    3. stale repeats are dropped: a row whose latitude and longitude both equal those of the previous kept row
       (a receiver repeating its last position while time advances);
    4. if ``min_groundspeed_m_s`` is given, rows whose reported ground speed is below it are dropped (taxiing,
       parked); rows with a missing ground speed are kept.

    Parameters
    ----------
    raw : RawFlight
    min_groundspeed_m_s : float, optional

    Returns
    -------
    RawFlight
        The kept rows (may be empty).
    """
    t = raw.t_s
    if not np.all(np.isfinite(t)):
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(f"{raw.source}: data row {i + 1}: t_s is not finite ({t[i]})")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise ValueError(f"{raw.source}: time must be strictly increasing; data row {i + 2} (t_s={t[i + 1]:.3f}) "
                         f"does not follow data row {i + 1} (t_s={t[i]:.3f})")
    lat, lon = raw.lat_deg, raw.lon_deg
    ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0) & (np.abs(lon) <= 360.0)
    kept = raw.take(ok)
    if len(kept) > 1:
        same = (np.diff(kept.lat_deg) == 0.0) & (np.diff(kept.lon_deg) == 0.0)
        # "previous kept row": a run of repeats all equal the first row of the run, so comparing neighbours is enough
        kept = kept.take(np.concatenate([[True], ~same]))
    if min_groundspeed_m_s is not None:
        gs = kept.groundspeed_m_s
        kept = kept.take(~(gs < float(min_groundspeed_m_s)))  # NaN compares False: kept
    return kept


@dataclass(frozen=True)
class Piece:
    """A continuous run of cleaned rows: ``rows`` is a :class:`RawFlight`, ``index`` its order in the flight."""

    rows: RawFlight
    index: int

    @property
    def duration_s(self):
        return float(self.rows.t_s[-1] - self.rows.t_s[0])


def split_segments(flight, max_gap_s=20.0, min_duration_s=120.0, min_points=8):
    """Split cleaned rows into continuous segments.

    A new segment starts wherever two consecutive rows are more than ``max_gap_s`` apart. Pieces shorter than
    ``min_duration_s`` or with fewer than ``min_points`` rows are rejected.

    Parameters
    ----------
    flight : RawFlight
        Output of :func:`clean`.
    max_gap_s, min_duration_s : float
    min_points : int
        At least 4 are needed by the cubic smoothing spline.

    Returns
    -------
    kept : list of Piece
        Segments long enough, in time order, numbered 0, 1, ... in that order.
    rejected : list of str
        One message per rejected piece (start/end time, duration, rows and the reason).
    """
    t = flight.t_s
    if t.size == 0:
        return [], [f"{flight.source}: no rows left after cleaning"]
    cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    bounds = np.concatenate([[0], cuts, [t.size]])
    kept, rejected = [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        dur = float(t[b - 1] - t[a])
        n = int(b - a)
        if dur < min_duration_s or n < max(min_points, 4):
            rejected.append(f"{flight.source}: piece t_s=[{t[a]:.0f}, {t[b - 1]:.0f}] ({dur:.0f} s, {n} rows) "
                            f"rejected: shorter than min_duration_s={min_duration_s:g} s or fewer than "
                            f"{max(min_points, 4)} rows")
            continue
        kept.append(Piece(flight.take(np.arange(a, b)), len(kept)))
    return kept, rejected


# --------------------------------------------------------------------------------------------------- projection
def _ecef(lat_rad, lon_rad):
    s = np.sin(lat_rad)
    n = _WGS84_A_M / np.sqrt(1.0 - _WGS84_E2 * s * s)
    c = np.cos(lat_rad)
    return n * c * np.cos(lon_rad), n * c * np.sin(lon_rad), n * (1.0 - _WGS84_E2) * s


def project_local_en(lat_deg, lon_deg, lat0_deg, lon0_deg):
    """Project WGS84 positions onto the local tangent plane (east, north) at a reference point.

    Local tangent plane ("ENU" without the up component) on the WGS84 ellipsoid: each point at zero ellipsoidal
    height is converted to Earth-centred Earth-fixed coordinates, and ``x_m``/``y_m`` are the components of its offset
    from the reference point along the local east/north unit vectors. This is exact geometry (an orthographic
    projection onto the tangent plane), so a point at true ground distance ``d`` from the reference appears at
    ``~R sin(d/R)``: it is shortened by ``~d^3 / (6 R^2)``, about 0.3 m at 50 km, 2.6 m at 100 km and 33 m (0.017 %)
    at 200 km (R ~ 6371 km); directions from the reference are preserved. The point also lies ``~d^2/(2R)`` below
    the plane (3.1 km at 200 km), which is ignored in this 2-D frame. Altitude is not used.

    Parameters
    ----------
    lat_deg, lon_deg : array_like
        Positions (degrees).
    lat0_deg, lon0_deg : float
        Reference point, mapped to (0, 0).

    Returns
    -------
    x_m, y_m : numpy.ndarray
        East and north coordinates (metres), x east, y north.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    la0, lo0 = math.radians(float(lat0_deg)), math.radians(float(lon0_deg))
    X, Y, Z = _ecef(lat, lon)
    X0, Y0, Z0 = _ecef(np.float64(la0), np.float64(lo0))
    dX, dY, dZ = X - X0, Y - Y0, Z - Z0
    sl, cl = math.sin(la0), math.cos(la0)
    so, co = math.sin(lo0), math.cos(lo0)
    x = -so * dX + co * dY
    y = -sl * co * dX - sl * so * dY + cl * dZ
    return x, y


# ---------------------------------------------------------------------------------------------------- smoothing
def smooth_segment(t_s, x_m, y_m, dt_s=1.0, position_noise_m=100.0):
    """Smooth one segment with a cubic smoothing spline per axis and sample it on a regular grid.

    Each axis is fitted with ``scipy.interpolate.UnivariateSpline(t, p, k=3, s=n * position_noise_m**2)``: the
    smoothest cubic spline whose residual sum of squares is at most ``n * sigma^2`` (``n`` = number of samples),
    i.e. residuals of about ``position_noise_m`` RMS. Velocity is the spline's first derivative.

    Parameters
    ----------
    t_s, x_m, y_m : array_like
        Strictly increasing times and positions (>= 4 samples).
    dt_s : float
        Output grid step; the grid is ``t_s[0] + k * dt_s`` up to ``t_s[-1]``.
    position_noise_m : float
        Assumed per-axis position error (metres); larger means smoother. The default 100 m is far above the
        ADS-B position accuracy (~10 m) because the shipped 5-s samples carry timing jitter: positions were
        resampled onto the 5-s grid from irregular reports, so consecutive displacements jump (e.g. 340 m,
        1000 m, 530 m in 5-s steps at a reported 100 m/s), an along-track error of order speed x 1-3 s. Over
        the shipped flights 100 m gave the smallest RMS difference between spline speed and reported ground
        speed (15 m: 7-22 m/s, 50 m: 2-18 m/s, 100 m: 3-18 m/s, 250 m: 7-18 m/s) while keeping orbits of
        ~2 km radius (accelerations stay below ~1 g).

    Returns
    -------
    t_s, x_m, y_m, vx_m_s, vy_m_s : numpy.ndarray
        On the grid; ``t_s`` keeps the input origin.
    splines : tuple of UnivariateSpline
        The ``(x, y)`` splines, e.g. to evaluate at the raw times.
    """
    t = np.asarray(t_s, dtype=np.float64)
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    if t.size < 4:
        raise ValueError(f"smoothing needs at least 4 samples, got {t.size}")
    if not dt_s > 0:
        raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
    s = t.size * float(position_noise_m) ** 2
    sx = UnivariateSpline(t, x, k=3, s=s)
    sy = UnivariateSpline(t, y, k=3, s=s)
    n = int(math.floor((t[-1] - t[0]) / dt_s + 1e-9)) + 1
    tg = t[0] + dt_s * np.arange(n)
    return (tg, sx(tg), sy(tg), sx.derivative()(tg), sy.derivative()(tg)), (sx, sy)


def velocity_check(rows, splines, t0_s=0.0):
    """Compare the spline velocity with the reported ground speed and track at the raw sample times.

    Parameters
    ----------
    rows : RawFlight
        The segment's rows (times in the file's origin).
    splines : tuple
        ``(sx, sy)`` from :func:`smooth_segment`, fitted on ``rows.t_s - t0_s``.
    t0_s : float
        Time origin subtracted before evaluating the splines.

    Returns
    -------
    dict
        ``speed_rms_m_s``: RMS of (spline speed - reported ground speed); ``velocity_rms_m_s``: RMS norm of the
        vector difference between the spline velocity and the velocity built from the reported ground speed and
        track; ``n``: rows with both reported; NaN values if none.
    """
    sx, sy = splines
    t = rows.t_s - t0_s
    vx, vy = sx.derivative()(t), sy.derivative()(t)
    gs, tr = rows.groundspeed_m_s, np.radians(rows.track_deg)
    ok = np.isfinite(gs) & np.isfinite(tr)
    if not ok.any():
        return {"speed_rms_m_s": math.nan, "velocity_rms_m_s": math.nan, "n": 0}
    sp = np.hypot(vx[ok], vy[ok])
    rvx, rvy = gs[ok] * np.sin(tr[ok]), gs[ok] * np.cos(tr[ok])
    return {
        "speed_rms_m_s": float(np.sqrt(np.mean((sp - gs[ok]) ** 2))),
        "velocity_rms_m_s": float(np.sqrt(np.mean((vx[ok] - rvx) ** 2 + (vy[ok] - rvy) ** 2))),
        "n": int(ok.sum()),
    }


class _Shifted:
    """A spline evaluated with its time axis shifted by ``shift_s`` (``f(t + shift_s)``)."""

    def __init__(self, spline, shift_s):
        self.spline, self.shift_s = spline, shift_s

    def __call__(self, t):
        return self.spline(np.asarray(t) + self.shift_s)

    def derivative(self):
        return _Shifted(self.spline.derivative(), self.shift_s)


# ------------------------------------------------------------------------------------------------- trajectories
@dataclass(frozen=True)
class AdsbTrajectory:
    """A smoothed ADS-B segment on a regular grid, in the project's local frame.

    Attributes
    ----------
    t_s, x_m, y_m, vx_m_s, vy_m_s : numpy.ndarray
        Samples (``t_s`` starts at 0, step ``dt_s``); x east, y north, metres, m/s. Pass them to
        ``TrajectoryScenario(t.t_s, t.x_m, t.y_m, t.vx_m_s, t.vy_m_s)`` or use :meth:`as_array`.
    flight_id : str
    segment : int
        Index of the segment among the flight's kept segments.
    lat0_deg, lon0_deg : float
        Reference point of the projection (centre of the segment's latitude/longitude bounding box).
    t0_s : float
        Time of the first sample in the file's time origin (Unix epoch for the shipped files).
    check : dict
        :func:`velocity_check` result (RMS differences against reported ground speed/track).
    n_segments : int
        Number of kept segments in the flight.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_m_s: np.ndarray
    vy_m_s: np.ndarray
    flight_id: str
    segment: int
    lat0_deg: float
    lon0_deg: float
    t0_s: float
    check: dict
    n_segments: int

    @property
    def duration_s(self):
        return float(self.t_s[-1])

    def as_array(self):
        """``(N, 5)`` array with columns ``t_s, x_m, y_m, vx_m_s, vy_m_s``."""
        return np.column_stack([self.t_s, self.x_m, self.y_m, self.vx_m_s, self.vy_m_s])

    def to_scenario(self, **kwargs):
        """A :class:`radar_env.sim.scenario.TrajectoryScenario` from these samples (name ``adsb:<id>:<segment>``)."""
        from .scenario import TrajectoryScenario

        kwargs.setdefault("name", f"adsb:{self.flight_id}:{self.segment}")
        return TrajectoryScenario(self.t_s, self.x_m, self.y_m, self.vx_m_s, self.vy_m_s, **kwargs)


def load_trajectory(flight, segment="longest", *, dt_s=1.0, max_gap_s=20.0, min_duration_s=120.0,
                    min_groundspeed_m_s=30.0, position_noise_m=100.0, min_speed_m_s=30.0):
    """Load, clean, split, project and smooth one flight segment.

    Parameters
    ----------
    flight : str or Path
        Shipped flight id (:func:`list_flights`) or path to a file in the same format.
    segment : "longest" or int
        Which kept segment (see :func:`split_segments`).
    dt_s : float
        Output grid step (s).
    max_gap_s, min_duration_s : float
        Segmenting (see :func:`split_segments`).
    min_groundspeed_m_s : float or None
        Rows with a reported ground speed below this are dropped before segmenting (removes taxiing and parked
        parts, which the calibration flights start and end with); ``None`` keeps them.
    position_noise_m : float
        Smoothing (see :func:`smooth_segment`).
    min_speed_m_s : float
        If the smoothed speed drops below this anywhere, only the longest run of grid samples at or above it is
        kept (re-zeroed to start at ``t_s = 0``; ``t0_s`` moves accordingly); ValueError if that run is shorter
        than ``min_duration_s``. ``TrajectoryScenario`` needs >= 10 m/s; the default 30 m/s also cuts take-off
        and landing rolls and the rare spline dips at data glitches.

    Returns
    -------
    AdsbTrajectory

    Raises
    ------
    ValueError
        Bad file (see :func:`load_raw`, :func:`clean`), no segment long enough (the message lists the rejected
        pieces), a segment index out of range, a smoothed speed below ``min_speed_m_s``, or latitude and longitude
        swapped: where the speed from the positions differs from the reported ground speed by more than
        ``SWAP_CHECK_RMS_M_S`` RMS (:func:`velocity_check`), the segment is rebuilt with the two columns exchanged,
        and if that fits better by ``SWAP_RATIO`` (1.2x) the file is refused (the shipped flights: 2.8-12.6 m/s as
        given, 1.4-15x worse exchanged; exchanged files: 8-104 m/s). A disagreement above ``WARN_SPEED_RMS_M_S``
        that exchanging does not explain is a warning.
    """
    path = flight_path(flight)
    flight_id = path.name[: -len(".csv.gz")] if path.name.endswith(".csv.gz") else path.stem
    raw = load_raw(path)
    kw = dict(dt_s=dt_s, max_gap_s=max_gap_s, min_duration_s=min_duration_s, min_groundspeed_m_s=min_groundspeed_m_s,
              position_noise_m=position_noise_m, min_speed_m_s=min_speed_m_s)
    traj = _trajectory_from_raw(raw, path, flight_id, segment, **kw)
    rms = traj.check["speed_rms_m_s"]
    if traj.check["n"] and rms > SWAP_CHECK_RMS_M_S:
        swapped = raw.take(np.arange(len(raw)))
        object.__setattr__(swapped, "lat_deg", raw.lon_deg)
        object.__setattr__(swapped, "lon_deg", raw.lat_deg)
        try:
            rms_swapped = _trajectory_from_raw(swapped, path, flight_id, segment, **kw).check["speed_rms_m_s"]
        except ValueError:
            rms_swapped = math.inf
        if rms_swapped * SWAP_RATIO < rms:
            raise ValueError(f"{path}: lat_deg and lon_deg look swapped: the speed from the positions differs from "
                             f"the reported ground speed by {rms:.1f} m/s RMS as given and by {rms_swapped:.1f} m/s "
                             "with the two columns exchanged; exchange them in the file")
        if rms > WARN_SPEED_RMS_M_S:
            warnings.warn(f"{path}: the speed from the positions differs from the reported ground speed by "
                          f"{rms:.1f} m/s RMS (the shipped flights: 2.8-12.6 m/s): a time or position problem in "
                          "the file?", UserWarning, stacklevel=2)
    return traj


def _trajectory_from_raw(raw, path, flight_id, segment, *, dt_s, max_gap_s, min_duration_s, min_groundspeed_m_s,
                         position_noise_m, min_speed_m_s):
    """:func:`load_trajectory`'s pipeline on the rows of one file (without the swapped-columns check)."""
    rows = clean(raw, min_groundspeed_m_s=min_groundspeed_m_s)
    pieces, rejected = split_segments(rows, max_gap_s=max_gap_s, min_duration_s=min_duration_s)
    if not pieces:
        why = "; ".join(rejected[:5]) + (" ..." if len(rejected) > 5 else "")
        n_bad_lat = int(np.sum(np.abs(raw.lat_deg) > 90.0))
        hint = (f"; {n_bad_lat} rows have |lat_deg| > 90: latitude and longitude swapped?" if n_bad_lat else "")
        raise ValueError(f"{path}: no segment of at least {min_duration_s:g} s after cleaning "
                         f"({len(raw)} rows read, {len(rows)} kept){hint}: {why}")
    if isinstance(segment, str):
        if segment != "longest":
            raise ValueError(f"segment must be 'longest' or an int, got {segment!r}")
        piece = max(pieces, key=lambda p: p.duration_s)
    else:
        k = int(segment)
        if not 0 <= k < len(pieces):
            durs = [round(p.duration_s) for p in pieces]
            raise ValueError(f"{path}: segment {k} out of range; {len(pieces)} segment(s) with durations {durs} s")
        piece = pieces[k]
    r = piece.rows
    lat0 = 0.5 * (float(r.lat_deg.min()) + float(r.lat_deg.max()))
    lon_u = np.degrees(np.unwrap(np.radians(r.lon_deg)))
    lon0 = 0.5 * (float(lon_u.min()) + float(lon_u.max()))
    x, y = project_local_en(r.lat_deg, r.lon_deg, lat0, lon0)
    t0 = t0_raw = float(r.t_s[0])
    (tg, xg, yg, vx, vy), splines = smooth_segment(r.t_s - t0, x, y, dt_s=dt_s, position_noise_m=position_noise_m)
    speed = np.hypot(vx, vy)
    if speed.min() < min_speed_m_s:
        # keep the longest run of grid samples whose smoothed speed is >= min_speed_m_s
        ok = np.concatenate([[False], speed >= min_speed_m_s, [False]])
        edges = np.flatnonzero(np.diff(ok.astype(np.int8)))
        starts, ends = edges[0::2], edges[1::2]
        if starts.size == 0:
            raise ValueError(f"{path}: segment {piece.index}: smoothed speed never reaches min_speed_m_s="
                             f"{min_speed_m_s:g} m/s")
        k = int(np.argmax(ends - starts))
        a, b = int(starts[k]), int(ends[k])
        if tg[b - 1] - tg[a] < min_duration_s:
            i = int(np.argmin(speed))
            raise ValueError(f"{path}: segment {piece.index}: smoothed speed {speed[i]:.2f} m/s at t={tg[i]:.0f} s "
                             f"is below min_speed_m_s={min_speed_m_s:g} and the longest part above it lasts only "
                             f"{tg[b - 1] - tg[a]:.0f} s (< min_duration_s={min_duration_s:g})")
        t0 = t0 + float(tg[a])
        tg, xg, yg, vx, vy = (tg[a:b] - tg[a], xg[a:b], yg[a:b], vx[a:b], vy[a:b])
        keep = (r.t_s >= t0) & (r.t_s <= t0 + tg[-1])
        r = r.take(keep)
        splines = tuple(_Shifted(sp_, t0 - t0_raw) for sp_ in splines)
    chk = velocity_check(r, splines, t0_s=t0)
    lon0 = (lon0 + 180.0) % 360.0 - 180.0
    return AdsbTrajectory(tg, xg, yg, vx, vy, flight_id=flight_id, segment=piece.index, lat0_deg=lat0,
                          lon0_deg=lon0, t0_s=t0, check=chk, n_segments=len(pieces))


# ------------------------------------------------------------------------------------------------------- radar
def place_radar(traj, rng=None, min_range_m=20e3, bearing_deg=225.0):
    """Place one radar site for a trajectory, deterministically unless ``rng`` is given.

    Rule: let ``c`` be the centre of the bounding box of the trajectory's positions and ``r_ext`` the largest
    distance of a position from ``c``. The site is put at distance ``D = r_ext + min_range_m`` from ``c`` in the
    direction ``bearing_deg`` (clockwise from north; default 225 deg, i.e. south-west of the flight), or in a
    direction drawn uniformly from ``rng`` when one is passed. By the triangle inequality every range then lies in
    ``[min_range_m, 2 r_ext + min_range_m]``. With the default 20 km, 22 of the 24 shipped flights (longest segment)
    stay within 20-141 km; ``ajaccio`` (45-235 km) and ``vancouver`` (114-387 km) are too large for that: the rule
    guarantees the minimum range, not a maximum. Cut long
    flights (or use :func:`radar_env.sim.scenario.place_radar_site`) if a maximum range must hold.

    Parameters
    ----------
    traj : AdsbTrajectory or array_like
        An :class:`AdsbTrajectory`, or an ``(N, 2)`` array of x, y positions (m).
    rng : numpy.random.Generator, optional
        If given, one ``rng.uniform(0, 2 pi)`` draw sets the direction.
    min_range_m : float
        Smallest range from the site to the flight.
    bearing_deg : float
        Direction from the flight's centre to the site when ``rng`` is None.

    Returns
    -------
    numpy.ndarray
        Site position ``(2,)`` ``[x_m, y_m]``.
    """
    if isinstance(traj, AdsbTrajectory):
        x, y = traj.x_m, traj.y_m
    else:
        a = np.asarray(traj, dtype=np.float64)
        x, y = a[:, 0], a[:, 1]
    cx = 0.5 * (x.min() + x.max())
    cy = 0.5 * (y.min() + y.max())
    r_ext = float(np.max(np.hypot(x - cx, y - cy)))
    ang = float(rng.uniform(0.0, 2.0 * np.pi)) if rng is not None else math.radians(bearing_deg)
    d = r_ext + float(min_range_m)
    return np.array([cx + d * math.sin(ang), cy + d * math.cos(ang)])
