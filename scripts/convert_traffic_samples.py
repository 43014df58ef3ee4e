"""Convert the navaid-calibration sample flights of the ``traffic`` library into ``radar_env/data/adsb/``.

Development script (it uses pandas); the runtime loader :mod:`radar_env.sim.adsb` needs only stdlib + numpy + scipy.

Source
------
PyPI package ``traffic`` 2.13 (MIT licence, Xavier Olive), folder ``traffic/data/samples/calibration/``: 24 real
OpenSky Network ADS-B flights of navaid-calibration aircraft (orbits, procedure turns, approaches), one
``<name>.json.gz`` each, a JSON list of records with ``timestamp`` (ms since the Unix epoch), ``icao24``,
``latitude``, ``longitude`` (deg), ``groundspeed`` (kt), ``track`` (deg), ``vertical_rate`` (ft/min), ``callsign``,
``altitude`` (ft). The samples are regular: every 5 s (``nice``: every 10 s).

Get it without installing ``traffic``::

    cd /tmp && /work/venv/bin/pip download traffic==2.13 --no-deps -d /tmp/traffic_wheel
    cd /tmp/traffic_wheel && unzip -q traffic-2.13-py3-none-any.whl -d x
    /work/venv/bin/python scripts/convert_traffic_samples.py /tmp/traffic_wheel/x/traffic/data/samples/calibration

Output
------
One ``<name>.csv.gz`` per flight (same stem as the source file) with header
``t_s,lat_deg,lon_deg,alt_m,groundspeed_m_s,track_deg``:

* ``t_s``: seconds since the Unix epoch (UTC), integer;
* ``lat_deg``, ``lon_deg``: the positions exactly as in the source (no smoothing, no resampling, no row dropped);
* ``alt_m``: barometric altitude, ft converted to m (``* 0.3048``), 0.1 m resolution;
* ``groundspeed_m_s``: kt converted to m/s (``* 1852/3600``), 0.01 m/s resolution (the source is whole knots);
* ``track_deg``: track over ground in [0, 360), see the repair below.

Track repair. In 22 of the 24 source files ``track`` lies in [-128, 127]: it was stored as an 8-bit signed
integer and wrapped modulo 256 (``liege_sprimont``, ``sydney``, ``nice`` are in [0, 360)). Example: ``ajaccio`` row 0
has ``track = -47`` while the positions move towards 209 deg (= -47 + 256). A stored value ``v`` therefore means
``v mod 256`` or, if that is below 104, possibly ``v mod 256 + 256``. This script picks the candidate nearest to the
course computed from the positions (central differences on a local east/north plane); the ambiguity is 256 deg,
far larger than the course noise, so the choice is not sensitive to that estimate. Files already in [0, 360) are
copied unchanged. The repaired track is only used to cross-check the loader's velocities; trajectories are built
from the positions alone.

Nothing else is changed: rows with missing positions, stale repeated positions (``sydney`` has 72) and
non-monotonic times are left for the loader's cleaning to handle.
"""

from __future__ import annotations

import argparse
import gzip
import io
from pathlib import Path

import numpy as np
import pandas as pd

FT_M = 0.3048
KNOT_M_S = 1852.0 / 3600.0
OUT_DIR = Path(__file__).resolve().parents[1] / "radar_env" / "data" / "adsb"


def position_course_deg(lat_deg, lon_deg):
    """Course over ground (deg clockwise from north) from positions by central differences."""
    lat = np.radians(lat_deg)
    lon = np.radians(lon_deg)
    x = np.unwrap(lon) * np.cos(np.nanmean(lat)) * 6371e3
    y = lat * 6371e3
    dx = np.gradient(x)
    dy = np.gradient(y)
    return np.degrees(np.arctan2(dx, dy)) % 360.0


def repair_track(track, lat_deg, lon_deg):
    """Undo the int8 wrap of ``track`` (see the module docstring). Returns track in [0, 360) and #changed rows."""
    track = np.asarray(track, dtype=float)
    if np.nanmin(track) >= 0.0:
        return track % 360.0, 0
    base = track % 256.0
    alt = np.where(base < 104.0, base + 256.0, np.nan)
    course = position_course_deg(lat_deg, lon_deg)

    def angdiff(a):
        return np.abs((a - course + 180.0) % 360.0 - 180.0)

    use_alt = np.isfinite(alt) & (angdiff(np.nan_to_num(alt)) < angdiff(base))
    out = np.where(use_alt, alt, base)
    return out, int(np.count_nonzero(out != track))


def convert(src: Path, out_dir: Path):
    d = pd.read_json(src)
    t_ms = d["timestamp"]
    if np.issubdtype(t_ms.dtype, np.datetime64):
        t_s = (t_ms.astype("datetime64[ns]").astype("int64") // 10**9).to_numpy()
    else:
        t_s = (t_ms.astype("int64") // 1000).to_numpy()
    lat = d["latitude"].to_numpy(float)
    lon = d["longitude"].to_numpy(float)
    track, n_fixed = repair_track(d["track"].to_numpy(float), lat, lon)
    out = pd.DataFrame({
        "t_s": t_s,
        "lat_deg": d["latitude"],
        "lon_deg": d["longitude"],
        "alt_m": (d["altitude"].astype(float) * FT_M).round(1),
        "groundspeed_m_s": (d["groundspeed"].astype(float) * KNOT_M_S).round(2),
        "track_deg": np.round(track, 1),
    })
    name = src.name[: -len(".json.gz")]
    buf = io.StringIO()
    out.to_csv(buf, index=False, float_format="%.7g", lineterminator="\n")
    # lat/lon need up to 9 significant digits; write them with repr-exact formatting instead of %.7g.
    text = buf.getvalue().splitlines()
    lines = [text[0]]
    for row, la, lo in zip(text[1:], d["latitude"].to_numpy(float), d["longitude"].to_numpy(float)):
        cells = row.split(",")
        cells[1] = "" if np.isnan(la) else repr(float(la))
        cells[2] = "" if np.isnan(lo) else repr(float(lo))
        lines.append(",".join(cells))
    dst = out_dir / f"{name}.csv.gz"
    with gzip.GzipFile(dst, "wb", compresslevel=9, mtime=0) as f:  # mtime=0: byte-reproducible output
        f.write(("\n".join(lines) + "\n").encode("ascii"))
    return name, len(out), float(t_s[-1] - t_s[0]), n_fixed, dst.stat().st_size


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src_dir", type=Path, help="traffic/data/samples/calibration folder of the unzipped wheel")
    p.add_argument("--out", type=Path, default=OUT_DIR)
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    total = 0
    for src in sorted(a.src_dir.glob("*.json.gz")):
        name, n, dur, n_fixed, size = convert(src, a.out)
        total += size
        print(f"{name:18s} rows={n:5d} duration={dur:7.0f} s track_unwrapped_rows={n_fixed:5d} size={size} B")
    print(f"total {total} B")


if __name__ == "__main__":
    main()
