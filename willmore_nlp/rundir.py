"""Run directories: resolved config, history.csv and one npz per accepted state.

Layout::

    RUN/config.json          resolved configuration (problem, parameters, flow options, versions)
    RUN/mesh.npz             simplices and initial vertices
    RUN/history.csv          one row per state (step 0 = initial), appended as steps are accepted
    RUN/states/state_KKKKKK.npz   vertices, Y, t, step of every accepted state

Every file is written atomically (temporary file + rename), so an interrupted run leaves
only complete files; :func:`load_run` reads them back.
"""

from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.flow import StepResult
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import atomic_write


class RunError(ValueError):
    """A run directory is missing, incomplete or inconsistent."""


def _write_text(path: Path, text: str) -> None:
    def w(t: Path) -> None:
        with open(t, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())

    atomic_write(path, w)


def _write_npz(path: Path, **arrays: Any) -> None:
    def w(t: Path) -> None:
        with open(t, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())

    atomic_write(path, w)


class RunWriter:
    """Writes a run directory as a flow advances.

    Parameters
    ----------
    out : path of the run directory (created; must be empty or absent unless ``resume``)
    config : resolved configuration, stored as JSON
    mesh : initial mesh
    """

    def __init__(self, out: str | os.PathLike[str], config: dict[str, Any], mesh: Mesh) -> None:
        self.out = Path(out)
        if self.out.exists() and any(self.out.iterdir()):
            raise RunError(f"{self.out}: output directory exists and is not empty")
        (self.out / "states").mkdir(parents=True, exist_ok=True)
        _write_text(self.out / "config.json", json.dumps(config, indent=2, sort_keys=True, default=str))
        _write_npz(self.out / "mesh.npz", vertices=mesh.vertices, simplices=mesh.simplices)
        self.rows: list[dict[str, Any]] = []

    def add(self, r: StepResult) -> None:
        """Write the state of ``r`` and append its row to history.csv (both atomically)."""
        _write_npz(self.out / "states" / f"state_{r.step:06d}.npz",
                   vertices=r.vertices, Y=r.Y, t=r.t, step=r.step, tau=r.tau)
        self.rows.append(r.row())
        keys: list[str] = []
        for row in self.rows:
            keys.extend(k for k in row if k not in keys)
        buf = io.StringIO()
        wr = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
        wr.writeheader()
        wr.writerows(self.rows)
        _write_text(self.out / "history.csv", buf.getvalue())


@dataclass
class Run:
    """A run read back from disk.

    Attributes
    ----------
    config : the resolved configuration
    history : one dict per state (numbers parsed)
    states : accepted states as Meshes (same topology), step 0 first
    times : (len(states),) times of the states
    Y : list of (N, m) inner steps Y of the states
    """

    path: Path
    config: dict[str, Any]
    history: list[dict[str, Any]]
    states: list[Mesh]
    times: np.ndarray
    Y: list[np.ndarray]


def _parse(v: str) -> Any:
    try:
        return int(v)
    except ValueError:
        try:
            return float(v)
        except ValueError:
            return v


def load_run(run_dir: str | os.PathLike[str]) -> Run:
    """Read a run directory written by :class:`RunWriter`.

    Raises
    ------
    RunError
        Missing files, unreadable states, or states that do not match the mesh.
    """
    d = Path(run_dir)
    for name in ("config.json", "mesh.npz", "history.csv"):
        if not (d / name).is_file():
            raise RunError(f"{d}: not a run directory (missing {name})")
    config = json.loads((d / "config.json").read_text(encoding="utf-8"))
    with np.load(d / "mesh.npz") as mz:
        simplices = mz["simplices"]
        n = mz["vertices"].shape
    with open(d / "history.csv", encoding="utf-8") as fh:
        history = [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    states, times, Ys = [], [], []
    for row in history:
        f = d / "states" / f"state_{int(row['step']):06d}.npz"
        try:
            with np.load(f) as s:
                V, Y, t = s["vertices"], s["Y"], float(s["t"])
        except (OSError, KeyError, ValueError) as exc:
            raise RunError(f"{f}: unreadable state ({exc})") from exc
        if V.shape != n:
            raise RunError(f"{f}: vertices have shape {V.shape}, the mesh has {n}")
        states.append(Mesh(V, simplices, str(f)))
        times.append(t)
        Ys.append(Y)
    return Run(d, config, history, states, np.array(times), Ys)
