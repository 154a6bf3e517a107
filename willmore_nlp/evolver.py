"""Optional external reference: Surface Evolver's minimised Willmore energy of a closed surface.

If Ken Brakke's Surface Evolver is installed (Debian package ``evolver-nox``, program ``evolver``),
:func:`evolver_reference` writes the surface as an Evolver datafile with zero surface tension and
the named quantity ``star_perp_sq_mean_curvature`` as the only energy, runs ``g ITERATIONS``
(Evolver's gradient descent) in batch mode and reads the energy before and after. Evolver's
mean curvature is the average (k1 + k2)/2, so its energy is int h_E^2 = 1/4 int (k1 + k2)^2; the
values returned are converted to this library's w = 1/2 int (k1 + k2)^2, i.e. multiplied by 2
(a round sphere: Evolver 4 pi, here 8 pi).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.mesh.core import Mesh

EVOLVER_TO_W = 2.0
"""Factor from Evolver's int ((k1 + k2)/2)^2 to w = 1/2 int (k1 + k2)^2."""


def find_evolver() -> str | None:
    """Path of the ``evolver`` program (``$WILLMORE_EVOLVER`` first), or None when not installed."""
    env = os.environ.get("WILLMORE_EVOLVER")
    if env:
        return env if Path(env).exists() else None
    return shutil.which("evolver")


def write_datafile(mesh: Mesh, path: str | os.PathLike[str]) -> None:
    """Write a closed triangulated surface as an Evolver datafile (oriented faces, zero tension).

    Raises
    ------
    ValueError
        For curves, open surfaces or surfaces not in R^3.
    """
    if mesh.d != 2 or mesh.m != 3 or not mesh.is_closed:
        raise ValueError(f"{mesh.source}: the Surface Evolver reference needs a closed triangulated surface in R^3")
    edges: dict[tuple[int, int], int] = {}
    order: list[tuple[int, int]] = []

    def edge(a: int, b: int) -> int:
        if (b, a) in edges:
            return -edges[(b, a)]
        if (a, b) not in edges:
            order.append((a, b))
            edges[(a, b)] = len(order)
        return edges[(a, b)]

    faces = [(edge(a, b), edge(b, c), edge(c, a)) for a, b, c in mesh.simplices.tolist()]
    lines = [f"// {mesh.source}: written by willmore_nlp for a Willmore-energy reference",
             "quantity willmore energy method star_perp_sq_mean_curvature global", "", "vertices"]
    lines += [f"{i} {x:.17g} {y:.17g} {z:.17g}" for i, (x, y, z) in enumerate(mesh.vertices.tolist(), 1)]
    lines += ["", "edges"] + [f"{k} {a + 1} {b + 1}" for k, (a, b) in enumerate(order, 1)]
    lines += ["", "faces"] + [f"{k} {e1} {e2} {e3} tension 0" for k, (e1, e2, e3) in enumerate(faces, 1)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def evolver_reference(mesh: Mesh, iterations: int = 200, timeout: float = 600.0) -> dict[str, Any]:
    """Surface Evolver's Willmore energy of ``mesh`` before and after ``iterations`` of ``g``.

    Returns
    -------
    dict with ``initial`` and ``final`` (in this library's convention w = 1/2 int (k1+k2)^2),
    ``iterations`` and ``program``.

    Raises
    ------
    FileNotFoundError
        When Surface Evolver is not installed.
    RuntimeError
        When Evolver fails or prints no energy (its output tail is in the message).
    """
    prog = find_evolver()
    if prog is None:
        raise FileNotFoundError("Surface Evolver ('evolver', Debian package evolver-nox) is not installed")
    with tempfile.TemporaryDirectory(prefix="willmore_evolver_") as tmp:
        fe = Path(tmp) / "surface.fe"
        write_datafile(mesh, fe)
        cmd = Path(tmp) / "commands.txt"
        cmd.write_text('printf "W0 %.17g\\n", willmore.value\n'
                       f"g {int(iterations)}\n"
                       'printf "W1 %.17g\\n", willmore.value\nq\nq\n', encoding="ascii")
        r = subprocess.run([prog, "-x", "-f", str(cmd), str(fe)], capture_output=True, text=True,
                           timeout=timeout, stdin=subprocess.DEVNULL)
    vals = dict(re.findall(r"^(W[01]) (\S+)$", r.stdout, flags=re.MULTILINE))
    if "W0" not in vals or "W1" not in vals:
        raise RuntimeError(f"Surface Evolver failed (exit {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    return {"initial": EVOLVER_TO_W * float(vals["W0"]), "final": EVOLVER_TO_W * float(vals["W1"]),
            "iterations": int(iterations), "program": prog}


def evolver_trajectory(mesh: Mesh, stages: list[str], timeout: float = 600.0) -> list[dict[str, Any]]:
    """Run Evolver commands one stage at a time, recording the surface after each.

    Parameters
    ----------
    mesh : Mesh
        Closed triangulated surface in R^3 (written with :func:`write_datafile`; zero tension, the
        Willmore quantity as the only energy).
    stages : list of str
        Evolver commands, e.g. ``["g 10", "hessian_seek"]``; none may refine or otherwise change
        the connectivity (the vertices are read back in the input order).
    timeout : float
        Seconds for the whole Evolver run.

    Returns
    -------
    list of dict, one for the initial surface and one per stage: ``command`` ("" for the initial),
    ``energy`` (Evolver's Willmore energy in this library's convention, see :data:`EVOLVER_TO_W`),
    ``cpu`` (Evolver's ``clock``, CPU seconds since it started, datafile reading included) and
    ``vertices`` ((N, 3) positions).

    Raises
    ------
    FileNotFoundError, RuntimeError
        As :func:`evolver_reference`.
    """
    prog = find_evolver()
    if prog is None:
        raise FileNotFoundError("Surface Evolver ('evolver', Debian package evolver-nox) is not installed")
    report = ('printf "S %.17g %.17g\\n", willmore.value, clock\n'
              'foreach vertex vv do printf "V %.17g %.17g %.17g\\n", vv.x, vv.y, vv.z\n')
    script = report + "".join(f"{c}\n{report}" for c in stages) + "q\nq\n"
    with tempfile.TemporaryDirectory(prefix="willmore_evolver_") as tmp:
        fe = Path(tmp) / "surface.fe"
        write_datafile(mesh, fe)
        cmd = Path(tmp) / "commands.txt"
        cmd.write_text(script, encoding="ascii")
        r = subprocess.run([prog, "-x", "-f", str(cmd), str(fe)], capture_output=True, text=True,
                           timeout=timeout, stdin=subprocess.DEVNULL)
    out: list[dict[str, Any]] = []
    verts: list[list[float]] = []
    for line in r.stdout.splitlines():
        if line.startswith("S "):
            if out:
                out[-1]["vertices"] = np.array(verts)
            w, clock = map(float, line.split()[1:3])
            out.append({"command": stages[len(out) - 1] if out else "", "energy": EVOLVER_TO_W * w, "cpu": clock})
            verts = []
        elif line.startswith("V "):
            verts.append([float(v) for v in line.split()[1:4]])
    if out:
        out[-1]["vertices"] = np.array(verts)
    if len(out) != len(stages) + 1 or any(o["vertices"].shape != mesh.vertices.shape for o in out):
        raise RuntimeError(f"Surface Evolver failed (exit {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    return out
