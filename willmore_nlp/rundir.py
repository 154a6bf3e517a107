"""Run directories: resolved config, history.csv, one npz per accepted state, and the run's status.

Layout::

    RUN/config.json          resolved configuration (problem, parameters, flow options, versions)
    RUN/mesh.npz             simplices and initial vertices
    RUN/states/state_KKKKKK.npz   vertices, Y, t, step, tau, multipliers and history row of every
                                  accepted state (step 0 = initial); a state whose connectivity
                                  differs from mesh.npz (the mesh control remeshed) also holds its
                                  ``simplices`` and, for a clamped problem, its ``free`` mask
    RUN/history.csv          one row per state, appended as steps are accepted
    RUN/status.json          running / completed / interrupted / abandoned / failed, with the
                             sessions (start and resumes) and, for a failure, the rejected attempts;
                             while running, the last state written (refreshed at most every
                             STATUS_SECONDS at accepted steps) and the retry under way (``under_way``)
    RUN/run.lock             held (flock) by the process writing the directory, so that a second
                             writer (e.g. a resume while the run goes on) is refused; the kernel
                             releases it when that process ends, however it ends

Crash safety. Every file except history.csv is written atomically (a hidden temporary file
``.NAME.XXXX`` beside it, then a rename), so a process killed at any moment leaves either the
old or the new version of a file, plus perhaps a stray temporary file. The states are the
record: each holds its own history row, and history.csv (appended one line per state, since
rewriting it would cost O(steps) per step) is rebuilt from them when a run is resumed. A reader
(:func:`load_run`, :meth:`RunWriter.resume`) trusts the states ``0, 1, ..., k`` that load and
match the mesh, stopping at the first gap or untrusted file, and ignores temporary files. A resume
deletes only what a write cut short leaves (temporary files and an unreadable last state) and
refuses to go on while other state files are untrusted: a state file put in place of one (say,
another run's) with the run's finished states after it is no write of the program, and deleting
those states would lose finished work (:func:`scan_states`).
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import StepResult
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.io import atomic_write, make_dirs

STATE_RE = re.compile(r"^state_(\d{6,})\.npz$")
"""File names of accepted states."""

SOLVER_STATE = "solver_state.npz"
"""What the step solver carried into the next step after the last state written (:func:`load_solver_state`)."""

STATUS_SECONDS = 10.0
"""A running run's status.json names its last state at most this often (:meth:`RunWriter.progress`; it is fsynced,
as the states are)."""
RUN_FILES = ("config.json", "mesh.npz", "history.csv", "status.json", "run.lock", SOLVER_STATE)
"""Files the program writes at the top of a run directory (besides ``states/``)."""

TEMP_RE = re.compile(r"^\.(state_\d{6,}\.npz|config\.json|mesh\.npz|history\.csv|status\.json|solver_state\.npz)"
                     r"\.[A-Za-z0-9_]+"
                     r"\.(npz|json|csv)$")
"""Temporary files of :func:`~willmore_nlp.mesh.io.atomic_write` (``.NAME.XXXXXXXX.SUFFIX``) for the run's
files; only these, the state files and :data:`RUN_FILES` are ever deleted from a run directory."""


class RunError(UserInputError):
    """A run directory is missing, incomplete or inconsistent."""


class UnreadableStateError(RunError):
    """A state file that cannot be read as an npz archive (what a write cut short may leave)."""


ZIP_MAGIC = b"PK\x03\x04"
"""The first bytes of an npz file (a zip archive)."""


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file, fsync, rename)."""
    def w(t: Path) -> None:
        with open(t, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())

    atomic_write(path, w)


def _npz_to(t: Path, arrays: dict[str, Any]) -> None:
    """``arrays`` written to the file ``t`` as npz and synced to the disk."""
    with open(t, "wb") as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())


def _write_npz(path: Path, **arrays: Any) -> None:
    atomic_write(path, lambda t: _npz_to(t, arrays))


def _csv_text(rows: list[dict[str, Any]], keys: list[str], header: bool) -> str:
    buf = io.StringIO()
    wr = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n", restval="")
    if header:
        wr.writeheader()
    wr.writerows(rows)
    return buf.getvalue()


def _json_default(o: Any) -> Any:
    """A JSON value for what json does not write: numpy scalars, objects with a ``json_record`` (a clamped run's
    :class:`~willmore_nlp.boundary.Boundary`), else the object's string."""
    if isinstance(o, np.generic):
        return o.item()
    if callable(getattr(o, "json_record", None)):
        return o.json_record()
    return str(o)


@dataclass
class Checkpoint:
    """The last trusted state of a run directory (what a resume continues from).

    Attributes
    ----------
    step, t : step number and time
    vertices, Y : (N, m) positions and inner step
    lam_g : constraint multipliers of the step that produced it (None for step 0 or old runs)
    row : its history row
    simplices : (K, d + 1) its connectivity when it differs from mesh.npz, else None
    free : (N,) bool free mask of a clamped problem on that connectivity, else None
    """

    step: int
    t: float
    vertices: np.ndarray
    Y: np.ndarray
    lam_g: np.ndarray | None
    row: dict[str, Any]
    simplices: np.ndarray | None = None
    free: np.ndarray | None = None


def require_run_dir(d: Path) -> None:
    """RunError unless ``d`` is a directory (naming the run directory when a file of one is given in its place, e.g.
    its config.json; a file elsewhere, e.g. a mesh file, is just not a run directory)."""
    if d.is_dir():
        return
    if not d.is_file():
        raise RunError(f"{d}: no such run directory")
    inside = f" (the run directory is {d.parent})" if (d.parent / "config.json").is_file() else ""
    raise RunError(f"{d}: a file, not a run directory{inside}")


def load_solver_state(run_dir: Path, step: int) -> dict[str, Any]:
    """The step solver's warm state written after state ``step`` (:meth:`RunWriter.add`); {} when the file is missing,
    unreadable or of another step (a resume then starts with a new solver: the same flow, not bit for bit)."""
    try:
        with np.load(Path(run_dir) / SOLVER_STATE, allow_pickle=False) as s:
            if int(s["step"]) != step:
                return {}
            warm: dict[str, Any] = {k: np.array(s[k]) for k in s.files if k != "step"}
    except Exception:  # np.load/zipfile raise many types; without a warm state a resume is not bit for bit, no more
        return {}
    if "solver" in warm:
        warm["solver"] = str(warm["solver"])
    return warm


def _parse(v: str | None) -> Any:
    if v is None:
        return None
    try:
        return int(v)
    except ValueError:
        try:
            return float(v)
        except ValueError:
            return v


def read_history_csv(path: Path) -> dict[int, dict[str, Any]]:
    """Rows of a history.csv by step; a partial last line (a crash mid-append) is dropped."""
    if not path.is_file():
        return {}
    text = path.read_text(encoding="utf-8", errors="replace")
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    rows: dict[int, dict[str, Any]] = {}
    for row in csv.DictReader(io.StringIO(text)):
        if None in row or any(v is None for v in row.values()):
            continue  # wrong number of fields
        try:
            step = int(row["step"])
        except (KeyError, ValueError):
            continue
        rows[step] = {k: _parse(v) for k, v in row.items()}
    return rows


def _load_state(f: Path, step: int, shape: tuple[int, ...]) -> Checkpoint:
    """Read and check one state file.

    Raises
    ------
    UnreadableStateError
        The file is no readable npz archive.
    RunError
        It is one, but not a state of step ``step`` of this run (keys, shapes, step, values).
    """
    try:
        with np.load(f, allow_pickle=False) as s:
            a = {name: s[name] for name in s.files}
    except Exception as exc:  # np.load/zipfile raise many types for damaged archives
        raise UnreadableStateError(f"{f}: unreadable state ({type(exc).__name__}: {exc})") from exc
    try:
        V = np.array(a["vertices"], dtype=float)
        Y = np.array(a["Y"], dtype=float)
        t = float(a["t"])
        k = int(a["step"])
        lam_g = np.array(a["lam_g"], dtype=float) if "lam_g" in a else None
        row = json.loads(str(a["row"])) if "row" in a else None
        S = np.array(a["simplices"], dtype=np.int64) if "simplices" in a else None
        free = np.array(a["free"], dtype=bool) if "free" in a else None
    except (KeyError, TypeError, ValueError) as exc:
        raise RunError(f"{f}: not a state of a run ({type(exc).__name__}: {exc})") from exc
    if k != step:
        raise RunError(f"{f}: holds step {k}, expected {step}")
    if S is not None:  # remeshed: its own connectivity
        if S.ndim != 2 or S.size == 0 or S.min() < 0 or S.max() >= V.shape[0] or V.shape[1:] != shape[1:]:
            raise RunError(f"{f}: simplices do not match its {V.shape[0]} vertices")
        shape = V.shape
    if free is not None and free.shape != (V.shape[0],):
        raise RunError(f"{f}: free mask has {free.shape} entries for {V.shape[0]} vertices")
    if V.shape != shape or Y.shape != shape:
        raise RunError(f"{f}: vertices have shape {V.shape}, the mesh has {shape}")
    if not (np.all(np.isfinite(V)) and np.all(np.isfinite(Y)) and np.isfinite(t)):
        raise RunError(f"{f}: non-finite values")
    if lam_g is not None and lam_g.size == 0:
        lam_g = None
    return Checkpoint(k, t, V, Y, lam_g, row if isinstance(row, dict) else {}, S, free)


def _cut_short(f: Path) -> bool:
    """Whether the file ``f`` begins as the program's npz files do (or is empty, or begins with zeros, as a file
    whose data a crash did not reach): an unreadable such file is a write cut short, not another program's file."""
    with open(f, "rb") as fh:
        head = fh.read(len(ZIP_MAGIC))
    return ZIP_MAGIC.startswith(head) or not head.strip(b"\0")


def scan_states(run_dir: Path, shape: tuple[int, ...]) -> tuple[list[Checkpoint], list[tuple[Path, str]],
                                                                 list[tuple[Path, str]]]:
    """Trusted states 0..k of a run directory and the files that cannot be trusted.

    Returns
    -------
    trusted : list of Checkpoint, step 0 first, without gaps
    cut_short : list of (file, reason): what a write cut short leaves and a resume deletes: stray temporary files,
        and an unreadable state file (:func:`_cut_short`) that is the last one and follows the trusted states
    other : list of (file, reason): the other untrusted state files (one that is unreadable and not the last, or
        readable but not a state of this run, e.g. another run's put in its place, and every state file after a gap
        or after such a file), which may be finished work: a resume refuses to go on while there are any

    Notes
    -----
    Both lists hold only files the program writes and recognises by name; any other file, e.g. the user's notes, is
    neither listed nor ever removed.
    """
    sdir = run_dir / "states"
    files: dict[int, Path] = {}
    temporary: list[tuple[Path, str]] = []
    if sdir.is_dir():
        for f in sorted(sdir.iterdir()):
            m = STATE_RE.match(f.name)
            if m and f.is_file():
                files[int(m[1])] = f
            elif TEMP_RE.match(f.name) and f.is_file():
                temporary.append((f, "temporary file left by an interrupted write"))
    temporary += [(f, "temporary file left by an interrupted write") for f in sorted(run_dir.iterdir())
                  if TEMP_RE.match(f.name) and f.is_file()]
    trusted: list[Checkpoint] = []
    cut_short: list[tuple[Path, str]] = []
    other: list[tuple[Path, str]] = []
    after: str | None = None
    for step in sorted(files):
        f = files[step]
        if after is None and step != len(trusted):
            after = f"after the missing state {len(trusted)}"
        if after is None:
            try:
                trusted.append(_load_state(f, step, shape))
            except UnreadableStateError as exc:
                if step == max(files) and _cut_short(f):
                    cut_short.append((f, f"{exc}: a write cut short"))
                else:
                    other.append((f, str(exc)))
                    after = f"after the untrusted state {step}"
            except RunError as exc:
                other.append((f, str(exc)))
                after = f"after the untrusted state {step}"
            continue
        other.append((f, after))
    return trusted, cut_short + temporary, other


def read_mesh_npz(d: Path) -> tuple[np.ndarray, np.ndarray]:
    """Initial vertices and simplices of a run directory."""
    try:
        with np.load(d / "mesh.npz", allow_pickle=False) as mz:
            return np.array(mz["vertices"]), np.array(mz["simplices"])
    except Exception as exc:  # np.load/zipfile raise many types for damaged archives
        raise RunError(f"{d / 'mesh.npz'}: unreadable ({type(exc).__name__}: {exc})") from exc


def read_config(d: Path) -> dict[str, Any]:
    """The stored configuration of a run directory (RunError when it is not one)."""
    for name in ("config.json", "mesh.npz"):
        if not (d / name).is_file():
            raise RunError(f"{d}: not a run directory (missing {name})")
    try:
        cfg = json.loads((d / "config.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RunError(f"{d / 'config.json'}: unreadable ({exc})") from exc
    if not isinstance(cfg, dict):
        raise RunError(f"{d / 'config.json'}: not a JSON object")
    return cfg


def lock_run_dir(d: Path) -> Any:
    """Hold an exclusive advisory lock on ``d/run.lock`` (RunError when another process holds it).

    The writer deletes run.lock when it closes (:func:`unlock_run_dir`), so a finished run
    directory holds no lock file; a lock taken on a file that was deleted meanwhile is retried
    on the new one, so two writers can never both hold "the" lock.
    """
    try:
        import fcntl
    except ImportError:  # not on POSIX: no locking
        return None
    path = d / "run.lock"
    while True:
        fh = open(path, "a+")  # noqa: SIM115 (held open for the writer's lifetime)
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            fh.seek(0)
            holder = fh.read().strip() or "another process"
            fh.close()
            raise RunError(f"{d}: is being written by {holder}; wait for it or stop it first") from exc
        try:
            same = os.stat(path).st_ino == os.fstat(fh.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        fh.close()  # the previous holder removed the file after we opened it: lock the new one
    fh.seek(0)
    fh.truncate()
    fh.write(f"pid {os.getpid()}\n")
    fh.flush()
    return fh


def unlock_run_dir(d: Path, lock: Any) -> None:
    """Delete ``d/run.lock`` (still holding it), then release the lock of :func:`lock_run_dir`."""
    if lock is None:
        return
    try:
        (d / "run.lock").unlink(missing_ok=True)
    finally:
        lock.close()


def check_new_run_dir(d: Path, *, keep_foreign: bool = False) -> None:
    """RunError unless ``d`` is absent or empty (or, with ``keep_foreign``, holds none of the program's files)."""
    if d.exists() and not d.is_dir():
        raise RunError(f"{d}: exists and is not a directory")
    if not d.is_dir():
        return
    sdir = d / "states"
    mine = any(f.name in RUN_FILES for f in d.iterdir()) or (
        sdir.is_dir() and any(STATE_RE.match(f.name) for f in sdir.iterdir()))
    if keep_foreign and not mine:
        return
    if (d / "config.json").is_file():
        raise RunError(f"{d}: holds a run already; continue it with 'willmore-nlp run --resume {d}', or start "
                       f"it afresh with --overwrite (deletes only the files the run wrote)")
    if any(d.iterdir()):
        raise RunError(f"{d}: output directory exists and is not empty (and is not a run directory); choose "
                       f"another --out")


def run_record(path: str | os.PathLike[str]) -> Path | None:
    """The run directory whose record ``path`` is part of, else None.

    The record of a run directory (a folder holding config.json, as for :func:`check_new_run_dir`) is the directory
    itself, its :data:`RUN_FILES` and its ``states/`` folder with everything in it; other paths in it, e.g.
    ``RUN/vtk`` or ``RUN/final.obj``, are not (``export`` writes there). Symbolic links and ``..`` are resolved.

    Parameters
    ----------
    path : a file or folder, existing or not

    Returns
    -------
    the run directory, or None when ``path`` is not part of a run's record
    """
    p = Path(path).resolve()
    if (p / "config.json").is_file():
        return p
    if p.name in RUN_FILES and (p.parent / "config.json").is_file():
        return p.parent
    return next((a.parent for a in (p, *p.parents) if a.name == "states" and (a.parent / "config.json").is_file()),
                None)


def clear_run_dir(d: Path) -> list[Path]:
    """Delete the files the program wrote in the run directory ``d`` (for ``run --overwrite``).

    Only :data:`RUN_FILES`, state files, their temporary files and an empty ``states/`` go; any
    other file (notes, a report, backups) stays. Refused (RunError) when ``d`` is not a run
    directory or another process is writing it.

    Returns
    -------
    the files removed
    """
    read_config(d)
    lock = lock_run_dir(d)
    removed: list[Path] = []
    try:
        sdir = d / "states"
        mine = [f for f in sdir.iterdir() if STATE_RE.match(f.name) or TEMP_RE.match(f.name)] if sdir.is_dir() else []
        mine += [f for f in d.iterdir() if (f.name in RUN_FILES and f.name != "run.lock") or TEMP_RE.match(f.name)]
        for f in mine:
            if f.is_file():
                f.unlink()
                removed.append(f)
        if sdir.is_dir() and not any(sdir.iterdir()):
            sdir.rmdir()
    finally:
        unlock_run_dir(d, lock)
    return removed


def _refusal(d: Path, j: int, other: list[tuple[Path, str]]) -> str:
    """The one-line refusal of a resume whose run directory ``d`` has the trusted states 0..j-1 and the untrusted
    state files ``other`` (:func:`scan_states`) that are no write cut short."""
    sdir, (f, why) = d / "states", other[0]
    then = f"then resume again (from step {max(j - 1, 0)}); nothing was changed"
    if f.name != f"state_{j:06d}.npz":
        return (f"{d}: cannot resume: state {j} is missing from {sdir} but {len(other)} later state files are there "
                f"(finished work, which the program does not delete); put state_{j:06d}.npz back, or move the later "
                f"states out of {sdir}, {then}")
    later = f", and {len(other) - 1} later state files follow it (finished work)" if len(other) > 1 else ""
    return (f"{d}: cannot resume: {why}{later}; the program deletes only writes of this run cut short: put the "
            f"run's own {f.name} back, or move it{' and the later states' if later else ''} out of {sdir}, {then}")


class RunWriter:
    """Writes a run directory as a flow advances.

    Parameters
    ----------
    out : path of the run directory (created; must be empty or absent)
    config : resolved configuration, stored as JSON
    mesh : initial mesh
    keep_foreign : allow files that are not the program's (left by :func:`clear_run_dir`)

    Notes
    -----
    Use :meth:`resume` to continue writing an existing run directory.
    """

    def __init__(self, out: str | os.PathLike[str], config: dict[str, Any], mesh: Mesh, *,
                 keep_foreign: bool = False) -> None:
        self.out = Path(out)
        check_new_run_dir(self.out, keep_foreign=keep_foreign)
        make_dirs(self.out)
        (self.out / "states").mkdir(exist_ok=True)
        self._lock = lock_run_dir(self.out)
        write_text_atomic(self.out / "config.json", json.dumps(config, indent=2, sort_keys=True, default=_json_default))
        _write_npz(self.out / "mesh.npz", vertices=mesh.vertices, simplices=mesh.simplices)
        self.simplices0 = np.asarray(mesh.simplices)
        self.rows: list[dict[str, Any]] = []
        self.keys: list[str] = []
        self.status: dict[str, Any] = {"state": "new", "sessions": []}
        self._written = -np.inf  # time.monotonic() of the last status.json write

    @classmethod
    def resume(cls, out: str | os.PathLike[str],
               check: Callable[[Checkpoint | None, dict[str, Any], dict[str, Any]], None] | None = None
               ) -> tuple[RunWriter, dict[str, Any], Checkpoint | None, list[str]]:
        """Open an existing run directory to continue it.

        Trusts the states 0..k that load and match the mesh (see :func:`scan_states`),
        deletes what writes cut short left (stray temporary files, an unreadable last
        state), and rewrites history.csv from the trusted states. ``check``, given, is called with the last
        trusted state, its history row (as the rewrite takes it: the state's own, else history.csv's; empty without
        a state) and status.json's contents (a dict, empty when unreadable) before any of that: an exception it
        raises leaves the directory as it was (a refused ``--steps`` had rewritten history.csv, dropping a line the
        user had added to it; a new user's check).

        Returns
        -------
        writer : RunWriter
        config : the stored configuration
        checkpoint : the last trusted state, or None when not even step 0 was written
        notes : one line per removed file

        Raises
        ------
        RunError
            Another process writes the directory, or a state file is untrusted and no write cut short (a gap in the
            states, or a state file that is not the run's, with state files after it: finished work the program
            does not delete); nothing is changed then, and the message says what the user can do.
        """
        d = Path(out)
        require_run_dir(d)
        config = read_config(d)
        V0, S0 = read_mesh_npz(d)
        lock = lock_run_dir(d)
        trusted, cut_short, other = scan_states(d, V0.shape)
        if other:
            unlock_run_dir(d, lock)
            raise RunError(_refusal(d, len(trusted), other))
        try:
            status = json.loads((d / "status.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            status = {}
        status = status if isinstance(status, dict) else {}
        csv_rows = read_history_csv(d / "history.csv")

        def row_of(ck: Checkpoint) -> dict[str, Any]:
            return ck.row or csv_rows.get(ck.step) or {"step": ck.step, "t": ck.t}

        if check is not None:
            try:
                check(trusted[-1] if trusted else None, row_of(trusted[-1]) if trusted else {}, status)
            except BaseException:
                unlock_run_dir(d, lock)
                raise
        notes = []
        for f, why in cut_short:
            if f.is_file():
                f.unlink()
                notes.append(f"removed {f} ({why})")
        self = cls.__new__(cls)
        self.out = d
        self._lock = lock
        self.simplices0 = S0
        self.rows = []
        self.keys = []
        for ck in trusted:
            row = row_of(ck)
            self.rows.append(row)
            self.keys.extend(k for k in row if k not in self.keys)
        self._rewrite_history()
        if not isinstance(status.get("sessions"), list):
            status = {"sessions": []}
        self.status = status
        return self, config, (trusted[-1] if trusted else None), notes

    def close(self) -> None:
        """Release the directory's lock and delete run.lock (a process that dies keeps the file, but
        the kernel releases its lock)."""
        lock, self._lock = self._lock, None
        unlock_run_dir(self.out, lock)

    # -- states and history ------------------------------------------------------------------
    def _rewrite_history(self) -> None:
        write_text_atomic(self.out / "history.csv", _csv_text(self.rows, self.keys, header=True))

    def add(self, r: StepResult, lam_g: np.ndarray | None = None, warm: dict[str, Any] | None = None) -> None:
        """Write the state of ``r`` (atomically), then append its row to history.csv.

        Parameters
        ----------
        r : the accepted state
        lam_g : the flow's constraint multipliers after it (needed for bit-identical resumes
            with warm starts)
        warm : the flow's :meth:`~willmore_nlp.flow.WillmoreFlow.warm_state` after it (the same), written to
            :data:`SOLVER_STATE` with the step number after the state (one file, replaced at every step that has
            one: newton-krylov's is 2-3 times the size of a state)
        """
        row = r.row()
        extra: dict[str, np.ndarray] = {} if lam_g is None else {"lam_g": np.asarray(lam_g, dtype=float)}
        if r.simplices is not None and not np.array_equal(r.simplices, self.simplices0):
            extra["simplices"] = np.asarray(r.simplices)
            if r.free is not None:
                extra["free"] = np.asarray(r.free, dtype=bool)
        def state() -> None:
            _write_npz(self.out / "states" / f"state_{r.step:06d}.npz",
                       vertices=r.vertices, Y=r.Y, t=r.t, step=r.step, tau=r.tau,
                       row=np.array(json.dumps(row, default=_json_default)), **extra)

        # the solver state is written in full first and renamed into place after the state, so that a disk that fills
        # up in either leaves the last state with its own solver state and the resume is bit for bit (written after
        # the state, a full disk once left state k with the solver state of k - 1)
        if warm:
            def both(tmp: Path) -> None:
                _npz_to(tmp, {"step": r.step, **{k: np.asarray(v) for k, v in warm.items()}})
                state()

            atomic_write(self.out / SOLVER_STATE, both)
        else:
            state()
        self.rows.append(row)
        new = [k for k in row if k not in self.keys]
        if new or len(self.rows) == 1:
            self.keys.extend(new)
            self._rewrite_history()
        else:
            with open(self.out / "history.csv", "a", encoding="utf-8") as fh:
                fh.write(_csv_text([row], self.keys, header=False))

    # -- status ------------------------------------------------------------------------------
    def set_status(self, state: str, **info: Any) -> None:
        """Record the run's state in status.json (atomically).

        Parameters
        ----------
        state : ``running`` (starts a session), ``completed``, ``interrupted``, ``abandoned``
            or ``failed`` (ends it)
        **info : further JSON-able fields (message, signal, rejected attempts ...)
        """
        now = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        last = self.rows[-1] if self.rows else {}
        sessions = self.status.setdefault("sessions", [])
        if state == "running":
            if sessions and "ended" not in sessions[-1]:
                sessions[-1].update({"ended": "unknown", "state": "died (no clean exit)"})
            sessions.append({"started": now, "pid": os.getpid(), "from_step": last.get("step", 0)})
        elif sessions:
            sessions[-1].update({"ended": now, "state": state, "to_step": last.get("step")})
        self.status.update({"state": state, "step": last.get("step"), "t": last.get("t"), "updated": now})
        for k in ("message", "signal", "rejected", "failed_step", "under_way"):
            self.status.pop(k, None)
        self.status.update(info)
        self._write_status()

    def progress(self, under_way: str | None = None) -> None:
        """Refresh a running run's status.json: the last state written (``step``, ``t``, ``updated``) and, with
        ``under_way``, the retry under way (the progress bar's text: the attempt rejected and the one that follows;
        cleared at the next accepted state). Without ``under_way`` at most every :data:`STATUS_SECONDS` (an
        accepted state; the state files are the record, this is for a reader watching a long run: a new user's check
        found status.json naming the run's first step throughout)."""
        named = "under_way" not in self.status and self.status.get("step") is not None  # (null before state 0)
        if under_way is None and named and time.monotonic() - self._written < STATUS_SECONDS:
            return
        last = self.rows[-1] if self.rows else {}
        self.status.update({"step": last.get("step"), "t": last.get("t"),
                            "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        if under_way is None:
            self.status.pop("under_way", None)
        else:
            self.status["under_way"] = under_way
        self._write_status()

    def warned(self, message: str) -> None:
        """Keep a warning of the run in status.json's ``warnings`` (each text once, in the order first shown; a resume
        adds its own): the terminal's lines were all a run left of them (a new user's check), and the report lists
        them."""
        kept = self.status.setdefault("warnings", [])
        if message not in kept:
            kept.append(message)
            self._write_status()

    def _write_status(self) -> None:
        write_text_atomic(self.out / "status.json", json.dumps(self.status, indent=2, default=_json_default))
        self._written = time.monotonic()


@dataclass
class Run:
    """A run read back from disk.

    Attributes
    ----------
    config : the resolved configuration
    history : one dict per state (numbers parsed)
    states : accepted states as Meshes, step 0 first (each with its own connectivity: the mesh
        control of surfaces may change it, see the history columns ``remeshed`` and ``vertices``)
    times : (len(states),) times of the states
    Y : list of (N, m) inner steps Y of the states
    status : content of status.json (empty for runs written before it existed)
    ignored : files that were not trusted (unreadable or temporary files, states of another run, states after a
        gap or after an untrusted one)
    """

    path: Path
    config: dict[str, Any]
    history: list[dict[str, Any]]
    states: list[Mesh]
    times: np.ndarray
    Y: list[np.ndarray]
    status: dict[str, Any] = field(default_factory=dict)
    ignored: list[str] = field(default_factory=list)


def load_run(run_dir: str | os.PathLike[str]) -> Run:
    """Read a run directory written by :class:`RunWriter`.

    Only trusted states are returned (see :func:`scan_states`); the history rows are those stored
    in the states (the record, as for a resume), or of history.csv for states written before
    they held their row.

    Raises
    ------
    RunError
        Missing config.json or mesh.npz, or no readable state at all.
    """
    d = Path(run_dir)
    config = read_config(d)
    V0, simplices = read_mesh_npz(d)
    trusted, cut_short, other = scan_states(d, V0.shape)
    untrusted = other + cut_short
    if not trusted:
        reason = f" ({untrusted[0][0]}: {untrusted[0][1]})" if untrusted else ""
        raise RunError(f"{d}: no readable state in {d / 'states'}{reason}")
    csv_rows = read_history_csv(d / "history.csv")
    try:
        states = [Mesh(ck.vertices, simplices if ck.simplices is None else ck.simplices,
                       str(d / "states" / f"state_{ck.step:06d}.npz")) for ck in trusted]
    except MeshError as exc:
        raise RunError(str(exc)) from exc
    history = [ck.row or csv_rows.get(ck.step) or {"step": ck.step, "t": ck.t} for ck in trusted]
    try:
        status = json.loads((d / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        status = {}
    return Run(d, config, history, states, np.array([ck.t for ck in trusted]), [ck.Y for ck in trusted],
               status if isinstance(status, dict) else {}, [f"{f}: {why}" for f, why in untrusted])
