"""ADS-B loader: file checks, cleaning, segmenting, projection, smoothing, radar placement, shipped flights."""

import gzip
import math

import numpy as np
import pytest

from radar_env.sim import adsb

HEADER = "t_s,lat_deg,lon_deg,alt_m,groundspeed_m_s,track_deg"
R_EARTH_M = 6371008.8


def write_flight(path, t, lat, lon, gs=None, trk=None, header=HEADER):
    """Write a flight in the shipped format (gzip CSV if the name ends in .gz)."""
    n = len(t)
    gs = np.full(n, 100.0) if gs is None else np.broadcast_to(gs, (n,))
    trk = np.zeros(n) if trk is None else np.broadcast_to(trk, (n,))
    lines = [header]
    for i in range(n):
        la = "" if np.isnan(lat[i]) else repr(float(lat[i]))
        lo = "" if np.isnan(lon[i]) else repr(float(lon[i]))
        lines.append(f"{t[i]:.0f},{la},{lo},1000,{gs[i]:.3f},{trk[i] % 360:.2f}")
    text = "\n".join(lines) + "\n"
    if str(path).endswith(".gz"):
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return path


def straight(heading_deg, n=120, dt=5.0, speed=100.0, lat0=45.0, lon0=5.0):
    t = 1.6e9 + dt * np.arange(n)
    h = math.radians(heading_deg)
    x = speed * math.sin(h) * (t - t[0])
    y = speed * math.cos(h) * (t - t[0])
    lat = lat0 + np.degrees(y / R_EARTH_M)
    lon = lon0 + np.degrees(x / (R_EARTH_M * math.cos(math.radians(lat0))))
    return t, lat, lon


# ------------------------------------------------------------------------------------------------ projection
def test_projection_known_distances():
    x, y = adsb.project_local_en([46.0], [5.0], 45.0, 5.0)
    assert x[0] == pytest.approx(0.0, abs=1e-6)
    assert y[0] == pytest.approx(111_141.0, rel=2e-3)  # 1 deg of latitude at 45.5 deg on WGS84, shortened ~1 m
    x, y = adsb.project_local_en([0.0], [1.0], 0.0, 0.0)
    assert x[0] == pytest.approx(111_319.5, rel=1e-4) and abs(y[0]) < 1e3  # 1 deg of longitude on the equator
    x, y = adsb.project_local_en([60.0], [6.0], 60.0, 5.0)
    assert x[0] == pytest.approx(55_800.0, rel=3e-3)  # cos(60 deg) shortening
    assert 300.0 < y[0] < 600.0  # the parallel curves north of the tangent plane's east axis: ~x^2 tan(lat)/(2R)
    # 200 km north: tangent plane shortens by ~d^3/(6R^2) ~ 33 m (documented)
    lat = 45.0 + np.degrees(200e3 / 6_367_000.0)
    x, y = adsb.project_local_en([lat], [5.0], 45.0, 5.0)
    assert 200e3 - 120.0 < y[0] < 200e3 + 700.0


# ------------------------------------------------------------------------------------------------ orientation
@pytest.mark.parametrize("heading,sign", [(0.0, (0, 1)), (90.0, (1, 0)), (180.0, (0, -1)), (270.0, (-1, 0))])
def test_north_up_east_right(tmp_path, heading, sign):
    t, lat, lon = straight(heading)
    p = write_flight(tmp_path / "f.csv.gz", t, lat, lon, trk=heading)
    tr = adsb.load_trajectory(p)
    assert tr.t_s[0] == 0.0 and np.all(np.diff(tr.t_s) == 1.0)
    vx, vy = np.median(tr.vx_m_s), np.median(tr.vy_m_s)
    assert vx == pytest.approx(100.0 * sign[0], abs=0.5)
    assert vy == pytest.approx(100.0 * sign[1], abs=0.5)
    assert tr.check["velocity_rms_m_s"] < 1.0 and tr.check["speed_rms_m_s"] < 1.0


def test_heading_wrap_through_north(tmp_path):
    # a right turn from heading 300 through 360/0 to 60 deg: reported track wraps 359 -> 0; velocity continuous
    dt, speed, omega = 5.0, 100.0, math.radians(1.0)
    t = 1.6e9 + dt * np.arange(200)
    h = math.radians(300.0) + omega * (t - t[0]) * 0.6
    x = np.concatenate([[0.0], np.cumsum(speed * np.sin(h[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(speed * np.cos(h[:-1]) * dt)])
    lat = 50.0 + np.degrees(y / R_EARTH_M)
    lon = 2.0 + np.degrees(x / (R_EARTH_M * math.cos(math.radians(50.0))))
    p = write_flight(tmp_path / "turn.csv", t, lat, lon, trk=np.degrees(h) % 360)
    tr = adsb.load_trajectory(p)
    hd = np.degrees(np.arctan2(tr.vx_m_s, tr.vy_m_s)) % 360
    assert hd.max() > 350 and hd.min() < 10  # crossed north
    # continuous: per-second velocity steps of the order of the 1 m/s^2 turn acceleration, no 100-m/s jump
    assert np.max(np.abs(np.diff(tr.vx_m_s))) < 3.0 and np.max(np.abs(np.diff(tr.vy_m_s))) < 3.0
    assert tr.check["velocity_rms_m_s"] < 10.0  # reported track 359 vs 1 deg compared as vectors, not angles


# ------------------------------------------------------------------------------------------------ cleaning
def test_gap_splits_segments(tmp_path):
    t, lat, lon = straight(45.0, n=200)
    t = t.copy()
    t[120:] += 60.0  # a 65-s gap
    p = write_flight(tmp_path / "gap.csv", t, lat, lon)
    rows = adsb.clean(adsb.load_raw(p))
    pieces, rejected = adsb.split_segments(rows, max_gap_s=20.0, min_duration_s=120.0)
    assert [len(pc.rows) for pc in pieces] == [120, 80] and not rejected
    tr0 = adsb.load_trajectory(p, segment=0)
    tr1 = adsb.load_trajectory(p, segment=1)
    assert tr0.duration_s == 595.0 and tr1.duration_s == 395.0 and tr1.n_segments == 2
    assert adsb.load_trajectory(p).segment == 0  # longest
    with pytest.raises(ValueError, match="segment 2 out of range"):
        adsb.load_trajectory(p, segment=2)


def test_short_piece_rejected_with_message(tmp_path):
    t, lat, lon = straight(0.0, n=140)
    t = t.copy()
    t[130:] += 100.0  # last 10 rows (45 s) after a gap
    rows = adsb.clean(adsb.load_raw(write_flight(tmp_path / "s.csv", t, lat, lon)))
    pieces, rejected = adsb.split_segments(rows, min_duration_s=120.0)
    assert len(pieces) == 1 and len(rejected) == 1 and "45 s" in rejected[0] and "rejected" in rejected[0]


def test_stale_repeats_and_nan_removed(tmp_path):
    t, lat, lon = straight(90.0, n=100)
    lat, lon = lat.copy(), lon.copy()
    lat[40:45] = lat[39]  # receiver repeats its last position for 5 rows
    lon[40:45] = lon[39]
    lat[60] = np.nan
    raw = adsb.load_raw(write_flight(tmp_path / "r.csv", t, lat, lon))
    assert len(raw) == 100 and np.isnan(raw.lat_deg[60])
    rows = adsb.clean(raw)
    assert len(rows) == 100 - 5 - 1
    assert not np.any((np.diff(rows.lat_deg) == 0) & (np.diff(rows.lon_deg) == 0))
    tr = adsb.load_trajectory(tmp_path / "r.csv")
    assert np.all(np.abs(np.hypot(tr.vx_m_s, tr.vy_m_s) - 100.0) < 3.0)  # no stop from the stale rows


def test_min_groundspeed_drops_slow_rows(tmp_path):
    t, lat, lon = straight(0.0, n=100)
    gs = np.full(100, 100.0)
    gs[:10] = 5.0
    rows = adsb.clean(adsb.load_raw(write_flight(tmp_path / "g.csv", t, lat, lon, gs=gs)), min_groundspeed_m_s=30)
    assert len(rows) == 90


# ------------------------------------------------------------------------------------------------ bad files
def test_missing_column(tmp_path):
    t, lat, lon = straight(0.0, n=50)
    p = write_flight(tmp_path / "m.csv", t, lat, lon, header="t_s,lat_deg,longitude,alt_m,groundspeed_m_s,track_deg")
    with pytest.raises(ValueError, match=r"m\.csv.*missing column.*lon_deg"):
        adsb.load_raw(p)


def test_non_monotonic_time(tmp_path):
    t, lat, lon = straight(0.0, n=50)
    t = t.copy()
    t[20] = t[18]
    p = write_flight(tmp_path / "nm.csv.gz", t, lat, lon)
    with pytest.raises(ValueError, match=r"nm\.csv\.gz.*strictly increasing.*data row 21"):
        adsb.load_trajectory(p)


def test_bad_number_and_too_short(tmp_path):
    p = tmp_path / "b.csv"
    p.write_text(HEADER + "\n0,45.0,5.0,0,100,0\n5,abc,5.0,0,100,0\n")
    with pytest.raises(ValueError, match=r"b\.csv: line 3, column 'lat_deg'"):
        adsb.load_raw(p)
    t, lat, lon = straight(0.0, n=10)  # 45 s
    p = write_flight(tmp_path / "short.csv", t, lat, lon)
    with pytest.raises(ValueError, match=r"short\.csv: no segment of at least 120 s.*45 s"):
        adsb.load_trajectory(p)
    with pytest.raises(ValueError, match="unknown ADS-B flight"):
        adsb.load_trajectory("no_such_flight")
    (tmp_path / "e.csv").write_text("")
    with pytest.raises(ValueError, match="empty file"):
        adsb.load_raw(tmp_path / "e.csv")


# ------------------------------------------------------------------------------------------------ radar site
def test_place_radar_rule(tmp_path):
    t, lat, lon = straight(30.0, n=200)
    tr = adsb.load_trajectory(write_flight(tmp_path / "p.csv", t, lat, lon))
    s = adsb.place_radar(tr, min_range_m=20e3)
    r = np.hypot(tr.x_m - s[0], tr.y_m - s[1])
    assert r.min() >= 20e3 - 1e-6 and r.max() <= 20e3 + 2 * 50e3
    assert np.array_equal(s, adsb.place_radar(tr))  # deterministic
    c = np.array([(tr.x_m.min() + tr.x_m.max()) / 2, (tr.y_m.min() + tr.y_m.max()) / 2])
    assert s[0] < c[0] and s[1] < c[1]  # default: south-west of the flight
    s1 = adsb.place_radar(tr, rng=np.random.default_rng(3))
    s2 = adsb.place_radar(tr, rng=np.random.default_rng(3))
    assert np.array_equal(s1, s2)
    assert np.hypot(tr.x_m - s1[0], tr.y_m - s1[1]).min() >= 20e3 - 1e-6


# ------------------------------------------------------------------------------------------------ shipped data
def test_shipped_flights_load():
    ids = adsb.list_flights()
    assert len(ids) == 24 and "munich" in ids
    for fid in ids:
        tr = adsb.load_trajectory(fid)
        for a in (tr.t_s, tr.x_m, tr.y_m, tr.vx_m_s, tr.vy_m_s):
            assert np.all(np.isfinite(a))
        sp = np.hypot(tr.vx_m_s, tr.vy_m_s)
        assert sp.min() >= 30.0 and sp.max() < 300.0, fid
        assert tr.duration_s > 3000.0, fid
        assert tr.check["speed_rms_m_s"] < 15.0, fid
        acc = np.hypot(np.diff(tr.vx_m_s), np.diff(tr.vy_m_s))
        # m/s^2 on the 1-s grid: a standard-rate turn (3 deg/s) at 100 m/s is 5.2 m/s^2; kota_kinabalu (fastest,
    # up to 270 m/s) has p99 ~12 m/s^2, so bound the 95th percentile
    assert np.percentile(acc, 95) < 8.0, fid


def test_shipped_flight_to_scenario():
    tr = adsb.load_trajectory("liege_sprimont")
    sc = tr.to_scenario()
    assert sc.duration_s == tr.duration_s
    assert tr.as_array().shape == (tr.t_s.size, 5)
