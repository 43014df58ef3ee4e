r"""The learned IMM: imm_cv_ct whose per-look parameters a causal network sets, run in numpy + numba.

``imm_cv_ct`` (:mod:`baselines.imm_cv_ct_runner`: a CV mode, a CT-EKF mode with the turn rate in its state, a high-noise
CV mode) holds its mode-switch probabilities and its modes' process noise constant. Here a GRU sets them at every
look (:data:`baselines.imm_cv_ct_runner.LOOK_PARAMS`: ``q_cv_g``, ``q_ct_g``, ``sigma_omega_deg_s15``, ``p_stay_cv``,
``p_stay_ct``, ``q_high_g``, ``p_stay_high``); the turn rate stays in the filter's state, estimated by the filter.

Per look ``k`` of a row (the parameters of look ``k`` are chosen before look ``k`` is filtered)::

    input_k  = [ obs_{k-1} , detectors_{k-1} ]
               obs: the env's observation after look k-1 (RadarTrack-v0's features, incl. the preview of plot k),
                    from the env's own chain (radar_env.filters.tracking.Tracker at the constant q feature_q_g, encoded by
                    radar_env.envs.observation.ObservationLayout, exactly as the env computes it)
               detectors: the IMM's own output after look k-1 -- mode probabilities mu (M), combined turn rate
                    omega / (20 deg/s), log10(its std in deg/s) / 3 (:func:`detector_inputs`)
    h_k      = GRU(input_k, h_{k-1})                         (h = 0 at the track start)
    delta_k  = W_out head(h_k) + b_out                       (W_out, b_out initialised to 0)
    s_k,i    = L_i + (H_i - L_i) sigmoid(u0_i + delta_k,i)   (ParamMap: u0_i puts s at the tuned value)
    param_i  = exp(s) for a noise (log space), sigmoid(s) for a stay probability (logit space)
    IMM look k with param_k  ->  estimate, mode probabilities, omega, its std (the detectors of look k)

``[L_i, H_i]`` is the parameter's :data:`baselines.imm_cv_ct_runner.IMM_CV_CT_PARAMS` range in log (noises) or logit
(probabilities) space, so every output is inside the documented range whatever the network does; the offsets
``delta`` move each parameter in that space from ``imm_cv_ct``'s tuned constant (``baselines/tuned.json``, recorded
in the checkpoint). With the last layer at zero the learned IMM *is* imm_cv_ct with its tuned values (tested to
1e-9). ``sigma_omega0_deg_s`` (the turn-rate prior at a turn's onset) and the turn-rate bound stay constants.

The same computation in torch, differentiable, trains it (:mod:`agents.training.learned_imm`); this module runs a
checkpoint with numpy (the GRU) and the compiled per-look kernel (:class:`baselines.imm_cv_ct_runner.IMMCVCTStepper`),
equal to the torch forward to 1e-9 (tests/test_learned_imm.py), with no torch.

A checkpoint is a folder: ``policy.npz`` (the weights, float64; read with ``np.load(allow_pickle=False)``, which
runs no code, unlike a pickle), ``policy.json`` (format, architecture, input features, the base parameters, the
feature chain's q) and ``env_config.json`` (the ``RadarTrack-v0`` arguments of its observation and training flights).
The bundled seed is ``agents/bundled/learned_imm/`` (tracker ``policy_imm_bp`` in the evaluation).
"""

from __future__ import annotations

import math

import numpy as np

from baselines.imm_cv_ct_runner import (IMM_CV_CT_PARAMS, imm_cv_ct_spec_from_params, look_parameter_names,
                                        run_imm_lockstep)
from baselines.trackers import observation_layout
from radar_env.envs.config import EnvConfig
from radar_env.filters.imm_cv_ct import detector_inputs, detector_names, initial_detectors  # noqa: F401 (re-exported)
from radar_env.common.units import G0_M_S2

from agents.policies.bundle import BUNDLED_LEARNED_IMM
from agents.policies.checks import env_kwargs_from_json
from agents.policies.recurrent import gru_cell, layer_weights, linear, weight_shapes as recurrent_shapes

__all__ = ["FORMAT", "VERSION", "POLICY_FILE", "BUNDLED_LEARNED_IMM", "ParamMap", "detector_inputs",
           "detector_names", "initial_detectors", "weight_shapes", "LearnedIMM", "save_learned_imm", "load_learned_imm",
           "is_learned_imm_checkpoint", "run_learned_imm", "run_bundled_learned_imm"]

FORMAT = "radar-track-learned-imm"
VERSION = 1
POLICY_FILE = "policy.npz"



# ------------------------------------------------------------------------------------------------ outputs
class ParamMap:
    """Network offsets ``delta (..., n_par)`` -> per-look parameters, bounded to their documented ranges.

    Args:
        base: ``{name: value}`` of every name in ``names`` (the tuned constants: where ``delta = 0`` maps to).
        names: the parameters, :func:`baselines.imm_cv_ct_runner.look_parameter_names` of the spec.
    Attributes: ``log_space`` (n_par,) bool (True: a noise, log space; False: a stay probability, logit space),
    ``L``, ``H``, ``u0`` (n_par,): the range in that space and the offset origin.
    """

    def __init__(self, base, names):
        self.names = tuple(names)
        info = {n: (lo, hi, log) for n, _, lo, hi, log in IMM_CV_CT_PARAMS}
        self.log_space = np.array([info[n][2] for n in self.names])
        self.lo = np.array([info[n][0] for n in self.names], dtype=np.float64)
        self.hi = np.array([info[n][1] for n in self.names], dtype=np.float64)
        v = np.array([float(base[n]) for n in self.names])
        if np.any(~(v > self.lo) | ~(v < self.hi)):
            raise ValueError(f"ParamMap: base values must lie strictly inside their ranges, got {dict(zip(names, v))}")
        T = lambda p: np.array([math.log(v) if log else math.log(v) - math.log1p(-v)   # noqa: E731 log / logit
                                for v, log in zip(p, self.log_space)])
        self.L, self.H, s0 = T(self.lo), T(self.hi), T(v)
        r = (s0 - self.L) / (self.H - self.L)
        self.u0 = np.log(r) - np.log1p(-r)
        self.base = v

    def transformed(self, delta, xp=np, consts=None):
        """``s = L + (H - L) sigmoid(u0 + delta)`` (log or logit of each parameter); ``xp``: ``numpy`` or
        ``torch`` (then ``consts = self.tensors(torch)``)."""
        L, H, u0 = (self.L, self.H, self.u0) if consts is None else consts
        return L + (H - L) * (0.5 + 0.5 * xp.tanh(0.5 * (u0 + delta)))

    def tensors(self, torch):
        """``(L, H, u0)`` as float64 tensors (for :meth:`transformed` in torch)."""
        return tuple(torch.as_tensor(a, dtype=torch.float64) for a in (self.L, self.H, self.u0))

    def physical(self, delta):
        """numpy ``delta (..., n_par)`` -> the parameters in their units (g, deg/s^1.5, probabilities), clipped to
        the ranges (which only rounding can leave)."""
        s = self.transformed(np.asarray(delta, dtype=np.float64))
        p = np.where(self.log_space, np.exp(s), 0.5 + 0.5 * np.tanh(0.5 * s))
        return np.clip(p, self.lo, self.hi)


# ------------------------------------------------------------------------------------------------ the network
def weight_shapes(arch):
    """``{name: shape}`` of the weights for ``arch`` (``input_size``: observation + detectors, ``hidden_size``,
    ``head``: tanh layer widths, ``n_par``): the recurrent q-policy's network with ``n_par`` outputs."""
    return recurrent_shapes({**arch, "n_out": arch["n_par"]})


class LearnedIMM:
    """A learned IMM checkpoint, ready to run (numpy GRU + the numba per-look IMM kernel).

    Args:
        weights: ``{name: array}`` (:func:`weight_shapes`). config: the ``policy.json`` dict. env_kwargs: the
            ``RadarTrack-v0`` arguments (its observation's features, q levels and track start).
    """

    is_tracker = True
    """It runs episodes itself (:meth:`run`), unlike a q-policy (the evaluation's runner asks)."""

    def __init__(self, weights, config, env_kwargs):
        self.config, self.env_kwargs = config, dict(env_kwargs)
        self.arch = config["architecture"]
        self.w = layer_weights(weights)
        want = weight_shapes(self.arch)
        got = {k: v.shape for k, v in self.w.items()}
        if got != {k: tuple(v) for k, v in want.items()}:
            raise ValueError(f"learned IMM weights do not match the architecture {self.arch}: got {got}, need {want}")
        self.spec = imm_cv_ct_spec_from_params(config["base_parameters"])
        self.names = look_parameter_names(self.spec)
        if tuple(config["parameters"]) != self.names:
            raise ValueError(f"policy.json parameters {config['parameters']} != {list(self.names)}")
        self.pmap = ParamMap(config["base_parameters"], self.names)
        self.cfg = EnvConfig.from_kwargs(**env_kwargs_from_json(self.env_kwargs))
        self.feature_q_m_s2 = float(config["feature_q_g"]) * G0_M_S2
        self.layout, _ = observation_layout(self.cfg)
        n_in = len(self.cfg.features) + len(detector_names(self.spec))
        if self.arch["input_size"] != n_in or tuple(config["input_features"]) != tuple(self.cfg.features):
            raise ValueError(f"policy.json: input_size {self.arch['input_size']} / features do not match the env's "
                             f"{len(self.cfg.features)} features + {n_in - len(self.cfg.features)} detectors")

    def offsets(self, inputs, h):
        """``(delta (n, n_par), h' (n, H))`` of the network for ``inputs (n, F)``."""
        w = self.w
        h = gru_cell(inputs, h, w["gru.weight_ih"], w["gru.weight_hh"], w["gru.bias_ih"], w["gru.bias_hh"])
        y = h
        for i in range(len(self.arch["head"])):
            y = np.tanh(linear(y, w[f"head.{i}.weight"]) + w[f"head.{i}.bias"])
        return linear(y, w["out.weight"]) + w["out.bias"], h

    def run(self, episodes, name="policy_imm_bp"):
        """The learned IMM on ``episodes`` from the common track start: a :class:`baselines.trackers.TrackRun`
        (x, P combined; extra series ``maneuver_probability``, ``turn_rate_deg_s`` and each parameter as
        ``param_<name>``; declared = maneuver probability > 0.5), through
        :func:`baselines.imm_cv_ct_runner.run_imm_lockstep` with the GRU choosing the parameters."""
        episodes = list(episodes)
        h = np.zeros((len(episodes), self.arch["hidden_size"]))

        def choose(obs, det, rows):
            delta, h[rows] = self.offsets(np.concatenate([obs.astype(np.float64), det], 1), h[rows])
            return self.pmap.physical(delta)

        return run_imm_lockstep(episodes, choose, self.cfg, self.spec, self.feature_q_m_s2, name)


def save_learned_imm(directory, weights, config, env_kwargs):
    """Write a checkpoint folder (module docstring); returns the ``policy.npz`` path."""
    from agents.policies.layout import write_weights_folder     # kind: agents.policies.learned
    return write_weights_folder(directory, "learned_imm_gru", FORMAT, VERSION, weights, config, env_kwargs)


def is_learned_imm_checkpoint(path):
    """Whether ``path`` (a ``policy.npz`` or its folder) is a learned IMM checkpoint (its ``policy.json`` says so)."""
    from agents.policies.checks import manifest_format
    return manifest_format(path) == FORMAT


def load_learned_imm(path) -> LearnedIMM:
    """A :class:`LearnedIMM` from a checkpoint folder or its ``policy.npz`` (no pickle), checked by the one
    validation path (:mod:`agents.policies.checks`) before anything runs. ``ValueError`` (one line, naming the file
    and the field) for a missing or malformed checkpoint; a file other than the folder's ``policy.npz`` is refused."""
    from agents.policies import checks
    from agents.policies.recurrent import _checked_shapes
    d, config, env_file, npz = checks.open_weights_folder(path, "a learned IMM checkpoint", FORMAT, VERSION)
    if config.get("model", "imm_cv_ct") != "imm_cv_ct":
        raise ValueError(f"{d / 'policy.json'}: field 'model' is {config.get('model')!r}; a learned IMM runs the "
                         "'imm_cv_ct' model")
    meta_file = d / "policy.json"
    arch = config.get("architecture")
    n_par = arch.get("n_par") if isinstance(arch, dict) else None
    if not isinstance(n_par, int) or isinstance(n_par, bool) or not 0 < n_par <= 64:
        raise ValueError(f"{meta_file}: field 'architecture.n_par' must be a positive int, got {n_par!r}")
    shapes = _checked_shapes(meta_file, {**arch, "n_out": n_par})
    base = config.get("base_parameters")
    if not isinstance(base, dict) or not base:
        raise ValueError(f"{meta_file}: field 'base_parameters' must be an object of the IMM's parameters")
    checks.check_finite_numbers(meta_file, base, "base_parameters")
    checks.check_finite_numbers(meta_file, config.get("feature_q_g"), "feature_q_g")
    if not config["feature_q_g"] > 0:
        raise ValueError(f"{meta_file}: field 'feature_q_g' must be > 0, got {config['feature_q_g']!r}")
    for field in ("parameters", "input_features"):
        v = config.get(field)
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise ValueError(f"{meta_file}: field {field!r} must be a list of names, got {v!r}"[:300])
    weights = checks.read_npz(npz)
    checks.check_weights(npz, weights, shapes)
    env_kwargs, _ = checks.check_env_config(env_file)
    try:
        return LearnedIMM(weights, config, env_kwargs)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{meta_file}: {msg}"[:400]) from None


def run_learned_imm(episodes, path, name="policy_imm_bp"):
    """The learned IMM of checkpoint ``path`` on ``episodes`` (a :class:`baselines.trackers.TrackRun`)."""
    return load_learned_imm(path).run(episodes, name)


def run_bundled_learned_imm(episodes, cfg=None):
    """The tracker ``policy_imm_bp``: the bundled seed (:data:`BUNDLED_LEARNED_IMM`). ``cfg`` is ignored: the
    checkpoint carries its own track start and observation."""
    if not BUNDLED_LEARNED_IMM.is_file():
        raise ValueError(f"policy_imm_bp: no bundled learned IMM at {BUNDLED_LEARNED_IMM}")
    return run_learned_imm(episodes, BUNDLED_LEARNED_IMM)

