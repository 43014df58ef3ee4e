"""A small multi-target example in Stone Soup: maneuvering targets, a polar radar with missed detections and clutter,
GNN association, tracks started and deleted by Stone Soup, filtered once by Stone Soup's extended Kalman filter
(constant velocity) and once by our ``imm_cv_ct`` (:mod:`baselines.stonesoup_components`); OSPA over time.

``python -m baselines.stonesoup_example`` prints the table and saves ``docs/figures/stonesoup_multitarget.png``
(``--help`` for the options). Everything but the filter is the same in every run: the same truths and scans (one
draw, replayed), the same initiator (a three-plot start with Stone Soup's EKF, so the IMM receives a confirmed
track's EKF state and starts its modes there), the same hypothesiser gate and deleter.

Scenario (Stone Soup's simulators): ``SwitchMultiTargetGroundTruthSimulator`` switching each target between
constant velocity and coordinated turns of +-3 deg/s (about 1 g at 200 m/s), a few targets at 40 to 80 km from a
radar at the origin; ``SimpleDetectionSimulator`` with ``CartesianToBearingRange`` (bearing 0.1 deg, range 50 m),
detection probability 0.9 and uniform clutter in the sector the targets fly in. The EKF is shown at two process
noises (neither tuned: a low one that is good on the straight legs and a high one that follows the turns); the
IMM runs at its tuned parameters (``baselines/tuned.json``), tuned on our single-target suites, not on this.

``--range-rate``: the radar also measures range rate (``CartesianToBearingRangeRate2D``, 1 m/s noise; clutter
uniform in range rate too); the EKFs and ``imm_cv_ct_rdot`` update on it, ``imm_cv_ct`` on the position only (as
it is evaluated); ``run(..., extra=...)`` adds other predictor/updater pairs (``python -m
agents.policies.stonesoup_learned`` adds the learned IMM and the learned q-policy this way).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
from pathlib import Path

import numpy as np

from .imm_cv_ct_runner import tuned_imm_cv_ct_spec
from .stonesoup_components import EPOCH, IMMCVCTPredictor, IMMCVCTUpdater

from stonesoup.base import Property  # noqa: E402
from stonesoup.buffered_generator import BufferedGenerator  # noqa: E402
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment  # noqa: E402
from stonesoup.deleter.time import UpdateTimeStepsDeleter  # noqa: E402
from stonesoup.hypothesiser.distance import DistanceHypothesiser  # noqa: E402
from stonesoup.initiator.simple import MultiMeasurementInitiator  # noqa: E402
from stonesoup.measures import Euclidean, Mahalanobis  # noqa: E402
from stonesoup.metricgenerator.manager import MultiManager  # noqa: E402
from stonesoup.metricgenerator.ospametric import OSPAMetric  # noqa: E402
from stonesoup.models.base import ReversibleModel  # noqa: E402
from stonesoup.models.measurement.nonlinear import (  # noqa: E402
    CartesianToBearingRange, CartesianToBearingRangeRate2D)
from stonesoup.models.transition.linear import (  # noqa: E402
    CombinedLinearGaussianTransitionModel, ConstantVelocity, KnownTurnRate)
from stonesoup.predictor.kalman import KalmanPredictor  # noqa: E402
from stonesoup.reader.base import DetectionReader  # noqa: E402
from stonesoup.simulator.simple import SimpleDetectionSimulator, SwitchMultiTargetGroundTruthSimulator  # noqa: E402
from stonesoup.tracker.simple import MultiTargetTracker  # noqa: E402
from stonesoup.types.array import CovarianceMatrix, StateVector  # noqa: E402
from stonesoup.types.state import GaussianState  # noqa: E402
from stonesoup.updater.kalman import ExtendedKalmanUpdater  # noqa: E402

from radar_env.common.units import DEG  # noqa: E402

FIGURE = Path(__file__).resolve().parents[1] / "docs" / "figures" / "stonesoup_multitarget.png"
SCAN_S = 5.0
EKF_Q = (0.5, 20.0)
"""The EKF's process noises (Stone Soup's ConstantVelocity ``noise_diff_coeff``, m^2/s^3)."""
RDOT_STD_M_S = 1.0
"""The range-rate noise with ``range_rate`` (m/s; Bizup's radar: 2 kt)."""
OSPA_C_M, OSPA_P = 2000.0, 1
GATE = 3.0        # Mahalanobis distance (the hypothesiser's missed_distance)


class _Replay(DetectionReader):
    """Replays recorded scans ``[(time, detections)]``, so every tracker sees the same draw."""

    scans: list = Property(doc="[(datetime, set of detections)]")

    @BufferedGenerator.generator_method
    def detections_gen(self):
        yield from self.scans


class BearingRangeRate(CartesianToBearingRangeRate2D, ReversibleModel):
    """Stone Soup's ``CartesianToBearingRangeRate2D`` with the position inverse of ``CartesianToBearingRange`` (the
    velocity 0), so that Stone Soup's measurement initiators accept its detections."""

    def inverse_function(self, detection, **kwargs):
        phi, rho = float(detection.state_vector[0]), float(detection.state_vector[1])
        out = StateVector(np.zeros((self.ndim_state, 1)))
        site = np.asarray(self.translation_offset, dtype=np.float64).ravel()
        out[self.mapping[0], 0] = rho * math.cos(phi) + site[0]
        out[self.mapping[1], 0] = rho * math.sin(phi) + site[1]
        return out


def scenario(n_steps=80, seed=7, n_targets=4, detection_probability=0.9, clutter_rate=3.0, range_rate=False):
    """One draw of the scenario (module docstring): ``(truths, scans, measurement_model)`` with ``truths`` the
    ground-truth paths, ``scans`` ``[(time, set of detections)]`` (real and clutter); ``range_rate``: detections
    ``[bearing, range, range rate]`` (:class:`BearingRangeRate`)."""
    rng = np.random.default_rng(seed)
    # every model that draws noise gets its own seed (a model without one draws from numpy's global generator)
    cv = CombinedLinearGaussianTransitionModel([ConstantVelocity(0.01), ConstantVelocity(0.01)], seed=seed + 1)
    turns = [KnownTurnRate(turn_noise_diff_coeffs=[0.01, 0.01], turn_rate=s * 3.0 * DEG, seed=seed + i)
             for i, s in ((2, 1), (3, -1))]
    # per scan: stay on a straight leg 0.95, start a turn (either way) 0.05; a turn lasts 10 scans on average
    probs = np.array([[0.95, 0.025, 0.025], [0.1, 0.9, 0.0], [0.1, 0.0, 0.9]])
    starts = []
    for _ in range(n_targets):
        r, b = rng.uniform(40e3, 80e3), rng.uniform(20.0, 70.0) * DEG      # bearing from east (Stone Soup's)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        starts.append(StateVector([r * math.cos(b), 200.0 * math.cos(heading), r * math.sin(b),
                                   200.0 * math.sin(heading)]))
    truth_sim = SwitchMultiTargetGroundTruthSimulator(
        transition_models=[cv] + turns, model_probs=probs,
        initial_state=GaussianState(StateVector([0.0, 0.0, 0.0, 0.0]), CovarianceMatrix(np.eye(4)), EPOCH),
        timestep=_dt.timedelta(seconds=SCAN_S), number_steps=n_steps, birth_rate=0.0, death_probability=0.0,
        preexisting_states=starts, seed=seed)
    if range_rate:
        model = BearingRangeRate(ndim_state=4, mapping=(0, 2), velocity_mapping=(1, 3),
                                 noise_covar=CovarianceMatrix(np.diag([(0.1 * DEG) ** 2, 50.0 ** 2,
                                                                       RDOT_STD_M_S ** 2])), seed=seed + 4)
        sector = np.array([[0.0, 90.0 * DEG], [20e3, 110e3], [-300.0, 300.0]])   # clutter: + range rate (m/s)
    else:
        model = CartesianToBearingRange(ndim_state=4, mapping=(0, 2),
                                        noise_covar=CovarianceMatrix(np.diag([(0.1 * DEG) ** 2, 50.0 ** 2])),
                                        seed=seed + 4)
        sector = np.array([[0.0, 90.0 * DEG], [20e3, 110e3]])      # clutter: bearing (rad), range (m)
    det_sim = SimpleDetectionSimulator(groundtruth=truth_sim, measurement_model=model, meas_range=sector,
                                       detection_probability=detection_probability, clutter_rate=clutter_rate,
                                       seed=seed)
    scans, truths = [], set()
    for time, detections in det_sim:
        scans.append((time, set(detections)))
        truths |= set(truth_sim.groundtruth_paths)
    return truths, scans, model


def _ekf(q):
    cv = CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])
    return KalmanPredictor(cv), ExtendedKalmanUpdater(measurement_model=None)


def _initiator():
    """A three-plot start with Stone Soup's EKF (the same for every filter): velocity prior 0 +- 300 m/s."""
    predictor, updater = _ekf(EKF_Q[1])
    prior = GaussianState(StateVector([0.0, 0.0, 0.0, 0.0]), CovarianceMatrix(np.diag([0.0, 300.0 ** 2, 0.0,
                                                                                         300.0 ** 2])))
    return MultiMeasurementInitiator(
        prior_state=prior, measurement_model=None, deleter=UpdateTimeStepsDeleter(2),
        data_associator=GNNWith2DAssignment(DistanceHypothesiser(predictor, updater, Mahalanobis(), GATE)),
        updater=updater, min_points=3)


def run_tracker(scans, filter_name, components=None):
    """The tracks of one filter on the replayed ``scans``: ``filter_name`` ``"imm_cv_ct"``, ``"imm_cv_ct_rdot"`` or
    ``"ekf_q<q>"``, or any name with ``components = (predictor, updater)`` (or ``(predictor, updater,
    hypothesiser class)``: the class, e.g. the learned trackers' plot-aware gate, built as the default
    ``DistanceHypothesiser`` is, with the same measure and gate)."""
    hypothesiser = DistanceHypothesiser
    if components is not None:
        predictor, updater, *rest = components
        hypothesiser = rest[0] if rest else hypothesiser
    elif filter_name in ("imm_cv_ct", "imm_cv_ct_rdot"):     # imm_cv_ct: position only, also on range-rate plots
        predictor = IMMCVCTPredictor(spec=tuned_imm_cv_ct_spec(filter_name))
        updater = IMMCVCTUpdater(use_range_rate=filter_name == "imm_cv_ct_rdot")
    elif filter_name.startswith("ekf_q"):
        predictor, updater = _ekf(float(filter_name[5:]))
    else:
        raise ValueError(f"filter_name must be 'imm_cv_ct', 'imm_cv_ct_rdot' or 'ekf_q<q>' (or components given), "
                         f"got {filter_name!r}")
    tracker = MultiTargetTracker(
        initiator=_initiator(), deleter=UpdateTimeStepsDeleter(3), detector=_Replay(scans),
        data_associator=GNNWith2DAssignment(hypothesiser(predictor, updater, Mahalanobis(), GATE)),
        updater=updater)
    tracks = set()
    for _, current in tracker:
        tracks |= current
    return tracks


def ospa(tracks, truths):
    """OSPA (Stone Soup's ``OSPAMetric``, position, c = :data:`OSPA_C_M`, p = :data:`OSPA_P`) per scan:
    ``(t_s (n,), ospa_m (n,))``."""
    metric = OSPAMetric(c=OSPA_C_M, p=OSPA_P, measure=Euclidean(mapping=(0, 2)), generator_name="ospa",
                        tracks_key="tracks", truths_key="truths")
    manager = MultiManager([metric])
    manager.add_data({"tracks": tracks, "truths": truths})
    series = manager.generate_metrics()["ospa"]["OSPA distances"].value
    t = np.array([(m.timestamp - EPOCH).total_seconds() for m in series])
    v = np.array([float(m.value) for m in series])
    order = np.argsort(t)
    return t[order], v[order]


def run(n_steps=80, seed=7, filters=None, range_rate=False, extra=None):
    """The example: ``{filter: {"t_s", "ospa_m", "n_tracks"}}`` plus ``"_truths"`` (the number of targets) and
    ``"_range_rate"``.
    ``extra``: ``{name: make}`` more filters, ``make()`` giving a fresh ``(predictor, updater)`` (or with a
    hypothesiser class, :func:`run_tracker`)."""
    truths, scans, _ = scenario(n_steps, seed, range_rate=range_rate)
    filters = filters or [f"ekf_q{q:g}" for q in EKF_Q] + ["imm_cv_ct"] + (["imm_cv_ct_rdot"] if range_rate else [])
    extra = dict(extra or {})
    out = {"_truths": len(truths), "_range_rate": bool(range_rate)}
    for f in list(filters) + list(extra):
        tracks = run_tracker(scans, f, extra[f]() if f in extra else None)
        t, v = ospa(tracks, truths)
        out[f] = {"t_s": t, "ospa_m": v, "n_tracks": len(tracks)}
    return out


def table(result, every_s=50.0):
    """The OSPA table as text: one row per ``every_s`` seconds, then the mean over the run and the track count."""
    names = [k for k in result if not k.startswith("_")]
    t = result[names[0]]["t_s"]
    lines = ["| t (s) | " + " | ".join(f"{n} OSPA (m)" for n in names) + " |",
             "|---:|" + "---:|" * len(names)]
    for i in np.flatnonzero(np.isclose(np.mod(t, every_s), 0.0)):
        lines.append(f"| {t[i]:.0f} | " + " | ".join(f"{result[n]['ospa_m'][i]:.0f}" for n in names) + " |")
    lines.append("| mean | " + " | ".join(f"{result[n]['ospa_m'].mean():.0f}" for n in names) + " |")
    lines.append("| tracks | " + " | ".join(f"{result[n]['n_tracks']}" for n in names) + " |")
    return "\n".join(lines)


def figure(result, path=FIGURE):
    """OSPA over time, one line per filter, saved to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    for name, r in result.items():
        if not name.startswith("_"):
            ax.plot(r["t_s"], r["ospa_m"], label=f"{name} (mean {r['ospa_m'].mean():.0f} m)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"OSPA (m), c = {OSPA_C_M:g} m, p = {OSPA_P}")
    rr = ", range rate" if result.get("_range_rate") else ""
    ax.set_title(f"{result['_truths']} maneuvering targets, Pd 0.9, clutter{rr}: Stone Soup GNN tracker")
    ax.legend()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None, extra=None, prog="python -m baselines.stonesoup_example", figure_path=FIGURE):
    """The command (``extra``: as :func:`run`)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=80, help="scans (5 s apart), default 80")
    ap.add_argument("--seed", type=int, default=7, help="seed of the truths, detections and clutter, default 7")
    ap.add_argument("--figure", default=str(figure_path), help=f"figure path, default {figure_path}")
    ap.add_argument("--range-rate", action="store_true", help="the radar measures range rate (imm_cv_ct_rdot)")
    ap.add_argument("--no-figure", action="store_true", help="print the table only")
    args = ap.parse_args(argv)
    if args.steps < 5:
        ap.error(f"--steps must be >= 5 (a track needs three plots to start), got {args.steps}")
    result = run(args.steps, args.seed, range_rate=args.range_rate, extra=extra)
    print(table(result))
    if not args.no_figure:
        print(f"figure: {figure(result, args.figure)}")
    return result


if __name__ == "__main__":
    main()
