"""Speed of RadarTrack-v0 beside CartPole-v1, measured in one run (issues 16 and 27; docs/speed.md's table).

Run by hand from the repository root: ``python benchmarks/bench_env.py [--seconds 2] [--markdown]``. Measures

(a) CartPole-v1 through ``gym.make`` and RadarTrack-v0 through ``gym.make`` (with its wrappers): steps/s, resets
    included, random actions drawn beforehand (so both pay the same per-step cost outside the env);
(b) at each ``--num-envs`` N (default 1, 16, 64, 256, 1024, 4096): Gymnasium's CartPole vector env
    (``gym.make_vec("CartPole-v1", num_envs=N, vectorization_mode="vector_entry_point")``, i.e. its numpy
    ``CartPoleVectorEnv``) and RadarTrack's native vector env (``RadarTrackVectorEnv``): row-steps/s
    (N x vector steps / s), autoresets included;
(c) ``Tracker.step`` alone at B = 1024 (row-steps/s; reloads excluded), the tracking chain without the Gym layer;
(d) the README's main job, ``python -m agents.cli evaluate --no-plots --quiet`` (the default evaluation), in
    fresh interpreters: once with an empty numba cache (cold, compilation included), then ``--main-job-runs``
    times with it filled (warm, the median reported): wall time, CPU time (user + sys of the child) and the load
    average before each run (``--only-main-job`` measures just this);
(e) first import with compilation: a fresh interpreter with ``NUMBA_CACHE_DIR`` pointed at an empty temporary
    directory imports ``radar_env``, makes the single and the vector env and takes a first reset and step (and a
    first ``imm_step``); then the same again with that cache filled (warm);
(f) resident memory of the vector env at ``--memory-envs`` (default 1024) envs after 200 steps, in a fresh
    interpreter: VmRSS before making it and after the steps, and the peak (VmHWM), from ``/proc/self/status``.

Every rate is also given as seconds per 1M steps (as gymnax publishes) and as a ratio to CartPole of the same kind
(single env to single env, vector env to the CartPole vector env at the same N). A rate window lasts ``--seconds``
and, for the envs, at least until the resets in it reach ``--min-resets-per-env`` per env: RadarTrack's vector
env draws the next episodes of finished rows in batches, so a window shorter than about one episode per row would
miss most of that cost (or be dominated by one batch). ``--profile`` prints a cProfile of the single env and of
the vector env at 256 envs; ``--markdown`` prints the results as docs/speed.md's table. The report ends with
issue 27's targets, each reached / NOT reached with the measured number, and gives the machine's load average at the
start and the end (the rates are shared with whatever else runs: compare runs made under the same load).
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import io
import json
import os
import platform
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:          # run as a script: import this checkout's radar_env, not an installed one
    sys.path.insert(0, str(REPO))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import radar_env  # noqa: E402,F401  (registers RadarTrack-v0)
from radar_env.sim.catalog import make_setup  # noqa: E402
from radar_env.envs.env import RadarTrackVectorEnv  # noqa: E402
from radar_env.sim.episode import draw_episode  # noqa: E402
from radar_env.filters.tracking import Tracker  # noqa: E402
from radar_env.common.units import G0_M_S2  # noqa: E402

DEFAULT_NUM_ENVS = (1, 16, 64, 256, 1024, 4096)
_ACTION_POOL = 64     # random actions drawn beforehand and cycled through


@dataclass
class Rate:
    steps_per_s: float
    steps: int
    seconds: float
    resets: int


def _timed(step, seconds, min_resets=0):
    """Call ``step()`` (returns (row-steps, resets) it did) until ``seconds`` have passed and ``min_resets`` resets
    were seen; the first call (warm-up, first compilation) is not counted."""
    step()
    n = r = 0
    t0 = time.perf_counter()
    while True:
        dn, dr = step()
        n, r = n + dn, r + dr
        dt = time.perf_counter() - t0
        if dt >= seconds and r >= min_resets:
            return Rate(n / dt, n, dt, r)


def bench_single(env_id, seconds, min_resets=1, **env_kwargs):
    """Steps/s of ``gym.make(env_id, **env_kwargs)`` with random actions, resets included."""
    env = gym.make(env_id, **env_kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    acts = [env.action_space.sample() for _ in range(_ACTION_POOL)]
    i = [0]

    def step():
        i[0] = (i[0] + 1) % _ACTION_POOL
        _, _, te, tr, _ = env.step(acts[i[0]])
        if te or tr:
            env.reset()
            return 1, 1
        return 1, 0

    out = _timed(step, seconds, min_resets)
    env.close()
    return out


def _bench_vec(venv, num_envs, seconds, min_resets):
    venv.reset(seed=0)
    venv.action_space.seed(0)
    acts = [venv.action_space.sample() for _ in range(_ACTION_POOL)]
    i = [0]

    def step():
        i[0] = (i[0] + 1) % _ACTION_POOL
        _, _, te, tr, _ = venv.step(acts[i[0]])
        return num_envs, int(np.count_nonzero(te | tr))

    out = _timed(step, seconds, min_resets)
    venv.close()
    return out


def bench_cartpole_vector(num_envs, seconds, min_resets_per_env=1.0):
    """Gymnasium's numpy CartPole vector env (next-step autoreset, its default)."""
    venv = gym.make_vec("CartPole-v1", num_envs=num_envs, vectorization_mode="vector_entry_point")
    return _bench_vec(venv, num_envs, seconds, int(np.ceil(min_resets_per_env * num_envs)))


def bench_vector(num_envs, seconds, min_resets_per_env=1.0, **env_kwargs):
    """RadarTrack's native vector env (same-step autoreset; ``env_kwargs``: its arguments)."""
    return _bench_vec(RadarTrackVectorEnv(num_envs=num_envs, **env_kwargs), num_envs, seconds,
                      int(np.ceil(min_resets_per_env * num_envs)))


def bench_tracker(B, seconds):
    """``Tracker.step`` over B rows at a fixed q; rows that run out are reloaded, reload time excluded."""
    rng = np.random.default_rng(0)
    pool = []
    for _ in range(32):
        s = make_setup("random", rng)
        pool.append(draw_episode(s.scenario, s.radar, rng))
    tr = Tracker(B)
    tr.load(np.arange(B), [pool[i % len(pool)] for i in range(B)])
    q = np.full(B, 0.5 * G0_M_S2)
    load_time = [0.0]

    def step():
        if np.any(tr.remaining_looks() == 0):
            t0 = time.perf_counter()
            rows = np.flatnonzero(tr.remaining_looks() == 0)
            tr.load(rows, [pool[i % len(pool)] for i in rows])
            load_time[0] += time.perf_counter() - t0
        tr.step(q)
        return B, 0

    r = _timed(step, seconds)
    dt = r.seconds - load_time[0]
    return Rate(r.steps / dt, r.steps, dt, 0)


# ------------------------------------------------------------------------------------------ fresh interpreters
def _child_env(**extra):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.update(extra)
    return env


def _run_child(code, **env):
    """Run ``code`` in a fresh interpreter (repository root first on sys.path); return its last stdout line as
    JSON, the wall time and the child's CPU time."""
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_child_env(**env), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"benchmark child failed ({p.returncode}):\n{p.stderr[-3000:]}")
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    return json.loads(p.stdout.strip().splitlines()[-1]), wall, cpu


_IMPORT_CODE = r"""
import json, time
t0 = time.perf_counter()
import gymnasium as gym
import numpy as np
import radar_env
from radar_env.envs.env import RadarTrackVectorEnv
from radar_env.filters import kalman as kf
t1 = time.perf_counter()
env = gym.make("RadarTrack-v0")
env.reset(seed=0)
env.step(env.action_space.sample())
venv = RadarTrackVectorEnv(num_envs=4)
venv.reset(seed=0)
venv.step(venv.action_space.sample())
t_env = time.perf_counter()
M = 2
kf.imm_step(np.log(np.full((1, M), 0.5)), np.zeros((1, M, 4)), np.tile(np.eye(4), (1, M, 1, 1)),
            np.log(np.full((M, M), 0.5)), np.tile(kf.transition_cv(1.0), (1, M, 1, 1)),
            np.tile(kf.process_noise(1.0, 1.0), (1, M, 1, 1)), np.zeros((1, 2)), np.eye(2)[None])
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_use_s": t2 - t1, "env_first_use_s": t_env - t1}))
"""


def import_times():
    """Cold (empty numba cache) and warm (cache filled by the cold run) import + first use, fresh interpreters."""
    with tempfile.TemporaryDirectory(prefix="bench_numba_cache_") as cache:
        out = {}
        for kind in ("cold", "warm"):
            res, wall, cpu = _run_child(_IMPORT_CODE, NUMBA_CACHE_DIR=cache)
            out[kind] = dict(res, wall_s=wall, cpu_s=cpu)
        return out


_MEMORY_CODE = r"""
import json
import numpy as np
def status_mb(key):   # VmRSS: resident now; VmHWM: this process's peak (getrusage's ru_maxrss would include the
    for line in open("/proc/self/status"):  # parent's peak at fork time on Linux)
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")
rss_mb = lambda: status_mb("VmRSS")
from radar_env.envs.env import RadarTrackVectorEnv
base = rss_mb()
venv = RadarTrackVectorEnv(num_envs=%d)
venv.reset(seed=0)
rng = np.random.default_rng(0)
for _ in range(200):
    venv.step(rng.integers(0, venv.single_action_space.n, venv.num_envs))
print(json.dumps({"rss_before_mb": base, "rss_after_mb": rss_mb(),
                  "peak_rss_mb": status_mb("VmHWM")}))
"""


def vector_memory(num_envs):
    res, wall, _ = _run_child(_MEMORY_CODE % int(num_envs))
    return dict(res, wall_s=wall)


MAIN_JOB = ("-m", "agents.cli", "evaluate", "--no-plots", "--quiet")


def _main_job_once(cache_dir):
    """One run of the main job in a fresh interpreter with ``NUMBA_CACHE_DIR=cache_dir``: wall and CPU time (user +
    sys of the child) and the 1-minute load average before and after it (other work on the machine)."""
    load0 = os.getloadavg()[0]
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, *MAIN_JOB], cwd=REPO, env=_child_env(NUMBA_CACHE_DIR=cache_dir),
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"main job failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return {"wall_s": wall, "cpu_s": (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime),
            "load_before": load0, "load_after": os.getloadavg()[0]}


def main_job(warm_runs=3):
    """The README's main job without plots (``python -m agents.cli evaluate --no-plots --quiet``), in fresh
    interpreters from the repository root: once cold (an empty numba cache: every kernel it uses compiles), then
    ``warm_runs`` times with that cache filled (the usual case). Returns the cold run, the warm runs and the warm
    median (by wall time) as ``wall_s`` / ``cpu_s``."""
    with tempfile.TemporaryDirectory(prefix="bench_numba_cache_") as cache:
        cold = _main_job_once(cache)
        warm = [_main_job_once(cache) for _ in range(max(1, int(warm_runs)))]
    med = sorted(warm, key=lambda r: r["wall_s"])[len(warm) // 2]
    return {"wall_s": med["wall_s"], "cpu_s": med["cpu_s"], "cold": cold, "warm": warm}


# ------------------------------------------------------------------------------------------ profile
def _print_profile(pr, title):
    for key in ("cumulative", "tottime"):
        s = io.StringIO()
        pstats.Stats(pr, stream=s).sort_stats(key).print_stats(12)
        print(f"\n--- cProfile, {title}, top 12 by {key} ---")
        print(s.getvalue())


def profile(num_envs=256, vector_steps=300, single_steps=3000):
    env = gym.make("RadarTrack-v0")
    env.reset(seed=0)
    env.action_space.seed(0)
    acts = [env.action_space.sample() for _ in range(single_steps)]
    pr = cProfile.Profile()
    pr.enable()
    for a in acts:
        _, _, te, tr, _ = env.step(a)
        if te or tr:
            env.reset()
    pr.disable()
    _print_profile(pr, f"RadarTrack-v0 single env, {single_steps} steps")
    venv = RadarTrackVectorEnv(num_envs=num_envs)
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = rng.integers(0, venv.single_action_space.n, (vector_steps, num_envs))
    pr = cProfile.Profile()
    pr.enable()
    for a in acts:
        venv.step(a)
    pr.disable()
    _print_profile(pr, f"RadarTrackVectorEnv num_envs={num_envs}, {vector_steps} steps")


# ------------------------------------------------------------------------------------------ report
def _git_commit():
    try:
        p = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True)
        return p.stdout.strip() or "unknown"
    except OSError:
        return "unknown"


def _versions():
    out = {"python": platform.python_version(), "numpy": np.__version__, "gymnasium": gym.__version__}
    try:
        import numba
        out["numba"] = numba.__version__
    except ImportError:
        out["numba"] = "not installed"
    return out


def _per_1m(sps):
    return 1e6 / sps if sps > 0 else float("inf")


def _rate_rows(results):
    """(case, N, RadarTrack rate, CartPole rate or None, resets per env) in table order."""
    rows = [("single env (gym.make)", 1, results["single"], results["cartpole_single"])]
    for n, (ours, cart) in results["vector"].items():
        rows.append(("native vector env", n, ours, cart))
    rows.append(("Tracker.step alone", 1024, results["tracker"], None))
    return rows


# issue 27's targets: (name, how to read it from the results, bound, "min" = at least / "max" = at most, unit)
TARGETS = (
    ("vector env row-steps/s at 1,024 envs", lambda r: _vector_rate(r, 1024), 1_000_000, "min", "/s"),
    ("vector env row-steps/s at 64 envs", lambda r: _vector_rate(r, 64), 300_000, "min", "/s"),
    ("memory at 1,024 envs (MB resident after 200 steps)",
     lambda r: r["memory"]["rss_after_mb"] if r.get("memory", {}).get("num_envs") == 1024 else None, 500, "max",
     " MB"),
    ("single env / CartPole-v1", lambda r: r["single"].steps_per_s / r["cartpole_single"].steps_per_s, 0.25, "min",
     "x"),
    ("first use, empty numba cache (make, reset and step both envs, s)",
     lambda r: r["import"]["cold"]["env_first_use_s"] if r.get("import") else None, 15.0, "max", " s"),
)


def _vector_rate(results, n):
    pair = results["vector"].get(n)
    return pair[0].steps_per_s if pair else None


def target_rows(results):
    """(target, value or None, bound, reached or None) for :data:`TARGETS`."""
    out = []
    for name, get, bound, kind, unit in TARGETS:
        try:
            v = get(results)
        except (KeyError, TypeError):
            v = None
        ok = None if v is None else (v >= bound if kind == "min" else v <= bound)
        out.append((name, v, bound, kind, unit, ok))
    return out


def _print_targets(results, markdown):
    lines = []
    for name, v, bound, kind, unit, ok in target_rows(results):
        fmt = (lambda x: f"{x:,.0f}") if bound >= 100 else (lambda x: f"{x:.3g}")
        got = "not measured" if v is None else f"{fmt(v)}{unit}"
        verdict = "-" if ok is None else ("reached" if ok else "NOT reached")
        lines.append((name, f"{'>=' if kind == 'min' else '<='} {fmt(bound)}{unit}", got, verdict))
    if markdown:
        print("\n| target | bound | measured | |\n|---|---:|---:|---|")
        for ln in lines:
            print("| " + " | ".join(ln) + " |")
    else:
        print("targets:")
        for name, b, got, verdict in lines:
            print(f"  {name:<64} {b:>14} {got:>16}  {verdict}")


def print_text(results):
    print(f"RadarTrack-v0 speed, {results['date']}, commit {results['commit']}, {results['cpus']} CPUs, "
          + ", ".join(f"{k} {v}" for k, v in results["versions"].items()))
    print(_load_text(results))
    hdr = f"{'case':<24} {'envs':>5} {'steps/s':>12} {'CartPole':>12} {'ratio':>8} {'s / 1M':>9} {'resets/env':>10}"
    print(hdr)
    for case, n, ours, cart in _rate_rows(results):
        ratio = f"{ours.steps_per_s / cart.steps_per_s:8.3f}" if cart else f"{'':>8}"
        cp = f"{cart.steps_per_s:12,.0f}" if cart else f"{'':>12}"
        print(f"{case:<24} {n:>5} {ours.steps_per_s:12,.0f} {cp} {ratio} {_per_1m(ours.steps_per_s):9.1f} "
              f"{ours.resets / n:10.2f}")
    _print_extras(results, markdown=False)
    _print_targets(results, markdown=False)


def _load_text(results):
    a, b = results.get("load_start"), results.get("load_end")
    if a is None or b is None:
        return "machine load not recorded"
    return (f"machine load (1-min average, {results['cpus']} CPUs) {a:.2f} at the start, {b:.2f} at the end: the rates "
            "are shared with whatever else ran")


def _print_extras(results, markdown):
    lines = []
    if results.get("main_job"):
        m = results["main_job"]
        runs = ", ".join(f"{r['wall_s']:.1f} s / {r['cpu_s']:.1f} s (load {r['load_before']:.1f})" for r in m["warm"])
        c = m["cold"]
        lines.append(f"main job (`python -m agents.cli evaluate --no-plots --quiet`), warm numba cache: "
                     f"{m['wall_s']:.1f} s wall, {m['cpu_s']:.1f} s CPU (median of {len(m['warm'])}: wall / CPU "
                     f"{runs}); cold (empty cache, compilation included): {c['wall_s']:.1f} s wall, "
                     f"{c['cpu_s']:.1f} s CPU (load {c['load_before']:.1f}); load = the 1-minute load average "
                     f"before the run, on {os.cpu_count()} CPUs")
    if results.get("import"):
        c, w = results["import"]["cold"], results["import"]["warm"]
        lines.append(f"first import + first use, empty numba cache: {c['import_s']:.2f} s + {c['first_use_s']:.2f} s "
                     f"(of which the envs {c.get('env_first_use_s', float('nan')):.2f} s, the rest a first IMM step; "
                     f"{c['wall_s']:.1f} s for the interpreter, {c['cpu_s']:.1f} s CPU); cached: {w['import_s']:.2f} "
                     f"s + {w['first_use_s']:.2f} s ({w['wall_s']:.1f} s)")
    if results.get("memory"):
        m = results["memory"]
        lines.append(f"vector env at {m['num_envs']} envs after 200 steps: {m['rss_after_mb']:.0f} MB resident "
                     f"({m['rss_before_mb']:.0f} MB before making it; peak {m['peak_rss_mb']:.0f} MB)")
    for ln in lines:
        print(("- " if markdown else "") + ln)


def print_markdown(results):
    v = results["versions"]
    print(f"Measured {results['date']} (commit {results['commit']}, {results['cpus']} CPUs, Python {v['python']}, "
          f"numpy {v['numpy']}, gymnasium {v['gymnasium']}, numba {v['numba']}) with "
          f"`python benchmarks/bench_env.py {results['argv']}`; windows of at least {results['seconds']:g} s and "
          f"{results['min_resets_per_env']:g} reset(s) per env; {_load_text(results)}.\n")
    print("| case | envs | steps/s | CartPole steps/s | ratio to CartPole | s per 1M steps | resets per env |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for case, n, ours, cart in _rate_rows(results):
        cp = f"{cart.steps_per_s:,.0f}" if cart else "-"
        ratio = f"{ours.steps_per_s / cart.steps_per_s:.3f}" if cart else "-"
        print(f"| {case} | {n:,} | {ours.steps_per_s:,.0f} | {cp} | {ratio} | {_per_1m(ours.steps_per_s):.1f} | "
              f"{ours.resets / n:.2f} |")
    print()
    _print_extras(results, markdown=True)
    _print_targets(results, markdown=True)


def _shown_argv(argv):
    """The command line for the table's caption, without ``--json FILE`` (where the numbers were saved)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--json":
            skip = True
        elif not a.startswith("--json="):
            out.append(a)
    return " ".join(out)


def _num_envs(text):
    try:
        vals = [int(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        vals = []
    if not vals or any(v < 1 for v in vals):
        raise argparse.ArgumentTypeError(f"expected comma-separated integers >= 1, got {text!r}")
    return tuple(vals)


def _nonneg(kind):
    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            v = None
        if v is None or not np.isfinite(v) or v < 0:
            raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
        return v
    return parse


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=_nonneg(float), default=2.0,
                    help="minimum measuring time per rate (default 2)")
    ap.add_argument("--min-resets-per-env", type=_nonneg(float), default=1.0,
                    help="each env rate's window also lasts until this many resets per env were seen (default 1)")
    ap.add_argument("--num-envs", type=_num_envs, default=DEFAULT_NUM_ENVS,
                    help="comma-separated vector sizes (default 1,16,64,256,1024,4096)")
    ap.add_argument("--memory-envs", type=_nonneg(int), default=1024,
                    help="vector size for the resident-memory check, 0 skips it (default 1024)")
    ap.add_argument("--skip-main-job", action="store_true", help="do not time the main job (a few minutes: once "
                    "cold, then --main-job-runs times warm)")
    ap.add_argument("--main-job-runs", type=_nonneg(int), default=3,
                    help="warm runs of the main job, the median reported (default 3)")
    ap.add_argument("--only-main-job", action="store_true", help="time the main job only (no env rates)")
    ap.add_argument("--skip-import", action="store_true", help="do not time the first import (fresh interpreters)")
    ap.add_argument("--profile", action="store_true", help="also print a cProfile of the single and vector env")
    ap.add_argument("--markdown", action="store_true", help="print the results as docs/speed.md's table")
    ap.add_argument("--json", metavar="FILE", help="also write the results to FILE as JSON")
    args = ap.parse_args(argv)
    T, mr = args.seconds, args.min_resets_per_env
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731

    results = {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
               "commit": _git_commit(), "cpus": os.cpu_count(), "versions": _versions(), "seconds": T,
               "min_resets_per_env": mr, "argv": _shown_argv(sys.argv[1:] if argv is None else argv),
               "load_start": os.getloadavg()[0]}
    if args.only_main_job:
        log("main job ...")
        results["main_job"] = main_job(args.main_job_runs)
        _print_extras(results, markdown=args.markdown)
        if args.json:
            Path(args.json).write_text(json.dumps(results, indent=1))
        return results
    log("single envs ...")
    results["cartpole_single"] = bench_single("CartPole-v1", T, min_resets=int(np.ceil(mr)))
    results["single"] = bench_single("RadarTrack-v0", T, min_resets=int(np.ceil(mr)))
    results["vector"] = {}
    for n in args.num_envs:
        log(f"vector envs, num_envs={n} ...")
        results["vector"][n] = (bench_vector(n, T, mr), bench_cartpole_vector(n, T, mr))
    log("Tracker.step ...")
    results["tracker"] = bench_tracker(1024, T)
    if not args.skip_main_job:
        log("main job ...")
        results["main_job"] = main_job(args.main_job_runs)
    if not args.skip_import:
        log("first import (fresh interpreters) ...")
        results["import"] = import_times()
    if args.memory_envs:
        log(f"memory at {args.memory_envs} envs ...")
        results["memory"] = dict(vector_memory(args.memory_envs), num_envs=args.memory_envs)

    results["load_end"] = os.getloadavg()[0]
    (print_markdown if args.markdown else print_text)(results)
    if args.json:
        def enc(o):
            return o.__dict__ if isinstance(o, Rate) else str(o)
        out = dict(results, vector={str(k): v for k, v in results["vector"].items()})
        Path(args.json).write_text(json.dumps(out, default=enc, indent=1))
    if args.profile:
        profile()
    return results


if __name__ == "__main__":
    main()
