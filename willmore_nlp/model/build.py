"""Build the step problem of a mesh, with optional boundary conditions and anisotropy."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from willmore_nlp.anisotropy import Anisotropy, get_anisotropy
from willmore_nlp.boundary import Boundary, BoundaryData, boundary_data
from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.energies import anisotropic, isotropic
from willmore_nlp.model.step import StepProblem
from willmore_nlp.tangential import TangentialControl, n_nodal, nodal_parameters


@dataclass
class StepSetup:
    """A step problem and the fixed data its parameter vector needs besides (Xk, tau, tt, lam).

    Attributes
    ----------
    problem : StepProblem
    extra : (N, m) nodal vector for problems with ``g_extra`` (the co-normal term), else None
    boundary : clamped-boundary data, or None
    anisotropy : the anisotropy, or None
    control : the tangential control (:mod:`willmore_nlp.tangential`); when enabled, the parameter
        vector carries its weight and the per-node data of Xk over ``simplices``
    simplices : (K, d + 1) all simplices of the mesh (the control's neighbourhoods and tangent spaces)
    """

    problem: StepProblem
    extra: np.ndarray | None = None
    boundary: BoundaryData | None = None
    anisotropy: Anisotropy | None = None
    control: TangentialControl = field(default_factory=TangentialControl)
    simplices: np.ndarray | None = None

    def params(self, Xk: np.ndarray, tau: float, tt: float, lam: float) -> np.ndarray:
        """Parameter vector of a step from Xk."""
        if not self.control.enabled:
            return self.problem.pack_p(Xk, tau, tt, lam, self.extra)
        S = self.problem.simplices if self.simplices is None else self.simplices
        Q = nodal_parameters(np.asarray(Xk, float), S, self.problem.x_free, self.control.fraction(tau))
        return self.problem.pack_p(Xk, tau, tt, lam, self.extra, more=(self.control.weight,), nodal=Q)


def _tag(beta: float) -> str:
    """Problem-name suffix of a tangential weight (empty for the paper's beta = 1)."""
    return "" if beta == 1.0 else f"_tw{beta:g}"


def _control_layout(mesh: Mesh, control: TangentialControl) -> dict[str, Any]:
    """StepProblem keywords of a tangential control: one more scalar (its weight) and per-node data."""
    if not control.enabled:
        return {}
    return {"n_par": 4, "n_nodal": n_nodal(mesh.m)}


def build_step(mesh: Mesh, *, boundary: Any = None, anisotropy: Any = None,
               tangential_weight: float = 1.0, tangential_control: TangentialControl | None = None) -> StepSetup:
    """The step problem of ``mesh``.

    Parameters
    ----------
    mesh : Mesh
        Closed unless ``boundary`` is given.
    boundary : Boundary, optional
        Clamped boundary (:mod:`willmore_nlp.boundary`): the "conormal" variant poses the inner
        problem on the patch with the co-normal term ``g -= tt Nco``; the "ring" variant on patch +
        ring, with the outer objective weighted 0 on the ring and Y fixed on the ring's outer nodes.
    anisotropy : str, callable or Anisotropy, optional
        Anisotropy gamma for the fully nonlinear anisotropic scheme (:mod:`willmore_nlp.anisotropy`):
        closed curves in R^2 and closed surfaces in R^3.
    tangential_weight : float
        beta >= 1: the distance term charges tangential displacement beta times
        (:func:`willmore_nlp.model.energies.distance`); 1 is the paper's scheme.
    tangential_control : TangentialControl, optional
        Tangential motion inside the step (:mod:`willmore_nlp.tangential`); None or method "off"
        is the paper's scheme.
    """
    control = TangentialControl() if tangential_control is None else tangential_control
    if not isinstance(control, TangentialControl):
        raise TypeError(f"tangential_control must be a TangentialControl, got {type(control).__name__}")
    if control.enabled and mesh.d == 2 and mesh.m != 3:
        raise MeshError(f"{mesh.source}: tangential_control needs surfaces in R^3, got R^{mesh.m}")
    beta = float(tangential_weight)
    if not (np.isfinite(beta) and beta >= 1.0):
        raise UserInputError(f"tangential_weight must be a number >= 1 (1 = the paper's L^2 distance), "
                         f"got {tangential_weight!r}")
    if beta != 1.0 and mesh.d == 2 and mesh.m != 3:
        raise MeshError(f"{mesh.source}: tangential_weight needs surfaces in R^3, got R^{mesh.m}")
    if anisotropy is not None:
        if boundary is not None:
            raise NotImplementedError("anisotropic flow with clamped boundaries is not implemented")
        return _build_anisotropic(mesh, anisotropy, beta, control)
    if boundary is not None:
        return _build_clamped(mesh, boundary, beta, control)
    if not mesh.is_closed:
        raise MeshError(
            f"{mesh.source}: the mesh has a boundary ({len(mesh.boundary_facets)} boundary "
            "facets) but closed-surface flow needs a closed mesh; pass boundary=... for a clamped flow"
        )
    problem = StepProblem(mesh.simplices, mesh.n_vertices, mesh.m, isotropic(beta),
                          name=f"iso_d{mesh.d}_m{mesh.m}{_tag(beta)}{control.tag}", tangential_weight=beta,
                          **_control_layout(mesh, control))
    return StepSetup(problem, control=control)


def _build_clamped(mesh: Mesh, boundary: Boundary, beta: float, control: TangentialControl) -> StepSetup:
    """Step problem of a free patch with a clamped boundary (both variants; docs/theory/scheme.md).

    The inner problem lives on patch + ring (when there is a ring): X is unknown on the free
    vertices, Y on the patch nodes (free vertices and Gamma) and equal to X on the ring's outer
    nodes. Ring elements carry ``c = (0, 1)`` in the "ring" variant and ``c = (0, 0)`` in the
    "conormal" variant, whose co-normal term ``-tt Nco`` stands for the ring's stiffness.
    """
    if not isinstance(boundary, Boundary):
        raise TypeError(f"boundary must be a willmore_nlp.boundary.Boundary, got {type(boundary).__name__}")
    bd = boundary_data(mesh, boundary)
    cells = np.flatnonzero(bd.patch | bd.ring)
    patch = bd.patch[cells].astype(float)
    stiff = patch if bd.variant == "conormal" else np.ones_like(patch)
    problem = StepProblem(mesh.simplices[cells], mesh.n_vertices, mesh.m, isotropic(beta), x_free=bd.free,
                          y_free=bd.patch_nodes, element_const=np.column_stack([patch, stiff]),
                          g_extra=bd.variant == "conormal",
                          name=f"clamped_d{mesh.d}_m{mesh.m}{_tag(beta)}{control.tag}",
                          tangential_weight=beta, **_control_layout(mesh, control))
    return StepSetup(problem, bd.nco if bd.variant == "conormal" else None, bd, control=control,
                     simplices=mesh.simplices)


def _build_anisotropic(mesh: Mesh, anisotropy: Any, beta: float, control: TangentialControl) -> StepSetup:
    """Step problem of the fully nonlinear anisotropic scheme on a closed mesh."""
    if not mesh.is_closed:
        raise MeshError(f"{mesh.source}: anisotropic flow needs a closed curve or surface")
    if mesh.d == 1 and mesh.m != 2:
        raise MeshError(f"{mesh.source}: anisotropic curve flow needs a curve in R^2 (the normal of a curve in "
                        f"R^{mesh.m} is not a vector), got R^{mesh.m}")
    an = get_anisotropy(anisotropy, mesh.m)
    problem = StepProblem(mesh.simplices, mesh.n_vertices, mesh.m, anisotropic(an.gamma, beta),
                          name=f"aniso_{an.name}_d{mesh.d}_m{mesh.m}{_tag(beta)}{control.tag}", anisotropic=True,
                          tangential_weight=beta, **_control_layout(mesh, control))
    return StepSetup(problem, anisotropy=an, control=control)
