"""A saved stable-baselines3 policy's deterministic actor in plain numpy: its MLP weights, activations, spaces and
action head, exported once to a ``.npz`` beside the zip and evaluated without torch or stable-baselines3.

Why: the main job asks the policy for q once per look, batched over the runs of a suite (thousands of calls of a
few to a few hundred rows). SB3's ``predict`` costs about a millisecond a call in Python and torch overhead (and
torch's threads fight the other work on a loaded 2-core machine), and importing torch and SB3 costs seconds. The
MLP itself is a few small matrix products.

What is exported (``export_model``), per algorithm, exactly the computation of SB3's ``predict(obs,
deterministic=True)`` (stable-baselines3 2.x):

===========  =====================================================  =================================================
algorithm    layers                                                 action head
===========  =====================================================  =================================================
PPO, A2C     ``mlp_extractor.policy_net`` then ``action_net``       Discrete: ``argmax`` of the softmax probabilities
                                                                    (SB3's Categorical mode); Box: the Gaussian mean,
                                                                    clipped to the action space
DQN          ``q_net.q_net``                                        ``argmax`` of the Q-values
SAC          ``actor.latent_pi`` then ``actor.mu``, ``tanh``        rescaled from [-1, 1] to the action space
TD3          ``actor.mu`` (ends with ``tanh``)                      rescaled from [-1, 1] to the action space
===========  =====================================================  =================================================

Supported: a flattening features extractor (``MlpPolicy``, Box observations), linear layers and the activations
``tanh``, ``relu``, ``elu``, ``leaky_relu``, ``silu`` (the ones ``radar-track train`` offers), no gSDE. Anything
else exports as None and the caller keeps SB3's ``predict``.

Arithmetic: the observation is rounded to float32 as SB3 does, then everything is float64 (the float32 weights are
exact in float64); for a discrete head the float64 probabilities (or Q-values) are rounded to float32 before the
argmax, so that values equal in float32 tie as in SB3 and the first such action wins, as ``torch.argmax`` picks
it. SB3 computes in float32, so a decision can differ only where two actions' float32 probabilities are within
float32 rounding of each other (there SB3's own answer depends on its summation order and thread count);
continuous actions agree with SB3's to float32 rounding. ``check_export`` compares both on sampled observations
at export time; tests/test_numpy_policy.py on the evaluation's own observations.

The ``.npz`` holds only arrays (numbers and strings) and is read with ``np.load(allow_pickle=False)``: unlike the
zip (whose loading unpickles Python objects), reading it runs no code. It records the SHA-256 of the zip it was
exported from; :func:`load_export` ignores an export whose zip has changed since.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

__all__ = ["NumpyPolicy", "export_model", "check_export", "export_path", "zip_sha256", "save_export",
           "load_export", "load_sb3_model", "export_saved", "EXPORT_VERSION", "ACTIVATIONS", "HEADS", "main"]

EXPORT_VERSION = 1
ACTIVATIONS = ("identity", "tanh", "relu", "elu", "leaky_relu", "silu")
"""Activation after a linear layer (``identity``: none). ``elu``'s alpha and ``leaky_relu``'s negative slope are the
layer's ``activation_param``."""
HEADS = ("categorical", "argmax", "clip", "rescale")
"""Action heads: ``categorical`` (argmax of the softmax probabilities), ``argmax`` (of the outputs, DQN),
``clip`` (outputs clipped to the Box: a Gaussian mean), ``rescale`` (outputs in [-1, 1] mapped to the Box)."""


_SINGLE_THREAD_MACS = 1 << 18
"""OpenBLAS runs a matrix product of up to 2^18 multiply-adds on one thread and splits larger ones over threads;
on a loaded 2-core machine those threads made the policy 3-6x slower (CPU time), so :meth:`NumpyPolicy.forward`
multiplies in row blocks of at most this size (16 rows of a 128 x 128 layer)."""


def _activate(h, name, param):
    if name == "tanh":
        return np.tanh(h, out=h)
    if name == "relu":
        return np.maximum(h, 0.0, out=h)
    if name == "elu":
        return np.where(h > 0.0, h, param * np.expm1(np.minimum(h, 0.0)))
    if name == "leaky_relu":
        return np.where(h >= 0.0, h, h * param)
    if name == "silu":
        return h * (0.5 * (1.0 + np.tanh(0.5 * h)))     # x sigmoid(x), without exp overflow
    return h


class NumpyPolicy:
    """The exported deterministic actor: ``predict`` with stable-baselines3's interface, no torch.

    Args:
        arrays: the export (``export_model``'s dict or a loaded ``.npz``): ``W{i}`` (out, in) and ``b{i}`` (out,)
            per layer, ``activation`` (L,) names, ``activation_param`` (L,), ``head``, ``obs_low`` / ``obs_high``
            (the observation Box), ``action_n`` (Discrete) or ``action_low`` / ``action_high`` (Box), ``algo``.
    Raises ``ValueError`` naming what is inconsistent (a damaged or foreign file).
    """

    def __init__(self, arrays):
        from gymnasium import spaces
        a = {k: np.asarray(v) for k, v in dict(arrays).items()}
        try:
            version = int(a["version"])
            self.algo = str(a["algo"])
            self.head = str(a["head"])
            acts = [str(s) for s in a["activation"]]
            params = np.asarray(a["activation_param"], dtype=np.float64)
            n_layers = len(acts)
            self.layers = [(np.asarray(a[f"W{i}"], dtype=np.float64), np.asarray(a[f"b{i}"], dtype=np.float64),
                            acts[i], float(params[i])) for i in range(n_layers)]
            obs_low, obs_high = (np.asarray(a[k], dtype=np.float32) for k in ("obs_low", "obs_high"))
        except KeyError as e:
            raise ValueError(f"policy export: missing array {e.args[0]!r}") from None
        known = {"version", "algo", "head", "activation", "activation_param", "obs_low", "obs_high", "action_n",
                 "action_low", "action_high", "source_sha256", *(f"{w}{i}" for i in range(n_layers) for w in "Wb")}
        extra = sorted(set(a) - known)
        if extra:
            raise ValueError(f"policy export: arrays {extra} are not part of the format (a damaged or foreign file)")
        low = [k for k in a if k[0] in "Wb" and k[1:].isdigit() and a[k].dtype not in (np.float32, np.float64)]
        if low:
            raise ValueError(f"policy export: {low[0]} is {a[low[0]].dtype}, not float32 or float64 (as exported)")
        if version != EXPORT_VERSION:
            raise ValueError(f"policy export: version {version}, this code reads version {EXPORT_VERSION}")
        if self.head not in HEADS:
            raise ValueError(f"policy export: head {self.head!r} is not one of {HEADS}")
        bad = [s for s in acts if s not in ACTIVATIONS]
        if bad or not n_layers or params.shape != (n_layers,):
            raise ValueError(f"policy export: activations {acts} (params {params.shape}) must be {n_layers} >= 1 "
                             f"names from {ACTIVATIONS}")
        n_in = int(np.prod(obs_low.shape))
        for i, (W, b, _, _) in enumerate(self.layers):
            if W.ndim != 2 or W.shape[1] != n_in or b.shape != (W.shape[0],):
                raise ValueError(f"policy export: layer {i} has W {W.shape}, b {b.shape}; expected ({'out'}, "
                                 f"{n_in}) and (out,)")
            n_in = W.shape[0]
        self.observation_space = spaces.Box(obs_low, obs_high, dtype=np.float32)
        if self.head in ("categorical", "argmax"):
            n = int(a.get("action_n", -1))
            if n != n_in:
                raise ValueError(f"policy export: {n} discrete actions but the last layer has {n_in} outputs")
            self.action_space = spaces.Discrete(n)
        else:
            low, high = (np.asarray(a[k], dtype=np.float32) for k in ("action_low", "action_high"))
            if low.size != n_in:
                raise ValueError(f"policy export: action Box of {low.size} entries but the last layer has {n_in} "
                                 "outputs")
            self.action_space = spaces.Box(low, high, dtype=np.float32)
        self._arrays = a

    def arrays(self):
        """The export as a dict of arrays (what :func:`save_export` writes)."""
        return dict(self._arrays)

    def forward(self, obs):
        """The last layer's outputs (n, A), float64, for observations (n, ...) (rounded to float32 first)."""
        h = np.asarray(obs, dtype=np.float32).reshape(np.shape(obs)[0], -1).astype(np.float64)
        n = h.shape[0]
        for W, b, act, param in self.layers:
            out = np.empty((n, W.shape[0]))
            step = max(1, _SINGLE_THREAD_MACS // W.size)
            for i in range(0, n, step):     # products small enough for OpenBLAS to run them on one thread
                np.matmul(h[i:i + step], W.T, out=out[i:i + step])
            out += b
            h = _activate(out, act, param)
        return h

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """``(action, state)`` as stable-baselines3's ``predict(..., deterministic=True)``: for one observation or
        a batch (n, ...); ``deterministic`` is accepted for the interface, the actor is always deterministic."""
        obs = np.asarray(observation)
        single = obs.shape == self.observation_space.shape
        out = self.forward(obs.reshape((1,) + obs.shape) if single else obs)
        if self.head == "categorical":
            p = np.exp(out - out.max(axis=1, keepdims=True))
            p /= p.sum(axis=1, keepdims=True)
            act = np.argmax(p.astype(np.float32), axis=1)
        elif self.head == "argmax":
            act = np.argmax(out.astype(np.float32), axis=1)
        else:
            a32 = out.astype(np.float32)
            low, high = self.action_space.low, self.action_space.high
            act = np.clip(a32, low, high) if self.head == "clip" else low + (0.5 * (a32 + 1.0) * (high - low))
            act = act.reshape((-1,) + self.action_space.shape)
        return (act[0] if single else act), state


# ------------------------------------------------------------------------------------------------ export
def _sequential_layers(modules):
    """``[(W, b, activation, param)]`` of a sequence of torch modules (Linear, supported activations, Identity,
    Flatten), or None if it holds anything else or an activation without a linear layer before it."""
    import torch.nn as nn
    layers = []
    for m in modules:
        if isinstance(m, nn.Linear):
            b = m.bias.detach().cpu().numpy() if m.bias is not None else np.zeros(m.out_features, np.float32)
            layers.append([m.weight.detach().cpu().numpy().astype(np.float32), b.astype(np.float32), "identity",
                           0.0])
            continue
        if isinstance(m, (nn.Identity, nn.Flatten)):
            continue
        kind = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu", nn.LeakyReLU: "leaky_relu", nn.SiLU: "silu"}.get(
            type(m))
        if kind is None or not layers or layers[-1][2] != "identity":
            return None
        layers[-1][2] = kind
        layers[-1][3] = float(m.alpha if kind == "elu" else m.negative_slope if kind == "leaky_relu" else 0.0)
    return layers


def _modules(net):
    import torch.nn as nn
    return list(net) if isinstance(net, nn.Sequential) else [net]


def export_model(model):
    """The deterministic actor of a loaded stable-baselines3 model as a dict of arrays (:class:`NumpyPolicy`'s
    input), or None if its structure is not one this module evaluates (the module docstring's table)."""
    import stable_baselines3 as sb3
    from gymnasium import spaces
    from stable_baselines3.common.distributions import CategoricalDistribution, DiagGaussianDistribution
    from stable_baselines3.common.torch_layers import FlattenExtractor

    pol = model.policy
    obs_space, act_space = model.observation_space, model.action_space
    if not isinstance(obs_space, spaces.Box) or not isinstance(act_space, (spaces.Box, spaces.Discrete)):
        return None
    layers, head, extractor = None, None, None
    if isinstance(model, (sb3.PPO, sb3.A2C)):
        extractor = pol.pi_features_extractor
        dist = pol.action_dist
        if isinstance(dist, CategoricalDistribution):
            head = "categorical"
        elif isinstance(dist, DiagGaussianDistribution) and not pol.squash_output:
            head = "clip"
        layers = _sequential_layers(_modules(pol.mlp_extractor.policy_net) + [pol.action_net])
    elif isinstance(model, sb3.DQN):
        extractor, head = pol.q_net.features_extractor, "argmax"
        layers = _sequential_layers(_modules(pol.q_net.q_net))
    elif isinstance(model, sb3.SAC) and not pol.actor.use_sde:
        extractor, head = pol.actor.features_extractor, "rescale"
        layers = _sequential_layers(_modules(pol.actor.latent_pi) + [pol.actor.mu])
        if layers is not None and layers[-1][2] == "identity":
            layers[-1][2] = "tanh"          # the squashed Gaussian's mode: tanh(mean)
        else:
            layers = None
    elif isinstance(model, sb3.TD3):
        extractor, head = pol.actor.features_extractor, "rescale"
        layers = _sequential_layers(_modules(pol.actor.mu))
        if layers is not None and layers[-1][2] != "tanh":
            layers = None
    if layers is None or head is None or type(extractor) is not FlattenExtractor:
        return None
    if head in ("categorical", "argmax") and not isinstance(act_space, spaces.Discrete):
        return None
    out = {"version": np.array(EXPORT_VERSION), "algo": np.array(type(model).__name__), "head": np.array(head),
           "activation": np.array([l[2] for l in layers]), "activation_param": np.array([l[3] for l in layers]),
           "obs_low": np.asarray(obs_space.low, np.float32), "obs_high": np.asarray(obs_space.high, np.float32)}
    for i, (W, b, _, _) in enumerate(layers):
        out[f"W{i}"], out[f"b{i}"] = W, b
    if isinstance(act_space, spaces.Discrete):
        out["action_n"] = np.array(int(act_space.n))
    else:
        out["action_low"] = np.asarray(act_space.low, np.float32)
        out["action_high"] = np.asarray(act_space.high, np.float32)
    return out


def _sample_observations(space, n, seed):
    """``n`` observations in the Box: uniform inside (finite bounds; standard normal where unbounded), its corners'
    faces included (every entry at its low or high bound for an eighth of them)."""
    rng = np.random.default_rng(seed)
    low, high = np.asarray(space.low, np.float64), np.asarray(space.high, np.float64)
    finite = np.isfinite(low) & np.isfinite(high)
    obs = np.where(finite, rng.uniform(np.where(finite, low, 0), np.where(finite, high, 1), (n,) + low.shape),
                   rng.standard_normal((n,) + low.shape))
    k = n // 8
    edge = rng.integers(0, 2, (k,) + low.shape).astype(bool)
    obs[:k] = np.where(finite, np.where(edge, high, low), obs[:k])
    return obs.astype(np.float32)


def check_export(policy, model, observations=None, n=1024, seed=0):
    """``(ok, message)``: does ``policy`` (a :class:`NumpyPolicy`) choose ``model``'s deterministic actions (SB3's
    ``predict``) on ``observations`` (default: ``n`` sampled in the observation Box)? Discrete actions must be
    equal, continuous ones equal to float32 rounding (relative 1e-5 of the action range)."""
    obs = _sample_observations(policy.observation_space, n, seed) if observations is None else \
        np.asarray(observations, dtype=np.float32)
    a_np, _ = policy.predict(obs)
    a_sb3, _ = model.predict(obs, deterministic=True)
    a_sb3 = np.asarray(a_sb3).reshape(np.shape(a_np))
    if policy.head in ("categorical", "argmax"):
        bad = np.flatnonzero(a_np != a_sb3)
        return bad.size == 0, f"{bad.size} of {obs.shape[0]} actions differ from SB3's"
    span = np.asarray(policy.action_space.high, np.float64) - np.asarray(policy.action_space.low, np.float64)
    err = np.max(np.abs(a_np.astype(np.float64) - a_sb3) / np.where(np.isfinite(span) & (span > 0), span, 1.0))
    return bool(err <= 1e-5), f"largest action difference {err:.2e} of the action range"


# ------------------------------------------------------------------------------------------------ files
def export_path(policy_path):
    """Where the export of ``policy_path`` (a zip) lives: the same name with ``.npz``."""
    return Path(policy_path).with_suffix(".npz")


def zip_sha256(policy_path):
    return hashlib.sha256(Path(policy_path).read_bytes()).hexdigest()


def load_sb3_model(path, allow_pickle=False):
    """The stable-baselines3 model in ``path`` (PPO, DQN, SAC, A2C or TD3 zip, on the CPU); imports SB3 and torch.
    The zip is a pickle: refused (``ValueError``, one line) unless ``allow_pickle`` (:func:`agents.policies.checks.
    refuse_pickle`). Raises ``ValueError`` for a file that is not such a model."""
    if not allow_pickle:
        from agents.policies.checks import refuse_pickle
        raise refuse_pickle(path)
    try:
        import stable_baselines3 as sb3
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ValueError("loading a policy needs stable-baselines3: pip install -e '.[train]'") from e
    errors = []
    for algo in ("PPO", "DQN", "SAC", "A2C", "TD3"):
        try:
            return getattr(sb3, algo).load(str(path), device="cpu")
        except Exception as e:  # noqa: BLE001 - try the next algorithm class
            errors.append(f"{algo}: {type(e).__name__}")
    raise ValueError(f"{path}: not a stable-baselines3 model this version can load ({'; '.join(errors)})")


def load_export(policy_path):
    """The :class:`NumpyPolicy` exported beside ``policy_path``, or None if there is none or it was exported from
    another file (its recorded SHA-256 differs from the zip's). Reads arrays only (``allow_pickle=False``).
    Raises ``ValueError`` for a damaged export."""
    from agents.policies.checks import read_npz
    npz = export_path(policy_path)
    if not npz.is_file():
        return None
    arrays = read_npz(npz)
    if str(arrays.get("source_sha256", "")) != zip_sha256(policy_path):
        return None
    try:
        pol = NumpyPolicy(arrays)
    except (ValueError, TypeError, IndexError, OverflowError) as e:
        raise ValueError(f"{npz}: {str(e).splitlines()[0] if str(e) else type(e).__name__}"[:400]) from None
    for i, (W, b, _, param) in enumerate(pol.layers):
        if not (np.all(np.isfinite(W)) and np.all(np.isfinite(b)) and np.isfinite(param)):
            raise ValueError(f"{npz}: layer {i} (W{i}, b{i}, activation_param) has non-finite entries")
    return pol


def save_export(policy_path, model=None, allow_pickle=False):
    """Export the policy zip ``policy_path`` (loaded with SB3 unless ``model`` is given: a pickle, refused unless
    ``allow_pickle``) to ``export_path``:
    the arrays of :func:`export_model` and the zip's SHA-256, after :func:`check_export` passed. Returns the
    ``.npz`` path; raises ``ValueError`` if the model cannot be exported or the check fails."""
    policy_path = Path(policy_path)
    if model is None:
        model = load_sb3_model(policy_path, allow_pickle=allow_pickle)
    arrays = export_model(model)
    if arrays is None:
        raise ValueError(f"{policy_path}: not a policy this exporter evaluates (see agents.policies.numpy_policy)")
    pol = NumpyPolicy(arrays)
    ok, msg = check_export(pol, model)
    if not ok:
        raise ValueError(f"{policy_path}: the numpy export does not reproduce SB3's actions ({msg})")
    arrays["source_sha256"] = np.array(zip_sha256(policy_path))
    out = export_path(policy_path)
    with open(out, "wb") as f:      # np.savez on a path would append .npz to a name without it
        np.savez(f, **arrays)
    return out


def export_saved(policy_path, model):
    """Write the export of the zip ``model`` was just saved to (training, after each save: no unpickling, the model
    is in memory), so that the run evaluates without ``--allow-pickle``. Returns the ``.npz`` path, or None when
    the model's structure has no export (the zip then needs the opt-in)."""
    try:
        return save_export(policy_path, model)
    except ValueError:
        return None


def main(argv=None):
    """``python -m agents.policies.numpy_policy POLICY.zip ...``: write each zip's numpy export beside it."""
    import argparse
    ap = argparse.ArgumentParser(prog="python -m agents.policies.numpy_policy",
                                 description="Export stable-baselines3 policy zips to numpy (.npz beside each).")
    ap.add_argument("policies", nargs="+", metavar="POLICY.zip")
    ap.add_argument("--allow-pickle", action="store_true",
                    help="required: exporting unpickles each zip, which runs its author's code (only files you trust)")
    args = ap.parse_args(argv)
    for p in args.policies:
        try:
            print(save_export(p, allow_pickle=args.allow_pickle))
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None


if __name__ == "__main__":
    main()
