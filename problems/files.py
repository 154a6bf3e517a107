"""A flow of a user's mesh file (OBJ, PLY, OFF, STL, npz or a curve text file)."""

from __future__ import annotations

from willmore_nlp.mesh.io import load_mesh
from willmore_nlp.registry import Problem, ProblemError, register


@register("file")
def from_file(path: str = "", tau: float | None = None, tau_tilde: float | None = None,
              lam: float = 0.0, steps: int = 10) -> Problem:
    """A closed curve or surface read from ``path``; defaults tau = h, tau_tilde = h^2 / 4 (curves) or h^2 / 100.

    Surfaces get the surface defaults of the other surface problems: tau_tilde = h^2 / 100 (the
    scheme shrinks spheres at rate 16 tau_tilde / R^5, see README) and the mesh control of
    :class:`~willmore_nlp.WillmoreFlow` (``remesh = "auto"``, the flow's default for surfaces; set
    ``remesh=off`` or ``mesh_control=off`` for the paper's scheme).
    """
    if not path:
        raise ProblemError("problem 'file' needs path=... (a mesh file)")
    mesh = load_mesh(path)
    h = mesh.h
    tt_factor = 0.25 if mesh.d == 1 else 0.01
    return Problem(mesh, h if tau is None else tau, tt_factor * h * h if tau_tilde is None else tau_tilde,
                   lam, steps=steps, description=f"mesh from {path}")
