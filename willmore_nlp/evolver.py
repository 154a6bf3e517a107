"""Optional external reference: Surface Evolver's minimised Willmore energy of a closed surface.

If Ken Brakke's Surface Evolver is installed (Debian package ``evolver-nox``, program ``evolver``),
:func:`evolver_reference` writes the surface as an Evolver datafile with zero surface tension and
the named quantity ``star_perp_sq_mean_curvature`` as the only energy, runs ``g ITERATIONS``
(Evolver's gradient descent) in batch mode and reads the energy before and after. Evolver's
mean curvature is the average (k1 + k2)/2, so its energy is int h_E^2 = 1/4 int (k1 + k2)^2; the
values returned are converted to this library's w = 1/2 int (k1 + k2)^2, i.e. multiplied by 2
(a round sphere: Evolver 4 pi, here 8 pi).

Vesicles (:func:`evolver_equilibrium`): the same energy with an optional fixed enclosed volume
(an Evolver ``body`` with a target ``volume``) and an optional fixed total area (a ``fixed``
named quantity of method ``facet_area``), and an optional spontaneous curvature (Evolver's
``h_zero`` = c0 / 2, since Evolver's h is half of this library's). Evolver enforces the
constraints by projection after every move, to about 1e-8 relative.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.settings import is_number

EVOLVER_TO_W = 2.0
"""Factor from Evolver's int ((k1 + k2)/2)^2 to w = 1/2 int (k1 + k2)^2."""


def find_evolver() -> str | None:
    """Path of the ``evolver`` program (``$WILLMORE_EVOLVER`` first), or None when not installed."""
    env = os.environ.get("WILLMORE_EVOLVER")
    if env:
        return env if Path(env).exists() else None
    return shutil.which("evolver")


def write_datafile(mesh: Mesh, path: str | os.PathLike[str], *, volume: float | None = None,
                   area: float | None = None, c0: float = 0.0) -> None:
    """Write a closed triangulated surface as an Evolver datafile (oriented faces, zero tension).

    Parameters
    ----------
    mesh : Mesh
        Closed triangulated surface in R^3 with outward-oriented faces.
    path : path of the datafile to write
    volume : float, optional
        Target enclosed volume: the faces form one Evolver body with this fixed volume.
    area : float, optional
        Target total area: a ``fixed`` named quantity ``area_q`` (method ``facet_area``).
    c0 : float
        Spontaneous curvature in this library's convention (h = k1 + k2, a sphere of radius R with
        outward normals has h = 2/R); written as Evolver's ``h_zero = c0 / 2``.

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
    lines = [f"// {mesh.source}: written by willmore_nlp for a Willmore-energy reference"]
    if c0 != 0.0:
        lines.append(f"parameter h_zero = {0.5 * c0:.17g}")
    lines.append("quantity willmore energy method star_perp_sq_mean_curvature global")
    if area is not None:
        lines.append(f"quantity area_q fixed = {area:.17g} method facet_area global")
    lines += ["", "vertices"]
    lines += [f"{i} {x:.17g} {y:.17g} {z:.17g}" for i, (x, y, z) in enumerate(mesh.vertices.tolist(), 1)]
    lines += ["", "edges"] + [f"{k} {a + 1} {b + 1}" for k, (a, b) in enumerate(order, 1)]
    lines += ["", "faces"] + [f"{k} {e1} {e2} {e3} tension 0" for k, (e1, e2, e3) in enumerate(faces, 1)]
    if volume is not None:
        lines += ["", "bodies", f"1 {' '.join(str(k) for k in range(1, len(faces) + 1))} volume {volume:.17g}"]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def _run(prog: str, cmd: Path, fe: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    """Run Evolver in batch mode on datafile ``fe`` with command file ``cmd``; a timeout is a RuntimeError."""
    try:
        return subprocess.run([prog, "-x", "-f", str(cmd), str(fe)], capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        # (timeout=0.05 raised a raw subprocess.TimeoutExpired; the docstrings promise RuntimeError)
        raise RuntimeError(f"Surface Evolver did not finish within the timeout of {timeout:g} s") from None


def _numbers(line: str, n: int) -> list[float]:
    """The ``n`` finite numbers after the tag of an output line of ours; otherwise a RuntimeError naming the line.

    (Evolver prints a NaN as ``(NaN)``; a long schedule on a degenerating mesh gave a raw ValueError
    "could not convert string to float: '(NaN)'".)"""
    try:
        vals = [float(x) for x in line.split()[1:n + 1]]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise RuntimeError(f"Surface Evolver printed a non-finite or unreadable value: {line.strip()[:200]!r}")
    return vals


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
        When Evolver fails or prints no energy (its output tail is in the message), prints NaN or an
        unreadable number (that line is in the message), or does not finish within ``timeout`` seconds.
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
        r = _run(prog, cmd, fe, timeout)
    vals = dict(re.findall(r"^(W[01]) (\S+)$", r.stdout, flags=re.MULTILINE))
    if "W0" not in vals or "W1" not in vals:
        raise RuntimeError(f"Surface Evolver failed (exit {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    w0, w1 = (_numbers(f"{k} {vals[k]}", 1)[0] for k in ("W0", "W1"))
    return {"initial": EVOLVER_TO_W * w0, "final": EVOLVER_TO_W * w1,
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
        r = _run(prog, cmd, fe, timeout)
    out: list[dict[str, Any]] = []
    verts: list[list[float]] = []
    for line in r.stdout.splitlines():
        if line.startswith("S "):
            if out:
                out[-1]["vertices"] = np.array(verts)
            w, clock = _numbers(line, 2)
            out.append({"command": stages[len(out) - 1] if out else "", "energy": EVOLVER_TO_W * w, "cpu": clock})
            verts = []
        elif line.startswith("V "):
            verts.append(_numbers(line, 3))
    if out:
        out[-1]["vertices"] = np.array(verts)
    if len(out) != len(stages) + 1 or any(o["vertices"].shape != mesh.vertices.shape for o in out):
        raise RuntimeError(f"Surface Evolver failed (exit {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    return out


DEFAULT_SCHEDULE: tuple[str, ...] = ("hessian_normal on", "normal_motion on", "g 50") + ("hessian_seek", "g 5") * 40
"""Default Evolver commands of :func:`evolver_equilibrium`: vertices move along the surface normal only
(``normal_motion`` for ``g``, ``hessian_normal`` for the Hessian), 50 gradient steps, then Newton line
searches (``hessian_seek``) each followed by 5 gradient steps (which re-project onto the constraints).
Normal motion is what keeps the mesh usable: minimising ``star_perp_sq_mean_curvature`` over all vertex
motions degenerates the triangles (measured on the 642-vertex oblate start of v = 0.65 after 121
commands of ``g``/``hessian_seek``: min angle 0.03 degrees, aspect ratio 1420, and this library's
discrete energy of that mesh 72 % above Evolver's own); vertex averaging ``V`` between gradient runs
keeps the triangles but biases the energy upwards (+0.6 % there) and never settles. Measured with this
schedule (642 vertices): v = 0.65 oblate start converges (relative change < 1e-10 over 4 commands)
after 18 commands in about 3 s, min angle 11.5 degrees."""


def evolver_equilibrium(mesh: Mesh, *, volume: float | str | None = "initial", area: float | str | None = "initial",
                        c0: float = 0.0, schedule: tuple[str, ...] | list[str] = DEFAULT_SCHEDULE,
                        tol: float = 1e-10, timeout: float = 600.0) -> dict[str, Any]:
    """Surface Evolver's constrained bending-energy minimiser from ``mesh`` (connectivity kept).

    The energy is Evolver's ``star_perp_sq_mean_curvature`` (see the module docstring), reported in
    this library's convention w = 1/2 int (k1 + k2 - c0)^2, with the enclosed volume and/or total
    area held fixed.

    Parameters
    ----------
    mesh : Mesh
        Closed triangulated surface in R^3, outward-oriented faces.
    volume, area : float, ``"initial"`` or None
        Target enclosed volume / total area: a number, ``"initial"`` (that of ``mesh``) or None (free).
    c0 : float
        Spontaneous curvature (this library's convention, see :func:`write_datafile`).
    schedule : sequence of str
        Evolver commands run in order; none may change the connectivity. The run stops early once
        the energy changed by less than ``tol`` (relative) over the last 4 commands.
    tol : float
        Relative energy change that ends the schedule early.
    timeout : float
        Seconds for the Evolver run.

    Returns
    -------
    dict with ``mesh`` (the final surface, same connectivity), ``energy`` and ``initial_energy`` (w),
    ``volume`` and ``area`` (Evolver's values of the final surface), ``target_volume`` and
    ``target_area`` (None when free), ``history`` ((n,) energies after each command), ``commands``
    (how many ran), ``converged`` (True when the run stopped because the energy changed by at most ``tol``
    relative over the last 4 commands; False when the schedule ran out first, which also issues a
    ``RuntimeWarning`` naming the schedule length and the last relative change, except for an empty
    schedule, which only evaluates), ``last_change`` (that relative change, over fewer commands when fewer
    ran), ``min_angle`` (the smallest triangle angle of the final mesh, degrees: a degenerating mesh shows
    here) and ``program``.

    Raises
    ------
    FileNotFoundError
        When Surface Evolver is not installed.
    ValueError
        For a mesh that is not a closed surface in R^3, or (with a volume target or c0 != 0) one oriented inward
        (:class:`~willmore_nlp.mesh.core.MeshError`); :class:`~willmore_nlp.errors.UserInputError` (a ValueError)
        for a target that is not positive and finite, a c0 or tol that is not finite (tol >= 0), a timeout that is
        not a positive finite number.
    RuntimeError
        When Evolver fails (its output tail is in the message), prints NaN or an unreadable number (that
        line is in the message), or does not finish within ``timeout`` seconds.
    """
    from willmore_nlp.geometry import enclosed_volume, measure, min_angles, require_outward

    if mesh.d != 2 or mesh.m != 3 or not mesh.is_closed:  # (an open mesh's "initial" volume, NaN, was refused as
        # 'volume target must be positive and finite, got 'initial'': a new user's check)
        raise ValueError(f"{mesh.source}: the Surface Evolver reference needs a closed triangulated surface in R^3")
    if volume is not None or (is_number(c0) and c0 != 0):
        # (an inward mesh with c0 = 2/R, the sphere's own curvature, gave 100.4 for ~0.008: c0's sign flipped with
        # the normals, silently; with volume="initial" it was 'volume target must be positive': a new user's check)
        require_outward(mesh, "evolver_equilibrium (the volume body and c0's sign)")
    # (c0 = nan reached Evolver, whose RuntimeError carried its raw output; a new-user check)
    numbers = (("c0", c0, "a finite number", True),
               ("tol", tol, "a finite number >= 0", is_number(tol) and tol >= 0),
               ("timeout", timeout, "a finite number of seconds > 0", is_number(timeout) and timeout > 0))
    for name, val, what, ok in numbers:
        if not (ok and is_number(val) and math.isfinite(val)):
            raise UserInputError(f"evolver_equilibrium: {name} must be {what}, got {val!r}")
    targets: dict[str, float | None] = {}
    for name, val, initial in (("volume", volume, enclosed_volume), ("area", area, measure)):
        if val is None:
            targets[name] = None
            continue
        if not (val == "initial" if isinstance(val, str) else is_number(val)):
            raise UserInputError(f"evolver_equilibrium: {name} must be a number, \"initial\" or None, got {val!r}")
        t = float(initial(mesh)) if isinstance(val, str) else float(val)
        if not (t > 0 and math.isfinite(t)):
            raise UserInputError(f"evolver_equilibrium: {name} target must be positive and finite, got {val!r}")
        targets[name] = t
    prog = find_evolver()
    if prog is None:
        raise FileNotFoundError("Surface Evolver ('evolver', Debian package evolver-nox) is not installed")
    vol_expr = "body[1].volume" if targets["volume"] is not None else "0"
    area_expr = "area_q.value" if targets["area"] is not None else "total_area"
    report = f'printf "S %.17g %.17g %.17g\\n", willmore.value, {vol_expr}, {area_expr}'
    loop = "".join(f"{c}; {report};\n"
                   f"if abs(willmore.value - w_4) <= {tol:.17g} * abs(willmore.value) then return;\n"
                   "w_4 := w_3; w_3 := w_2; w_2 := w_1; w_1 := willmore.value;\n" for c in schedule)
    script = ("target_tolerance := 1e-12\n" + report + "\n"
              + "w_1 := willmore.value; w_2 := 1e300; w_3 := 1e300; w_4 := 1e300\n"
              + ("run_all := {\n" + loop + "}\nrun_all\n" if schedule else "")
              + 'foreach vertex vv do printf "V %.17g %.17g %.17g\\n", vv.x, vv.y, vv.z\nq\nq\n')
    with tempfile.TemporaryDirectory(prefix="willmore_evolver_") as tmp:
        fe = Path(tmp) / "surface.fe"
        write_datafile(mesh, fe, volume=targets["volume"], area=targets["area"], c0=c0)
        cmd = Path(tmp) / "commands.txt"
        cmd.write_text(script, encoding="ascii")
        r = _run(prog, cmd, fe, timeout)
    rows = [_numbers(line, 3) for line in r.stdout.splitlines() if line.startswith("S ")]
    verts = [_numbers(line, 3) for line in r.stdout.splitlines() if line.startswith("V ")]
    if not rows or len(verts) != mesh.n_vertices:
        raise RuntimeError(f"Surface Evolver failed (exit {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    h = np.array([row[0] for row in rows])
    # the stopping test of the script, on the printed (%.17g, exact) energies: change over the last 4 commands
    k = min(4, len(h) - 1)
    diff = abs(h[-1] - h[-1 - k])
    converged = bool(k == 4 and diff <= tol * abs(h[-1]))
    change = diff / abs(h[-1]) if h[-1] != 0 else (0.0 if diff == 0 else math.inf)
    out_mesh = mesh.with_vertices(np.array(verts))
    min_angle = float(min_angles(out_mesh.vertices, out_mesh.simplices).min())
    if schedule and not converged:
        # (c0 = 0.8 on the oblate v = 0.65 start: all 83 default commands ran, min angle 0.0075 degrees, and
        # nothing said the energy was not an equilibrium)
        warnings.warn(f"evolver_equilibrium: not converged after the whole schedule of {len(schedule)} commands: "
                      f"relative energy change over the last {k} commands {change:.3g}, tol = {tol:g} "
                      f"(smallest triangle angle {min_angle:.3g} degrees)", RuntimeWarning, stacklevel=2)
    w = EVOLVER_TO_W * h
    return {"mesh": out_mesh, "energy": float(w[-1]), "initial_energy": float(w[0]),
            "volume": rows[-1][1] if targets["volume"] is not None else None, "area": rows[-1][2],
            "target_volume": targets["volume"], "target_area": targets["area"], "history": w,
            "commands": len(rows) - 1, "converged": converged, "last_change": float(change),
            "min_angle": min_angle, "program": prog}
