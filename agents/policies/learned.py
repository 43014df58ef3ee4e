"""One interface for every learned tracker: a folder of known files, read by :func:`load_learned` by its kind.

Every learned tracker, bundled or trained by a user, is a folder holding:

* ``policy.npz``: the weights as arrays (no pickle);
* ``policy.json``: ``kind`` (one of :data:`KINDS`) and the architecture (a recurrent policy's and a learned IMM's
  file is also their per-kind config, read by :mod:`agents.policies.recurrent` / :mod:`agents.policies.learned_imm`);
* ``env_config.json``: the ``RadarTrack-v0`` arguments it was trained with;
* ``training.json``: the training record (hyperparameters, command, summary);
* ``choice.json``: the choice record (the rule and what it chose: a seed, a checkpoint);
* where the kind is a stable-baselines3 model, ``policy.zip`` beside the ``.npz`` (a pickle; the ``.npz`` is its
  numpy export and is what runs when it is current, :mod:`agents.policies.numpy_policy`; without a current export
  the zip is refused unless ``allow_pickle=True``).

Every file is checked by :mod:`agents.policies.checks` before anything runs (one-line ``ValueError`` naming the file
and the field), and a file given by path is the file loaded, never a neighbour.

The kind, not the caller, decides how the tracker runs: :func:`load_learned` reads ``policy.json`` and hands the
folder to the per-kind loader (:func:`agents.policies.loading.load_policy`). The bundled trackers are named in
:data:`BUNDLED_LEARNED`; ``load_learned("policy_bp")`` and ``load_learned("agents/bundled/backprop")`` are the same.

A folder written before this layout (a training run with ``policy.zip`` and no ``policy.json``, or a recurrent
checkpoint whose ``policy.json`` has a ``format`` but no ``kind``) is still read: its kind is inferred from those
files (JSON only; nothing is unpickled to decide it).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from agents.policies.layout import (BUNDLED_DIR, BUNDLED_LEARNED, CORRECTION_KINDS, IMM_KINDS, KINDS, MANIFEST,
                                    MANIFEST_FORMAT, MANIFEST_VERSION, Q_POLICY_KINDS, SB3_KINDS, TRACKER_KINDS,
                                    read_json, sb3_kind, weights_file, write_manifest, write_records)

__all__ = ["KINDS", "Q_POLICY_KINDS", "IMM_KINDS", "CORRECTION_KINDS", "BUNDLED_DIR", "BUNDLED_LEARNED", "MANIFEST",
           "LearnedTracker", "load_learned", "resolve_learned", "read_kind", "sb3_kind", "write_manifest",
           "write_records", "learned_label", "write_run_layout", "staging_beside", "install_checked"]


def read_kind(folder, file=None):
    """The kind of the learned tracker in ``folder``: ``policy.json``'s ``kind``; for a folder written before this
    layout, inferred from its files (module docstring). ``file``: the weights file the caller named, if any.

    Returns:
        ``(kind, source)``: the kind and the file it was read or inferred from.
    Raises:
        ValueError: (one line, naming the file and the field) no ``policy.json`` and no ``policy.zip``; a
            ``policy.json`` that is not a JSON object, or whose ``kind`` is not one of :data:`KINDS`.
    """
    from agents.policies import learned_imm, recurrent
    from agents.policies.checks import read_json_object
    folder = Path(folder)
    man = folder / MANIFEST
    if os.path.lexists(man) and not man.is_file():
        raise ValueError(f"{man}: is not a regular file (a folder, or a link to nothing)")
    if man.is_file():
        meta = read_json_object(man, "a JSON object with a 'kind' field")
        if "kind" in meta:
            kind = meta["kind"]
            if not isinstance(kind, str) or kind not in KINDS:
                raise ValueError(f"{man}: field 'kind' is {kind!r}, not one of {list(KINDS)}")
            v = meta.get("version")
            if kind in SB3_KINDS and (meta.get("format") != MANIFEST_FORMAT or isinstance(v, bool)
                                      or v != MANIFEST_VERSION):
                raise ValueError(f"{man}: a {kind} folder's policy.json must have format {MANIFEST_FORMAT!r} and "
                                 f"version {MANIFEST_VERSION}, got {meta.get('format')!r} and {meta.get('version')!r}")
            return kind, str(man)
        # before this layout: the recurrent checkpoints' policy.json had a format and no kind
        legacy = {recurrent.FORMAT: "gru_q_policy", learned_imm.FORMAT: "learned_imm_gru"}
        if meta.get("format") in legacy:
            return legacy[meta["format"]], str(man)
        raise ValueError(f"{man}: no field 'kind' (one of {list(KINDS)})")
    zip_file = Path(file) if file is not None and Path(file).suffix == ".zip" else folder / "policy.zip"
    if zip_file.is_file():
        # a training run of an SB3 model before this layout: its config.json (here, or one up for best/) names
        # the algorithm; the env config says whether it drives the IMM
        algo = "ppo"
        for cfg in (folder / "config.json", folder.parent / "config.json"):
            if cfg.is_file():
                try:
                    algo = json.loads(cfg.read_text()).get("algo", algo)
                except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
                    pass
                break
        env = {}
        if (folder / "env_config.json").is_file():
            env = read_json(folder / "env_config.json")
        try:
            return sb3_kind(algo, env if isinstance(env, dict) else {}), str(zip_file)
        except ValueError as e:
            raise ValueError(f"{zip_file}: {e}") from None
    raise ValueError(f"{folder}: not a learned tracker folder (no {MANIFEST} naming its kind, no policy.zip)")


def resolve_learned(path_or_name):
    """``(folder, file, bundled_name)`` for a bundled name (:data:`BUNDLED_LEARNED`), a folder, or a file inside
    one (``policy.zip``, ``policy.npz``, ``policy.json``: the old options took files); a bundled name is never
    read as a path (a folder named like one is given as ``./NAME``). ``file`` is the weights
    file named, else ``None``; ``bundled_name`` is set when the folder is a bundled one. ``ValueError`` (one line)
    when it is neither a bundled name nor an existing path."""
    s = str(path_or_name)
    if s in BUNDLED_LEARNED:    # a bundled name always means the bundled tracker (a folder so named: ./NAME)
        return BUNDLED_LEARNED[s], None, s
    p = Path(s)
    if not p.exists():
        raise ValueError(f"{s!r} is neither a bundled learned tracker ({', '.join(BUNDLED_LEARNED)}) nor an "
                         "existing folder or file")
    if p.is_file() and p.suffix not in (".zip", ".npz") and p.name != MANIFEST:
        raise ValueError(f"{s}: not a learned tracker's file (policy.npz, policy.zip or {MANIFEST} in its folder); "
                         "a file is loaded from the path given, never a neighbour: give the folder")
    folder, file = (p, None) if p.is_dir() else (p.parent, p if p.suffix in (".zip", ".npz") else None)
    if file is not None and file.suffix == ".npz":    # policy.json describes policy.npz: never load a neighbour
        from agents.policies.checks import check_policy_file
        check_policy_file(file)
    bundled = next((n for n, d in BUNDLED_LEARNED.items() if d.exists() and d.resolve() == folder.resolve()), None)
    return folder, file, bundled


def learned_label(folder, bundled_name=None):
    """The tracker name a learned tracker is reported under: its bundled name, else its folder's name (a training
    run's ``best/`` takes the run's name, ``<run>_best``)."""
    if bundled_name is not None:
        return bundled_name
    folder = Path(folder).resolve()
    return f"{folder.parent.name}_best" if folder.name == "best" else folder.name


@dataclasses.dataclass
class LearnedTracker:
    """A loaded learned tracker, as the evaluation runs it.

    Attributes:
        kind: one of :data:`KINDS` (from its ``policy.json``).
        name: the tracker name it is reported under (:func:`learned_label`, or the caller's).
        folder: its folder.
        file: the file the per-kind loader read (``policy.zip`` for an SB3 kind, whose numpy export runs when
            current; ``policy.npz`` otherwise).
        env_config: the :class:`radar_env.envs.env.EnvConfig` it was trained with.
        policy: what :func:`agents.policies.loading.load_policy` returned: a ``choose_q`` (a q-policy) or a
            tracker object with ``run`` (a learned IMM).
    """

    kind: str
    name: str
    folder: Path
    file: Path
    env_config: object
    policy: object

    def run(self, episodes):
        """``TrackRun`` of this tracker on ``episodes`` (labelled :attr:`name`)."""
        if getattr(self.policy, "is_tracker", False):      # a learned IMM or a correction runs itself
            return self.policy.run(episodes, self.name)
        from baselines.trackers import run_q_policy
        return run_q_policy(episodes, self.policy, self.name, self.env_config)

    def input_files(self):
        """The files it is read from (an evaluation's outputs must not replace them)."""
        names = ("policy.zip", "policy.npz", MANIFEST, "env_config.json")
        return [self.folder / n for n in names if (self.folder / n).is_file()]


def load_learned(path_or_name, name=None, kinds=None, allow_pickle=False) -> LearnedTracker:
    """Load a learned tracker by bundled name or path, by its kind.

    Args:
        path_or_name: a bundled name (:data:`BUNDLED_LEARNED`), a tracker folder, or a weights file in one.
        name: the tracker name to report it under (default :func:`learned_label`).
        kinds: if given, the kinds accepted here; another kind is refused (how the old per-tracker options keep a
            learned IMM from running as a q-policy).
        allow_pickle: unpickle an SB3 ``policy.zip`` whose numpy export is missing or stale (runs its author's
            code); without it such a folder is refused in one line.
    Returns:
        LearnedTracker
    Raises:
        ValueError: one line naming the file and the field: not a learned tracker folder, an unknown or refused
            kind, or whatever the per-kind loader refuses (:func:`agents.policies.loading.load_policy`).

    Nothing is unpickled without ``allow_pickle``; every file is checked by :mod:`agents.policies.checks` first.
    """
    from agents.policies.loading import load_policy
    folder, file, bundled = resolve_learned(path_or_name)
    kind, source = read_kind(folder, file)
    if kinds is not None and kind not in kinds:
        raise ValueError(f"{source}: kind {kind!r} ({KINDS[kind]}), expected {' or '.join(map(repr, kinds))}")
    if file is None or (kind in SB3_KINDS and file.suffix != ".zip"):
        file = weights_file(folder, kind)
    policy, cfg = load_policy(file, allow_pickle=allow_pickle)
    # the per-kind loader looks at the files; the kind must agree with what it found
    is_tracker = bool(getattr(policy, "is_tracker", False))
    is_correction = bool(getattr(policy, "is_correction", False))
    if is_tracker != (kind in TRACKER_KINDS) or is_correction != (kind in CORRECTION_KINDS):
        held = "window correction" if is_correction else "learned IMM" if is_tracker else "q-policy"
        raise ValueError(f"{source}: kind {kind!r}, but {file.name} holds a {held}")
    return LearnedTracker(kind, name or learned_label(folder, bundled), folder, file, cfg, policy)


def staging_beside(folder):
    """A temporary folder beside ``folder`` (the same depth, so a base given as a relative folder resolves there as
    from ``folder``), removed on exit: where a folder's new files are written and loaded before they replace its
    own (:func:`install_checked`)."""
    import tempfile
    folder = Path(folder).resolve()
    folder.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(dir=folder.parent, prefix=f".{folder.name}.")


def install_checked(staged, folder, names):
    """Move the files ``names`` of a staged learned-tracker folder (:func:`staging_beside`) into ``folder`` once the
    staged folder loads (:func:`load_learned`), each replaced whole, in ``names``' order
    (:func:`radar_env.common.files.move_replacing`). ``ValueError`` from the load, ``folder`` untouched,
    otherwise."""
    from radar_env.common.files import move_replacing
    load_learned(str(staged))
    folder = Path(folder)
    folder.mkdir(exist_ok=True)
    for n in names:
        move_replacing(Path(staged) / n, folder / n)


def write_run_layout(run, kind, summary):
    """Give a training run folder (and its ``best/``, if written) the learned-tracker layout, after training:
    ``policy.json`` (an SB3 kind: written here, with the numpy export ``policy.npz`` when the model's structure
    allows one; a recurrent kind: already written by its saver), ``training.json`` (the run's ``config.json``,
    ``command.txt`` and ``summary``) and ``choice.json`` (the final weights at the root; ``best/``: the lowest
    selection ratio, with its ``selection.json``), so that :func:`load_learned` reads either folder by its kind.

    Args:
        run: the run folder (``config.json``, ``command.txt`` and the final weights in it).
        kind: one of :data:`KINDS`.
        summary: the run's summary (what ``summary.json`` holds).
    """
    run = Path(run)
    training = {"config": read_json(run / "config.json") if (run / "config.json").is_file() else None,
                "command": (run / "command.txt").read_text().strip() if (run / "command.txt").is_file() else None,
                "summary": summary}
    folders = [(run, {"rule": "the final weights (end of training)", "chosen": "final",
                      "timesteps": summary.get("timesteps", summary.get("steps"))})]
    if (run / "best" / "env_config.json").is_file():
        sel = run / "best" / "selection.json"
        folders.append((run / "best", {"rule": "the lowest selection ratio of the validations during training "
                                               "(training-range selection seeds)", "chosen": "best",
                                       "selection": read_json(sel) if sel.is_file() else None}))
    for folder, choice in folders:
        if kind in SB3_KINDS and (folder / "policy.zip").is_file():
            from agents.policies.numpy_policy import load_export, save_export
            try:    # the trainer exported each zip it saved; else export the zip this training run wrote
                if load_export(folder / "policy.zip") is None:
                    save_export(folder / "policy.zip", allow_pickle=True)
            except ValueError:
                pass        # no numpy export for this structure: the zip runs through SB3 (policy.json says so)
            write_manifest(folder, kind)
        write_records(folder, training=training, choice=choice)
