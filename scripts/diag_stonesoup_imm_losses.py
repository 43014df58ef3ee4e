"""Diagnostics for the learned IMM's losses in the multi-target Stone Soup example (policy_imm_bp lost targets in
turns that imm_cv_ct keeps; docs/stonesoup.md, "Why the learned IMM lost targets in the example").

* :func:`main`: per track, which truth's plot it took look by look (letters: truths by start x; c: clutter; .:
  none) and the OSPA (``python scripts/diag_stonesoup_imm_losses.py [seed]``);
* :func:`single_target`: each truth alone (its own plots only), the same initiator, gate and deleter;
* :func:`turns`: each truth's turning scans;
* :func:`episodes_of`, :func:`evaluation_errors`: the truths as our episodes, our start, no gate: position RMSE;
* :func:`ungated`: the Stone Soup pair on one truth's plots from the initiator's start, every plot associated or,
  with ``gate``, a plot beyond it taken as a missed look: per look the plot's Mahalanobis distance, the error and
  the prediction's position std;
* :func:`plot_distances`, :func:`summary`: the distances of every plot from our start (no gate);
* :func:`component_rmse`: the learned IMM's position RMSE through the pair on episodes (no gate).

Run with ``PYTHONPATH=.`` from the repository; the tuned coast is ``learned_pair(model, "tuned")``."""
import math
import sys
import numpy as np
from baselines import stonesoup_example as ex
from baselines.stonesoup_components import EPOCH
from stonesoup.types.detection import Clutter, TrueDetection


def labels(truths):
    order = sorted(truths, key=lambda p: float(p.states[0].state_vector[0]))     # by start x: stable labels
    return {p.id: "ABCDEFGH"[i] for i, p in enumerate(order)}


def track_log(tracks, lab, t0=EPOCH):
    rows = []
    for tr in sorted(tracks, key=lambda t: t.states[0].timestamp):
        s = []
        for st in tr.states:
            h = getattr(st, "hypothesis", None)
            m = getattr(h, "measurement", None) if h is not None and h else None
            if m is None:
                s.append(".")
            elif isinstance(m, TrueDetection):
                s.append(lab[m.groundtruth_path.id])
            elif isinstance(m, Clutter):
                s.append("c")
            else:
                s.append("?")
        ts = (tr.states[0].timestamp - t0).total_seconds()
        te = (tr.states[-1].timestamp - t0).total_seconds()
        rows.append((ts, te, "".join(s)))
    return rows


def main(seed=7, names=("imm_cv_ct", "policy_imm_bp"), extra=None, steps=80):
    truths, scans, _ = ex.scenario(steps, seed, range_rate=True)
    lab = labels(truths)
    out = {}
    for n in names:
        comps = extra[n]() if extra and n in extra else None
        tracks = ex.run_tracker(scans, n, comps)
        t, v = ex.ospa(tracks, truths)
        print(f"== {n}: OSPA mean {v.mean():.0f} m, {len(tracks)} tracks")
        for ts, te, s in track_log(tracks, lab):
            print(f"  {ts:5.0f}-{te:5.0f} s  {s}")
        out[n] = tracks
    return truths, scans, out


if __name__ == "__main__":
    from agents.policies.stonesoup_learned import learned_pair, bundled_learned_imm
    from agents.policies.stonesoup_chain import PlotAwareHypothesiser
    m = bundled_learned_imm()
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 7
    main(seed, extra={"policy_imm_bp": lambda: (*learned_pair(m), PlotAwareHypothesiser)})


def single_target(seed=7, names=("imm_cv_ct", "policy_imm_bp"), extra=None, steps=80):
    """Each truth alone: its own plots only (no clutter, no other target), the same initiator, gate and deleter."""
    truths, scans, _ = ex.scenario(steps, seed, range_rate=True)
    lab = labels(truths)
    for p in sorted(truths, key=lambda p: p.id):
        own = [(t, {d for d in ds if isinstance(d, TrueDetection) and d.groundtruth_path.id == p.id})
               for t, ds in scans]
        for n in names:
            comps = extra[n]() if extra and n in extra else None
            tracks = ex.run_tracker(own, n, comps)
            t, v = ex.ospa(tracks, {p})
            print(f"{lab[p.id]} {n:14s} OSPA {v.mean():5.0f} m, {len(tracks)} tracks: "
                  + "  ".join(f"{a:.0f}-{b:.0f}" for a, b, _ in track_log(tracks, lab)))


def turns(seed=7, steps=80):
    """Per truth, per scan: R / L turning (heading change > 1 deg per scan), '-' straight."""
    truths, _, _ = ex.scenario(steps, seed, range_rate=True)
    lab = labels(truths)
    for p in sorted(truths, key=lambda p: p.id):
        v = np.array([[float(s.state_vector[1]), float(s.state_vector[3])] for s in p.states])
        hd = np.degrees(np.unwrap(np.arctan2(v[:, 1], v[:, 0])))
        d = np.diff(hd)
        print(lab[p.id], "".join("L" if x > 1 else "R" if x < -1 else "-" for x in d))


def episodes_of(seed=7, steps=80):
    """Each truth of the example with its own plots as one of our Episodes (missed looks where it has no plot): the
    example's data in our evaluation's form (our start: two-hit + warm-up; no gate, no association)."""
    from baselines.stonesoup_components import look_from_detection
    from radar_env.sim.episode import Episode
    truths, scans, _ = ex.scenario(steps, seed, range_rate=True)
    lab = labels(truths)
    eps = []
    for p in sorted(truths, key=lambda p: lab[p.id]):
        by_t = {s.timestamp: s for s in p.states}
        t, tru, looks = [], [], []
        for ts, ds in scans:
            own = [d for d in ds if isinstance(d, TrueDetection) and d.groundtruth_path.id == p.id]
            s = by_t[ts].state_vector
            t.append((ts - EPOCH).total_seconds())
            tru.append([float(s[0]), float(s[2]), float(s[1]), float(s[3])])
            looks.append(look_from_detection(own[0]) if own else None)
        K = len(t)
        g = lambda f, shape=(): np.array([lk[f] if lk else np.full(shape, np.nan) for lk in looks], dtype=float)
        site = np.zeros((K, 2))
        det = np.array([lk is not None for lk in looks])
        eps.append(Episode(name=f"ss{seed}_{lab[p.id]}", t_s=np.array(t), site_index=np.zeros(K, int), site_xy_m=site,
                           truth=np.array(tru), truth_accel_m_s2=np.zeros((K, 2)), truth_turn_rate_rad_s=np.zeros(K),
                           maneuvering=np.zeros(K, bool), detected=det, range_m=g("range_m"),
                           bearing_rad=g("bearing_rad"), radial_velocity_m_s=g("radial_velocity_m_s"),
                           z_m=g("z_m", (2,)), R_m2=g("R_m2", (2, 2)), range_noise_std_m=np.full(K, 50.0),
                           bearing_noise_std_rad=np.full(K, math.radians(0.1)),
                           radial_velocity_noise_std_m_s=np.full(K, ex.RDOT_STD_M_S)))
    return eps


def evaluation_errors(eps):
    """Position errors of imm_cv_ct and policy_imm_bp on ``eps`` from our start (no gate): per episode and look."""
    from baselines.imm_cv_ct_runner import run_imm_cv_ct, tuned_imm_cv_ct_spec
    from agents.policies.stonesoup_learned import bundled_learned_imm
    runs = {"imm_cv_ct": run_imm_cv_ct(eps, tuned_imm_cv_ct_spec("imm_cv_ct")),
            "policy_imm_bp": bundled_learned_imm().run(eps)}
    for b, e in enumerate(eps):
        line = [e.name]
        for n, r in runs.items():
            k0 = int(r.start_index[b])
            err = np.linalg.norm(r.x[b, k0:, :2] - e.truth[k0:, :2], axis=1)
            d = r.x[b, k0:, :2] - e.truth[k0:, :2]
            nees = np.einsum("ki,kij,kj->k", d, np.linalg.inv(r.P[b, k0:, :2, :2]), d)
            line.append(f"{n}: rmse {np.sqrt(np.mean(err**2)):.0f} m, max {err.max():.0f} m, "
                        f"looks with pos NEES > 25: {int((nees > 25).sum())}")
        print("  ".join(line))
    return runs


def ungated(seed=7, label="A", steps=80, start_state=None, pair=None, gate=None):
    """The learned IMM through the Stone Soup pair on one truth's own plots, every plot associated (no gate): from
    the initiator's third EKF update (as in the example) unless ``start_state`` is given. Per look: (t, detected,
    Mahalanobis distance of the plot under the plot-aware prediction, position error)."""
    from stonesoup.measures import Mahalanobis
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.detection import MissedDetection
    from stonesoup.types.track import Track
    from agents.policies.stonesoup_learned import learned_pair
    truths, scans, _ = ex.scenario(steps, seed, range_rate=True)
    lab = labels(truths)
    p = [q for q in truths if lab[q.id] == label][0]
    by_t = {s.timestamp: s for s in p.states}
    own = [(t, [d for d in ds if isinstance(d, TrueDetection) and d.groundtruth_path.id == p.id]) for t, ds in scans]
    predictor, updater = pair or learned_pair()
    if start_state is None:      # the initiator's EKF start on the first three plots
        init = ex._initiator()
        for t, ds in own:
            tr = init.initiate(set(ds), t)
            if tr:
                start_state = next(iter(tr)).state
                break
    track = Track([start_state])
    rows = []
    for t, ds in own:
        if t <= start_state.timestamp:
            continue
        if ds:
            pred = predictor.predict(track, timestamp=t, measurement=ds[0])
            mp = updater.predict_measurement(pred, measurement_model=ds[0].measurement_model)
            dist = Mahalanobis().__call__(mp, ds[0])
            if gate is not None and dist > gate:       # gated out: the tracker's missed look
                pred = predictor.predict(track, timestamp=t)
                post = updater.update(SingleHypothesis(pred, MissedDetection(timestamp=t)))
            else:
                post = updater.update(SingleHypothesis(pred, ds[0]))
        else:
            pred = predictor.predict(track, timestamp=t)
            dist = float("nan")
            post = updater.update(SingleHypothesis(pred, MissedDetection(timestamp=t)))
        track.append(post)
        s = by_t[t].state_vector
        err = math.hypot(float(post.state_vector[0] - s[0]), float(post.state_vector[2] - s[2]))
        sd = float(np.sqrt(np.trace(np.asarray(pred.covar)[np.ix_([0, 2], [0, 2])])))
        rows.append(((t - EPOCH).total_seconds(), bool(ds), dist, err, sd))
    return rows


def plot_distances(eps, which="policy_imm_bp", start="ours"):
    """Mahalanobis distances (bearing, range, range rate) of every detected plot of ``eps`` under the tracker's
    prediction (the learned IMM: made given that plot, the plot-aware gate), every plot associated (no gate), from
    our start (``start="ours"``) or, for the example's episodes, nothing else. Returns one array per episode."""
    from stonesoup.measures import Mahalanobis
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.detection import MissedDetection
    from stonesoup.types.track import Track
    from baselines import stonesoup_components as S
    from baselines.imm_cv_ct_runner import common_start, tuned_imm_cv_ct_spec
    from agents.policies.stonesoup_learned import learned_pair, track_starts, bundled_learned_imm
    m = bundled_learned_imm()
    if which == "policy_imm_bp":
        predictor, updater = learned_pair(m)
        states, k0 = track_starts(eps, m)
    else:
        predictor = S.IMMCVCTPredictor(spec=tuned_imm_cv_ct_spec("imm_cv_ct"))
        updater = S.IMMCVCTUpdater(use_range_rate=False)
        _, k0, x, P = common_start(eps, m.cfg)
        states = [S.gaussian_state(x[b], P[b], e.t_s[k0[b]]) for b, e in enumerate(eps)]
    out = []
    for b, e in enumerate(eps):
        dets = S.detections_from_episode(e, radial_velocity=True)
        track, ds = Track([states[b]]), []
        for k in range(int(k0[b]) + 1, e.n_looks):
            t = S.stamp(e.t_s[k])
            d = dets[k]
            if d is not None:
                pred = predictor.predict(track, timestamp=t, **({"measurement": d} if which == "policy_imm_bp" else {}))
                ds.append(Mahalanobis()(updater.predict_measurement(pred, measurement_model=d.measurement_model), d))
                track.append(updater.update(SingleHypothesis(pred, d)))
            else:
                pred = predictor.predict(track, timestamp=t)
                track.append(updater.update(SingleHypothesis(pred, MissedDetection(timestamp=t))))
        out.append(np.array(ds))
    return out


def summary(dists, name):
    d = np.concatenate(dists)
    print(f"{name:40s} plots {d.size:5d}  mean d^2 {np.mean(d**2):5.2f} (3 if consistent)  > 3: "
          f"{100 * np.mean(d > 3):4.1f} %  99th pct {np.percentile(d, 99):5.2f}  max {d.max():5.2f}")


def component_rmse(eps, pair=None, model=None):
    """Position RMSE (over looks after our start) of the learned IMM through the Stone Soup pair on ``eps``, every
    plot associated (no gate), missed looks as bare ``MissedDetection`` updates; ``pair`` default ``learned_pair``."""
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.detection import MissedDetection
    from stonesoup.types.track import Track
    from baselines import stonesoup_components as S
    from agents.policies.stonesoup_learned import learned_pair, track_starts, bundled_learned_imm
    model = model or bundled_learned_imm()
    predictor, updater = pair or learned_pair(model)
    states, k0 = track_starts(eps, model)
    se, n, se_after_miss, n_after_miss = 0.0, 0, 0.0, 0
    for b, e in enumerate(eps):
        dets = S.detections_from_episode(e, radial_velocity=True)
        track = Track([states[b]])
        for k in range(int(k0[b]) + 1, e.n_looks):
            t = S.stamp(e.t_s[k])
            d = dets[k]
            pred = predictor.predict(track, timestamp=t)
            track.append(updater.update(SingleHypothesis(pred, d if d is not None else MissedDetection(timestamp=t))))
            x = np.asarray(track.state.state_vector, dtype=float).ravel()
            err2 = (x[0] - e.truth[k, 0]) ** 2 + (x[2] - e.truth[k, 1]) ** 2
            se, n = se + err2, n + 1
            if not e.detected[k - 1] or not e.detected[k]:
                se_after_miss, n_after_miss = se_after_miss + err2, n_after_miss + 1
    return math.sqrt(se / n), math.sqrt(se_after_miss / max(n_after_miss, 1)), n, n_after_miss
