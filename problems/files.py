"""A flow of a user's mesh file (OBJ, PLY, OFF, STL, npz or a curve text file)."""

from __future__ import annotations

from willmore_nlp.mesh.io import load_mesh
from willmore_nlp.registry import Problem, ProblemError, register


@register("file")
def from_file(path: str = "", tau: float | None = None, tau_tilde: float | None = None,
              lam: float = 0.0, steps: int = 10) -> Problem:
    """A closed curve or surface read from ``path``; defaults tau = h, tau_tilde = h^2 / 4."""
    if not path:
        raise ProblemError("problem 'file' needs path=... (a mesh file)")
    mesh = load_mesh(path)
    h = mesh.h
    return Problem(mesh, h if tau is None else tau, 0.25 * h * h if tau_tilde is None else tau_tilde,
                   lam, steps=steps, description=f"mesh from {path}")
