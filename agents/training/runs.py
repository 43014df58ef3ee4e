"""What every trainer shares (``radar-track train --method ppo`` in :mod:`agents.training.train`, ``--method
backprop`` in :mod:`agents.training.backprop`, ``--method window`` in :mod:`agents.training.window`): the
hyperparameter files, ``--hp`` parsing, the training scenarios and the run folder.

A run is written into ``<out>/<name>.partial/`` and renamed to ``<out>/<name>/`` only when complete
(:func:`run_paths`; :func:`writing_run`: :func:`open_run_folder`, then :func:`finish_run` or :func:`mark_failed`;
:func:`write_run_files`); a finished ``<out>/<name>/`` is never overwritten, and while a run writes, it holds an
exclusive lock on its name (:class:`RunLock`).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tomllib
import traceback
import zipfile
from importlib import resources
from pathlib import Path

__all__ = ["ENV_ID", "TRAIN_SCENARIOS", "HP_DIR", "HP_NAMES", "load_hyperparams", "parse_hp", "apply_cli_overrides",
           "check_plain_name", "RunLock", "run_paths", "open_run_folder", "resumable", "write_checkpoint",
           "CHECKPOINT_ERRORS", "checkpoint_refusal", "adam_arrays", "load_adam", "write_run_files", "mark_failed",
           "finish_run", "writing_run", "EVAL_SCENARIOS_HP", "SELECT_ON_HP"]

ENV_ID = "RadarTrack-v0"
TRAIN_SCENARIOS = ("random", "random_radars")
"""The random generators training may use (named scenarios, trajectories and flights are for evaluation only)."""
EVAL_SCENARIOS_HP = ((lambda v: isinstance(v, dict) and bool(v) and all(
    isinstance(r, int) and not isinstance(r, bool) and r >= 1 for r in v.values())), "a JSON object {suite: runs >= 1}")
"""Every trainer's ``--hp eval_scenarios`` check: ``(check, what it must be)``."""
SELECT_ON_HP = ((lambda v: isinstance(v, list) and all(isinstance(n, str) for n in v)), "a list of suite names")
"""Every trainer's ``--hp select_on`` check: ``(check, what it must be)``."""
HP_DIR = Path(__file__).with_name("hyperparams")
HP_NAMES = ("ppo", "dqn", "sac", "backprop", "backprop_imm_cv_ct", "window")
"""The hyperparameter files shipped in ``agents/training/hyperparams/``."""


def load_hyperparams(algo, path=None):
    """The ``RadarTrack-v0`` table of ``agents/training/hyperparams/<algo>.toml`` (package data, read through
    ``importlib.resources`` so it works from a wheel install) or of the TOML file ``path``; ``algo`` ``"backprop"``
    reads ``backprop.toml`` (``--method backprop``)."""
    if path:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"--hyperparams: file {str(path)!r} does not exist")
        text, where = path.read_bytes(), str(path)
    else:
        if algo not in HP_NAMES:
            raise ValueError(f"algo must be one of {HP_NAMES}, got {algo!r}")
        res = resources.files(__package__).joinpath("hyperparams", f"{algo}.toml")
        text, where = res.read_bytes(), f"agents/training/hyperparams/{algo}.toml"
    try:
        table = tomllib.loads(text.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"--hyperparams: {where} is not TOML ({e})") from None
    if ENV_ID not in table:
        raise ValueError(f"--hyperparams: {where}: no [\"{ENV_ID}\"] table")
    return table[ENV_ID]


def parse_hp(items):
    """``--hp KEY=VALUE`` items -> ``{KEY: value}`` (the value parsed as JSON, else kept as a string); a one-line
    ``SystemExit`` for an item without ``=``."""
    out = {}
    for it in items or []:
        if "=" not in it:
            raise SystemExit(f"error: --hp expects KEY=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def apply_cli_overrides(hp, env_kwargs_json, hp_items):
    """``hp`` (a hyperparameter table) with the command line's overrides: ``--hp KEY=VALUE`` items and the
    ``--env-kwargs`` JSON object merged over the table's ``env_kwargs``; a one-line ``SystemExit`` for JSON that is
    not an object."""
    try:
        ek = json.loads(env_kwargs_json)
    except json.JSONDecodeError as e:
        raise SystemExit(f"error: --env-kwargs is not JSON: {e}") from None
    if not isinstance(ek, dict):
        raise SystemExit("error: --env-kwargs must be a JSON object")
    hp.update(parse_hp(hp_items))
    hp["env_kwargs"] = {**dict(hp.get("env_kwargs") or {}), **ek}
    return hp


# ------------------------------------------------------------------------------------------------ run folders
def check_plain_name(option, name):
    """``name`` if it is a plain folder name (one path component: no ``/`` or ``\\``, not ``.``/``..``, not empty, no
    NUL), so that a run or sweep folder stays inside its ``--out``; ``ValueError`` naming ``option`` otherwise."""
    if (not isinstance(name, str) or name in ("", ".", "..") or Path(name).name != name or "\\" in name
            or "/" in name or "\0" in name):
        raise ValueError(f"{option}: must be a plain folder name inside --out (no '/', '..'), got {name!r}")
    return name


class RunLock:
    """An exclusive lock on the run name ``<out>/<name>`` for as long as a run writes it: the ``flock`` of
    ``<out>/.<name>.lock`` (released by the kernel if the process dies, so a killed run's ``.partial`` can be
    replaced later). A second run under the same name while the first runs is refused (``ValueError`` naming
    ``--name``) instead of deleting the first's ``.partial`` and mixing its files into the first's folder."""

    def __init__(self, run):
        import fcntl
        self.path = run.with_name(f".{run.name}.lock")
        run.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise ValueError(f"--name: another run is writing {str(run)!r} now (it holds {str(self.path)!r}); "
                                 "choose another name or wait for it to end") from None
            try:     # the previous holder may have removed the file between our open and our lock: lock it anew
                if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                    break
            except FileNotFoundError:
                pass
            os.close(fd)
        self.fd = fd
        os.write(fd, f"{os.getpid()}\n".encode())

    def release(self):
        if self.fd is not None:
            self.path.unlink(missing_ok=True)      # while still holding it (see the check above)
            os.close(self.fd)
            self.fd = None


def run_paths(out, run_name, default_name):
    """``(run, part)``: the run folder ``<out>/<name>`` and its ``<name>.partial`` (``name`` = ``run_name`` or
    ``default_name``). ``ValueError`` naming ``--name`` / ``--out`` for a name that is not a plain folder name, a
    finished run of that name (never overwritten) or an ``--out`` that is not a directory."""
    if run_name is not None:
        check_plain_name("--name", run_name)
    run = Path(out) / (run_name or default_name)
    part = run.with_name(run.name + ".partial")
    if run.exists():        # a finished run is never overwritten (an unfinished <name>.partial is, in open_run_folder)
        raise ValueError(f"--name: run folder {str(run)!r} already exists; choose another name (or remove it)")
    if Path(out).exists() and not Path(out).is_dir():
        raise ValueError(f"--out: {str(out)!r} exists and is not a directory")
    return run, part


def open_run_folder(run, part, keep=False):
    """Lock the run name (:class:`RunLock`: a second run with this name stops here, before touching the first's
    files), then create ``part`` (``<name>.partial``); an earlier attempt under this name that failed or was killed
    is removed first, unless ``keep`` (a resumed run). Returns the lock, which :func:`mark_failed` or
    :func:`finish_run` releases."""
    from radar_env.common.files import check_output_dir
    check_output_dir("--out", Path(run).parent)       # never through a link, never over a device or FIFO
    check_output_dir("--name", part)
    lock = RunLock(run)
    try:
        if run.exists():
            raise ValueError(f"--name: run folder {str(run)!r} already exists; choose another name (or remove it)")
        if part.exists() and not keep:
            shutil.rmtree(part)
        part.mkdir(parents=True, exist_ok=keep)
    except OSError as e:
        lock.release()
        raise ValueError(f"--out: cannot create the run folder {str(part)!r} ({e.strerror or e})") from None
    except BaseException:
        lock.release()
        raise
    return lock


def resumable(part, config, ignores=()):
    """Whether the unfinished run folder ``part`` holds a checkpoint (``checkpoints/last.json``) of a run with this
    ``config``; ``ValueError`` naming ``--name`` if it is of another config (the keys ``ignores`` may differ)."""
    if not (part / "checkpoints" / "last.json").is_file():
        return False
    try:
        old = json.loads((part / "config.json").read_text())
    except (OSError, json.JSONDecodeError):
        old = None
    new = json.loads(json.dumps(config))
    if isinstance(old, dict):
        old, new = ({k: v for k, v in d.items() if k not in ignores} for d in (old, new))
    if old != new:
        keys = sorted(k for k in set(old or {}) | set(new) if (old or {}).get(k) != new.get(k))
        raise ValueError(f"--name: {str(part)!r} holds an unfinished run with another configuration (differs in "
                         f"{keys}); rerun its own command to resume it, or remove it, or choose another --name")
    return True


def write_checkpoint(part, arrays, meta):
    """A trainer's resume checkpoint in ``<part>/checkpoints``: ``last.npz`` holds ``arrays`` and ``meta`` (a dict)
    as a JSON string (``meta_json``), written then renamed, so a kill leaves the previous checkpoint or the new one,
    never a mix; ``last.json`` beside it is ``meta`` again, for reading (and what :func:`resumable` looks for). No
    pickle: numbers and text only."""
    import numpy as np
    from agents.evaluation.metrics import jsonable
    d = Path(part) / "checkpoints"
    d.mkdir(exist_ok=True)
    text = json.dumps(jsonable(meta), indent=1, allow_nan=False)
    tmp = d / "last.tmp.npz"
    np.savez(tmp, **arrays, meta_json=np.array(text))
    os.replace(tmp, d / "last.npz")
    (d / "last.tmp.json").write_text(text)
    os.replace(d / "last.tmp.json", d / "last.json")


CHECKPOINT_ERRORS = (OSError, EOFError, ValueError, KeyError, TypeError, RuntimeError, zipfile.BadZipFile)
"""What reading a damaged or foreign checkpoint raises (numpy, zipfile, json, torch's ``load_state_dict``)."""


def checkpoint_refusal(part, e):
    """The one-line ``ValueError`` for a checkpoint in ``part`` that cannot be resumed, from the error ``e``
    (its message folded onto one line: torch's ``load_state_dict`` errors span several)."""
    d = Path(part) / "checkpoints"
    return ValueError(f"--name: the checkpoint {d / 'last.npz'} cannot be resumed ({type(e).__name__}: "
                      f"{' '.join(str(e).split())}); remove {part} to start the run again, or choose another --name")


def adam_arrays(opt):
    """Adam's moments and step counts of ``opt`` as arrays ``adam/<param index>/<name>`` for
    :func:`write_checkpoint` (:func:`load_adam` puts them back)."""
    import numpy as np
    return {f"adam/{i}/{k}": v.detach().numpy() if hasattr(v, "detach") else np.asarray(v)
            for i, st in opt.state_dict()["state"].items() for k, v in st.items()}


def load_adam(opt, arrays):
    """The ``adam/...`` entries of ``arrays`` (:func:`adam_arrays`'s) back into ``opt``'s state."""
    import torch
    state = {}
    for k, v in arrays.items():
        if k.startswith("adam/"):
            _, i, name = k.split("/")
            state.setdefault(int(i), {})[name] = torch.from_numpy(v)
    sd = opt.state_dict()
    sd["state"] = state
    opt.load_state_dict(sd)


def write_run_files(part, config, args, command, env_kwargs):
    """``config.json``, ``args.json``, ``command.txt`` and ``env_config.json`` of a run."""
    (part / "config.json").write_text(json.dumps(config, indent=1))
    (part / "args.json").write_text(json.dumps(args or {}, indent=1))
    (part / "command.txt").write_text((command or "") + "\n")
    (part / "env_config.json").write_text(json.dumps(env_kwargs, indent=1))


ROW_BYTES = 2 << 20
"""A conservative estimate of the memory one training row takes (an env row of the vector env, an episode of a
backprop batch: its looks, the filter's state and the network's activations kept for the backward pass)."""


def physical_memory_bytes():
    """The machine's physical memory (None if the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_rows_fit(option, rows, row_bytes=ROW_BYTES):
    """``ValueError`` naming ``option`` when ``rows`` training rows (``row_bytes`` each) would not fit in the
    machine's physical memory: checked before anything is allocated."""
    mem = physical_memory_bytes()
    if mem is not None and rows * row_bytes > mem:
        raise ValueError(f"{option}: {rows:,} rows need about {rows * row_bytes / 2**30:,.1f} GiB (about "
                         f"{row_bytes / 2**20:.0f} MiB each), more than this machine's {mem / 2**30:.1f} GiB; "
                         f"give at most {mem // row_bytes:,}")


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) stopped a training run: its ``<name>.partial`` folder is kept (:func:`mark_failed`).
    ``message(command)`` is the one line the command ends with: where the run is and the command that resumes it
    (``resumable``) or starts it again."""

    def __init__(self, part, resumable):
        super().__init__(str(part))
        self.part, self.resumable = Path(part), resumable

    def message(self, command):
        import shlex
        name = self.part.name.removesuffix(".partial")
        words = shlex.split(command or "radar-track train")
        if "--name" not in words and not any(w.startswith("--name=") for w in words):
            words += ["--name", name]
        again = " ".join(map(shlex.quote, words))
        what = ("resume it from its last checkpoint" if self.resumable
                else "start it again (this method does not resume)")
        return f"radar-track train: interrupted; the unfinished run is in {self.part}/; to {what}: {again}"


def run_cli(start, command, out):
    """``start()`` (a training run) for ``radar-track train``, every fault it may end with as one line
    (``SystemExit``): a refused argument (``ValueError``), Ctrl-C during the run (:class:`RunInterrupted`: where the
    run is and the command that resumes it) or before its folder was made, a write that failed (``OSError``: a full
    disk, a folder made read-only; the run's ``.partial`` folder keeps its last complete checkpoint)."""
    try:
        return start()
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    except RunInterrupted as e:
        raise SystemExit(e.message(command)) from None
    except OSError as e:        # a full disk, a folder made read-only: what and where, in one line
        raise SystemExit(f"radar-track train: could not write {e.filename or out} ({e.strerror or e}); the "
                         "unfinished run and its last complete checkpoint stay in its .partial folder") from None
    except KeyboardInterrupt:
        raise SystemExit("radar-track train: interrupted before the run folder was made; nothing written") from None


def mark_failed(part, lock):
    """Write the current exception's traceback to ``<part>/FAILED`` (call it in an ``except`` block) and release the
    run's lock."""
    try:
        (part / "FAILED").write_text(traceback.format_exc())
    finally:
        lock.release()


def finish_run(part, run, lock):
    """The run is complete: ``<name>.partial`` becomes ``<name>``; the run's lock is released."""
    try:
        part.rename(run)
    finally:
        lock.release()


@contextlib.contextmanager
def writing_run(run, part, resumable, keep=False):
    """The body of a training run, as every trainer writes one: :func:`open_run_folder` (``keep``: a resumed run's
    ``.partial`` stays), then the body; if it ends normally the run is finished (:func:`finish_run`), if it raises
    the ``.partial`` folder is marked failed (:func:`mark_failed`) and Ctrl-C becomes :class:`RunInterrupted`
    (``resumable``: whether the method resumes from its checkpoint)."""
    lock = open_run_folder(run, part, keep=keep)
    try:
        yield
    except KeyboardInterrupt:
        mark_failed(part, lock)
        raise RunInterrupted(part, resumable=resumable) from None
    except BaseException:
        mark_failed(part, lock)
        raise
    finish_run(part, run, lock)
