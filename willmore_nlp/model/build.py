"""Build the step problem of a mesh (and, later, of its boundary description or anisotropy)."""

from __future__ import annotations

from willmore_nlp.mesh.core import Mesh
from willmore_nlp.model.energies import isotropic
from willmore_nlp.model.step import StepProblem


def build_step(mesh: Mesh) -> StepProblem:
    """Isotropic step problem of a closed mesh: all X and Y unknown."""
    return StepProblem(mesh.simplices, mesh.n_vertices, mesh.m, isotropic, name=f"iso_d{mesh.d}_m{mesh.m}")
