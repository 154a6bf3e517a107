"""Export a run as a VTK time series (one .vtu per state plus a .pvd index) for ParaView & co.

Each state is written with meshio (a well-kept reader/writer of FEM mesh formats) as an unstructured
grid of lines (curves) or triangles (surfaces), 3-D points (curves in R^2 get z = 0), and point data:

* ``Y``: the inner mean-curvature-motion step Y[X] of the state,
* ``mean_curvature_vector``: -M_lumped^{-1} L X (:func:`willmore_nlp.geometry.mean_curvature_vector`),
* ``normal``: unit vertex normal (surfaces: area-weighted face normals; planar curves: the tangent
  turned by -90 degrees, outward for counter-clockwise curves; curves in R^3: the principal normal, the direction
  of the mean curvature vector (toward the centre of curvature), zero where it vanishes; it was zero everywhere,
  so that a space curve coloured by ``normal_speed`` looked motionless: a new user's check),
* ``velocity``: (X^k - X^{k-1}) / (t^k - t^{k-1}) (zero for the initial state and for a state whose
  vertices differ from the previous one's because the mesh control remeshed it; the flips and the
  light repair keep the vertices, and the velocity then includes the repair's tangential moves),
* ``normal_speed``: velocity . normal.

The .pvd index (a small VTK XML file listing the .vtu files with their times) is written with the
standard library's XML writer. :func:`export_state` writes one state as a mesh file instead (OBJ, OFF, PLY, STL,
npz or a text curve), for other tools.

Neither replaces a file unless asked to (``overwrite``): a mesh file that exists, or a folder that is not empty, is
refused. With ``overwrite`` a mesh file is replaced, and in a folder only what an earlier export wrote there:
run.pvd and the state_KKKKKK.vtu files, those the new export does not write again being deleted when the old run.pvd
lists them; any other file stays. A run's own record (the run directory, its config.json, mesh.npz, history.csv,
status.json, solver_state.npz and its ``states/`` folder: :func:`willmore_nlp.rundir.run_record`) is never written.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import NEW_VERTICES
from willmore_nlp.geometry import mean_curvature_vector, vertex_normals
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import CURVE_FORMATS, SURFACE_FORMATS, atomic_write, make_dirs, save_mesh
from willmore_nlp.rundir import RunError, load_run, run_record

PVD = "run.pvd"
"""The time index of a folder export."""

VTU_RE = re.compile(r"^state_\d{6,}\.vtu$")
"""File names of the states of a folder export."""


def _points3(V: np.ndarray) -> np.ndarray:
    return V if V.shape[1] == 3 else np.hstack([V, np.zeros((V.shape[0], 3 - V.shape[1]))])


def state_mesh(mesh: Mesh, Y: np.ndarray, prev: np.ndarray | None, dt: float) -> meshio.Mesh:
    """meshio mesh of one state with its point data (see module docstring)."""
    H = np.nan_to_num(mean_curvature_vector(mesh))
    if mesh.d == 1 and mesh.m == 3:  # a space curve: the principal normal
        size = np.linalg.norm(H, axis=1, keepdims=True)
        nrm = np.divide(H, size, out=np.zeros_like(H), where=size > 0)
    else:
        nrm = vertex_normals(mesh)
    same = prev is not None and prev.shape == mesh.vertices.shape
    vel = (mesh.vertices - prev) / dt if same and dt > 0 else np.zeros_like(mesh.vertices)
    cell = "line" if mesh.d == 1 else "triangle"
    return meshio.Mesh(
        _points3(mesh.vertices),
        [(cell, mesh.simplices)],
        point_data={
            "Y": _points3(Y),
            "mean_curvature_vector": _points3(H),
            "normal": _points3(nrm),
            "velocity": _points3(vel),
            "normal_speed": np.einsum("ij,ij->i", vel, nrm),
        },
    )


def check_target(out: str | os.PathLike[str], *, folder: bool, overwrite: bool) -> None:
    """Refuse an export target that would replace what export may not (see the module docstring).

    Parameters
    ----------
    out : the mesh file (``folder`` False) or the folder of the VTU files and run.pvd (``folder`` True)
    folder : whether ``out`` is a folder export's
    overwrite : replace an existing mesh file, or the run.pvd and state_KKKKKK.vtu of an earlier export in the folder

    Raises
    ------
    UserInputError
        ``out`` is part of a run's record (also with ``overwrite``); is a folder where a mesh file is asked for;
        exists (a file), or is a folder that is not empty, without ``overwrite``; or, with ``overwrite``, is a
        non-empty folder holding no earlier export (no run.pvd). The message names ``out``.
    """
    p = Path(out)
    run = run_record(p)
    if run is not None:
        example = run / ("vtk" if folder else f"final{p.suffix}")
        raise UserInputError(f"--out {p}: is part of the run directory {run} (its record of the run, which export "
                             f"never writes, even with --overwrite); choose another path, e.g. {example}")
    if folder:
        if not (p.is_dir() and any(p.iterdir())):
            return
        if not overwrite:
            raise UserInputError(f"--out {p}: folder exists and is not empty; --overwrite replaces the {PVD} and "
                                 "state_*.vtu files of an earlier export there (other files stay), or choose another "
                                 "--out")
        if not (p / PVD).is_file():
            raise UserInputError(f"--out {p}: folder is not empty and holds no earlier export (no {PVD}), so even "
                                 "--overwrite does not write into it; choose a new or empty folder")
    elif p.is_dir():
        raise UserInputError(f"--out {p}: is a folder, not a mesh file; choose another name")
    elif p.exists() and not overwrite:
        raise UserInputError(f"--out {p}: exists; --overwrite replaces it, or choose another name")


def _listed_states(pvd: Path) -> set[str]:
    """The state_KKKKKK.vtu names that the run.pvd ``pvd`` lists (none when it is missing or not a .pvd)."""
    try:
        root = ET.parse(pvd).getroot()
    except (OSError, ET.ParseError):
        return set()
    return {name for ds in root.iter("DataSet") if VTU_RE.match(name := ds.get("file") or "")}


def export_run(run_dir: str | os.PathLike[str], out: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Write ``out/state_KKKKKK.vtu`` for every state of a run and ``out/run.pvd``; returns the .pvd path.

    Parameters
    ----------
    run_dir : the run directory
    out : the folder to write: new or empty, or with ``overwrite`` one holding an earlier export (see the module
        docstring; :func:`check_target`)
    overwrite : replace the earlier export's run.pvd and state files, deleting those of its states that the new
        export does not write (those its run.pvd lists)

    Raises
    ------
    UserInputError
        ``out`` refused by :func:`check_target`, or ``run_dir`` not a readable run directory.
    """
    check_target(out, folder=True, overwrite=overwrite)
    run = load_run(run_dir)
    d = Path(out)
    pvd = d / PVD
    earlier = _listed_states(pvd)
    make_dirs(d)
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    coll = ET.SubElement(root, "Collection")
    prev, t_prev = None, 0.0
    written: set[str] = set()
    for row, mesh, Y, t in zip(run.history, run.states, run.Y, run.times, strict=True):
        action = str(row.get("remesh_action") or "")
        if int(row.get("remeshed") or 0) and (not action or NEW_VERTICES & set(action.split("+"))):
            prev = None  # remeshed: the vertices are not those of the previous state (flips and repair keep them)
        name = f"state_{int(row['step']):06d}.vtu"
        m = state_mesh(mesh, Y, prev, float(t) - t_prev)
        atomic_write(d / name, lambda p, m=m: meshio.write(p, m, file_format="vtu"))
        ET.SubElement(coll, "DataSet", timestep=repr(float(t)), group="", part="0", file=name)
        written.add(name)
        prev, t_prev = mesh.vertices, float(t)
    ET.indent(root)
    atomic_write(pvd, lambda p: ET.ElementTree(root).write(p, xml_declaration=True, encoding="utf-8"))
    for name in sorted(earlier - written):  # the earlier export's states that this one has not (a longer run's)
        (d / name).unlink(missing_ok=True)
    return pvd


MESH_FILE_FORMATS = (*SURFACE_FORMATS, *CURVE_FORMATS, ".npz")
"""Suffixes of ``export --out`` that ask for one state as a mesh file (:func:`export_state`); a name without a suffix
is a folder (the command line refuses any other suffix, e.g. ``--out x.csv``, which made a folder ``x.csv``)."""


def export_state(run_dir: str | os.PathLike[str], out: str | os.PathLike[str],
                 step: int | None = None, overwrite: bool = False) -> tuple[Path, int]:
    """Write the state of step ``step`` of a run (default: its last state) as the mesh file ``out``, its format
    from the suffix (:func:`willmore_nlp.mesh.io.save_mesh`: OBJ, OFF, npz and text curves round-trip exactly);
    returns ``out`` and the step written. A state after a remeshing is written with its own connectivity.

    Parameters
    ----------
    run_dir : the run directory
    out : the mesh file to write (an existing one only with ``overwrite``; never a run's own file:
        :func:`check_target`)
    step : the step whose state is written (default the last)
    overwrite : replace ``out`` if it exists

    Raises
    ------
    RunError
        No state of that step in the run (the message names the steps there are).
    UserInputError
        ``out`` refused by :func:`check_target`.
    """
    check_target(out, folder=False, overwrite=overwrite)
    run = load_run(run_dir)
    steps = [int(r["step"]) for r in run.history]
    k = len(steps) - 1 if step is None else next((i for i, s in enumerate(steps) if s == step), None)
    if k is None:
        raise RunError(f"{run_dir}: no state of step {step} (the run has steps {steps[0]} to {steps[-1]})")
    path = Path(out)
    save_mesh(run.states[k], path)
    return path, steps[k]
