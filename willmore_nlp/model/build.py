"""Build the step problem of a mesh, with optional boundary conditions and anisotropy."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.energies import isotropic
from willmore_nlp.model.step import StepProblem


@dataclass
class StepSetup:
    """A step problem and the fixed data its parameter vector needs besides (Xk, tau, tt, lam).

    Attributes
    ----------
    problem : StepProblem
    extra : (N, m) nodal vector for problems with ``g_extra`` (the co-normal term), else None
    """

    problem: StepProblem
    extra: np.ndarray | None = None

    def params(self, Xk: np.ndarray, tau: float, tt: float, lam: float) -> np.ndarray:
        """Parameter vector of a step from Xk."""
        return self.problem.pack_p(Xk, tau, tt, lam, self.extra)


def build_step(mesh: Mesh, *, boundary: Any = None, anisotropy: Any = None) -> StepSetup:
    """The step problem of ``mesh``.

    Parameters
    ----------
    mesh : Mesh
        Closed unless ``boundary`` is given.
    boundary : optional
        Boundary description (clamped boundary variants).
    anisotropy : optional
        Anisotropy gamma (fully nonlinear anisotropic scheme).
    """
    if boundary is not None or anisotropy is not None:
        raise NotImplementedError("boundary conditions and anisotropy are not available yet")
    if not mesh.is_closed:
        raise MeshError(
            f"{mesh.source}: the mesh has a boundary ({len(mesh.boundary_facets)} boundary "
            "facets) but closed-surface flow needs a closed mesh; pass boundary=... for a clamped flow"
        )
    problem = StepProblem(mesh.simplices, mesh.n_vertices, mesh.m, isotropic, name=f"iso_d{mesh.d}_m{mesh.m}")
    return StepSetup(problem)
