"""Soak RadarTrack-v0's native vector env on the extremes of the radar parameters it accepts.

``python scripts/soak_covariance.py [--seconds S] [--num-envs N] [--imm-runs N] [--seed K] [--json FILE]``

For every corner of the documented radar ranges (scan period, range, bearing and radial-velocity noise, detection
probability: :data:`EXTREMES`; random flights for ordinary scan periods, :func:`scenario_for`) the vector env is
stepped with uniformly random actions (discrete and continuous, the NEES reward term on) and every step checks:
every float array of the info finite (the plot's columns where there is a plot), the observation and reward finite,
each row's posterior covariance symmetric and positive definite by ``numpy.linalg.cholesky``. The classical IMMs
(``imm2``, ``imm_cv_ct``) run on episodes drawn with the same radars and are checked the same way at every scored
look. Prints one line per corner and the totals (row-steps, looks,
failures); exit status 1 on any failure. tests/test_covariance_pd.py runs it for a few seconds in CI.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from radar_env.sim.draws import draw_episodes  # noqa: E402
from radar_env.envs.env import RadarTrackVectorEnv  # noqa: E402
from radar_env.sim.radar import Radar, RadarSite  # noqa: E402
from radar_env.sim.scenario import ScenarioBuilder  # noqa: E402

EXTREMES = {
    "scan_period_s": (0.01, 12.0, 3600.0),
    "range_noise_std_m": (1e-6, 1e5),
    "bearing_noise_std_rad": (1e-9, 0.5),
    "radial_velocity_noise_std_m_s": (1e-6, 1e3),
    "detection_probability": (0.05, 1.0),
}
"""The corners soaked: each accepted range's maximum (``RadarSite``: scan period (0, 3600] s, range noise
(0, 1e5] m, bearing noise (0, 0.5] rad, radial-velocity noise (0, 1e3] m/s, detection probability (0, 1]) and,
for the ranges open at 0, a value far below any radar's (nanometre to microradian noise, a 10 ms scan)."""

IMM_TRACKERS = ("imm2", "imm_cv_ct")


def scenario_for(scan_period_s):
    """The random flights for ordinary scan periods (1-60 s); outside, a built flight of a few dozen looks of the
    radar (a random flight of minutes is 30,000 looks at 10 ms, and too short for a track start at an hour):
    straight, a 90 deg turn at 2 g, straight, at 200 m/s from 50 km north of the site."""
    if 1.0 <= scan_period_s <= 60.0:
        return "random"
    leg = 12.0 * scan_period_s if scan_period_s > 60.0 else max(40.0 * scan_period_s, 2.0)
    return (ScenarioBuilder(position_m=(0.0, 50e3), speed_m_s=200.0, heading_deg=90.0).straight(leg)
            .turn(90.0, accel_g=2.0).straight(leg).build(name="built_flight"))


def check_info(info, where):
    """Raise AssertionError/LinAlgError naming ``where`` and the key if an info array is not finite or a covariance
    not symmetric positive definite."""
    det = info["detected"]
    for k, v in info.items():
        if isinstance(v, np.ndarray) and v.dtype.kind == "f":
            v = v[det] if k in ("measurement", "measurement_covariance", "polar") else v
            assert np.isfinite(v).all(), f"{where}: info[{k!r}] not finite"
    for k, v in info["reward_terms"].items():
        assert np.isfinite(v).all(), f"{where}: reward term {k!r} not finite"
    P = info["covariance"]
    assert np.array_equal(P, np.swapaxes(P, -1, -2)), f"{where}: covariance not symmetric"
    np.linalg.cholesky(P)


def soak_corner(site, seconds, num_envs, seed, action_type="discrete"):
    """Step one corner for ``seconds`` (at least one episode end per row is not required). Returns
    ``(row_steps, failures, first_failure)``; a radar the env refuses at build returns ``(0, 0, message)``."""
    kw = dict(radar=Radar(site), scenario=scenario_for(site.scan_period_s), action_type=action_type,
              reward_nees_weight=1.0, warmup_scans=1 if site.scan_period_s > 60 else 12)
    try:
        env = RadarTrackVectorEnv(num_envs=num_envs, **kw)
    except ValueError as e:
        return 0, 0, f"refused at build: {e}"
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    steps, fails, first = 0, 0, None
    t_end = time.perf_counter() + seconds
    while True:
        try:
            check_info(info, f"step {steps // num_envs}")
            assert np.isfinite(obs).all(), "observation not finite"
        except (AssertionError, np.linalg.LinAlgError) as e:
            fails += 1
            first = first or str(e)
        if time.perf_counter() > t_end:
            break
        a = (rng.integers(0, env.single_action_space.n, num_envs) if action_type == "discrete"
             else rng.uniform(-1.0, 1.0, (num_envs, 1)))
        obs, reward, term, trunc, info = env.step(a)
        if not np.isfinite(reward).all():
            fails += 1
            first = first or "reward not finite"
        steps += num_envs
    return steps, fails, first


def soak_imms(site, runs, seed):
    """The IMMs on ``runs`` episodes drawn with ``site``: ``(looks, failures, first_failure)``."""
    from baselines.registry import run_tracker
    from radar_env.envs.env import EnvConfig

    warmup = 1 if site.scan_period_s > 60 else 12
    try:
        batch = draw_episodes(scenario_for(site.scan_period_s), Radar(site), None,
                              [np.random.default_rng(seed + i) for i in range(runs)], warmup_scans=warmup)
    except ValueError as e:
        return 0, 0, f"refused: {e}"
    eps = [batch.episode(i) for i in range(batch.batch_size)]
    looks, fails, first = 0, 0, None
    for t in IMM_TRACKERS:
        run = run_tracker(t, eps, EnvConfig.from_kwargs(warmup_scans=warmup))
        for b, e in enumerate(eps):
            P = run.P[b, run.start_index[b]:e.n_looks]
            looks += P.shape[0]
            try:
                assert np.isfinite(P).all() and np.isfinite(run.x[b, run.start_index[b]:e.n_looks]).all(), \
                    f"{t}: not finite"
                assert np.array_equal(P, np.swapaxes(P, -1, -2)), f"{t}: not symmetric"
                np.linalg.cholesky(P)
            except (AssertionError, np.linalg.LinAlgError) as err:
                fails += 1
                first = first or f"{t}, episode {b}: {err}"
    return looks, fails, first


def _quiet_range_warning(fn):
    """The slow-scan corners fly thousands of km from their radar on purpose: their range warning is expected."""
    def run(*args, **kwargs):
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"scenario 'built_flight': the flight goes beyond")
            return fn(*args, **kwargs)
    return run


soak_corner, soak_imms = _quiet_range_warning(soak_corner), _quiet_range_warning(soak_imms)


def corners():
    for vals in itertools.product(*EXTREMES.values()):
        yield RadarSite(**dict(zip(EXTREMES, vals)))


def soak(seconds_per_corner=0.2, num_envs=8, seed=0, imm_runs=4, action_types=("discrete", "continuous"),
         out=print, sites=None):
    """Soak every corner (:func:`corners`, or the given ``sites``); returns the totals dict."""
    tot = {"corners": 0, "row_steps": 0, "env_failures": 0, "imm_looks": 0, "imm_failures": 0, "refused": 0,
           "first_failures": []}
    t0 = time.perf_counter()
    for i, site in enumerate(corners() if sites is None else sites):
        at = action_types[i % len(action_types)]
        steps, fails, first = soak_corner(site, seconds_per_corner, num_envs, seed + i, at)
        looks, ifails, ifirst = soak_imms(site, imm_runs, seed + 1000 * i) if imm_runs else (0, 0, None)
        tot["corners"] += 1
        tot["row_steps"] += steps
        tot["env_failures"] += fails
        tot["imm_looks"] += looks
        tot["imm_failures"] += ifails
        tot["refused"] += int(steps == 0)
        for f in (first if fails or steps == 0 else None, ifirst if ifails else None):
            if f:
                tot["first_failures"].append(f"{site}: {f}")
        out(f"T={site.scan_period_s:g} s sr={site.range_noise_std_m:g} m sb={site.bearing_noise_std_rad:g} rad "
            f"sv={site.radial_velocity_noise_std_m_s:g} m/s pd={site.detection_probability:g} ({at}): "
            f"{steps} row-steps, {fails} failures; IMMs {looks} looks, {ifails} failures"
            + (f"  [{first}]" if steps == 0 else ""))
    tot["seconds"] = time.perf_counter() - t0
    return tot


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="seconds of env steps per corner (default 2)")
    ap.add_argument("--num-envs", type=int, default=16, help="rows of the vector env (default 16)")
    ap.add_argument("--imm-runs", type=int, default=16, help="episodes per corner for the IMMs (default 16)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="write the totals to this file")
    args = ap.parse_args(argv)
    tot = soak(args.seconds, args.num_envs, args.seed, args.imm_runs)
    print(f"\n{tot['corners']} corners, {tot['row_steps']} row-steps ({tot['env_failures']} failures), "
          f"{tot['imm_looks']} IMM looks ({tot['imm_failures']} failures), {tot['refused']} refused at build, "
          f"{tot['seconds']:.0f} s")
    for f in tot["first_failures"]:
        print("  " + f)
    if args.json:
        Path(args.json).write_text(json.dumps(tot, indent=1))
    return 1 if tot["env_failures"] or tot["imm_failures"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
