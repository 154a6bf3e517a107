"""Tangential control inside the step: a mesh-improving tangential target for the distance term.

With ``tangential_control = "meanratio"`` the outer objective of the step gets the term

    beta * sum_i m_i |P_i (X_i - Xk_i - S_i)|^2            (m_i = lumped mass of node i in Xk)

(:class:`~willmore_nlp.model.terms.tangential_control.TangentialControlTerm`). ``P_i`` is the orthogonal
projector onto the tangent space of the mesh at node i in Xk (``t t^T`` along the unit vertex tangent of a curve,
``I - n n^T`` with the area-weighted unit vertex normal of a surface) and ``S_i = P_i U_i`` the
tangential part of a mesh-improving step U of Xk: on a surface a diagonally scaled descent step of
the scale-invariant mean-ratio distortion of the triangles (:func:`surface_displacement`), on a
curve the step to the midpoint of the neighbours, equidistribution (:func:`curve_displacement`). The gradient of
the term with respect to X_i is ``2 beta m_i P_i (...)``, a tangent vector at node i: the normal
component of every nodal equation of the step is the paper's,
so the normal velocity, hence the geometric flow as h -> 0, is unchanged, while the tangential
motion follows S (by the factor beta / (1 + beta) when nothing else pulls) and keeps the nodes spread.

This module computes the per-node data ``Q_i = [vec(P_i), S_i]`` ((m*m + m) numbers) of Xk that the
step problem carries as per-node parameters (:class:`willmore_nlp.model.step.StepProblem`, ``n_nodal``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.topology import scatter_sum
from willmore_nlp.mesh.validate import face_normals, vertex_normals_of

CONTROL_METHODS = ("auto", "off", "meanratio")
"""Values of the ``tangential_control`` option: "off" is the paper's scheme, "auto" (the default) is "meanratio" where
it was measured to help and "off" elsewhere (:func:`resolve_method`)."""

DEFAULT_CONTROL_WEIGHT = 1.0
"""Default beta of the mean-ratio control (``tangential_control_weight``). Measured against 0.3 and 3 on the
mesh-quality study's surfaces (docs/guide/mesh_quality_measurements.md, "Rest means rest"): 1 was at least as good as
the repair alone in every case (the 642-v vesicle cup rests with 1 and not with 0.3; 3 slows the blends' rest)."""

ANISOTROPIC_CLAMPED_CONTROL_WEIGHT = 100.0
"""Default beta of the control on a clamped surface with an anisotropy (:func:`default_weight`). Measured
(2026-11-30, docs/guide/anisotropy.md, "Clamped surfaces"): with gamma1 and the ring variant every step of weight 1
slid the first free row toward Gamma (0.18 h per step at rest; the stepped triangles there at 5-7 deg) and an isotropic
remeshing undid it after every step, with 4 retries per step on ``sphere_cap``; weight 10 still let it fall to 14.6
deg, 30 to 19 deg every fourth step; 100 keeps every stepped state above 32 deg with no remeshing and no retry, and
gamma0 and gamma2:1e-2 on the same patch run as well as with 1. On closed anisotropic surfaces it lets the energy
rise (a gamma1 ellipsoid: W_gamma 42.42 -> 43.25 in 30 steps), so they keep :data:`DEFAULT_CONTROL_WEIGHT`."""


def resolve_method(method: str, mesh: Mesh, mesh_control: str, variational: bool,
                   free: np.ndarray | None = None) -> str:
    """The control a flow runs: ``method`` itself unless it is "auto".

    "auto" is "meanratio" for a triangle surface in R^3 when the mesh control is on (``mesh_control == "auto"``),
    the step solver minimises W (``variational``; the semi-implicit baseline does not), the initial mesh resolves a
    tangent plane at every moving node (no :func:`unresolved_nodes` among the ``free`` ones: all nodes when None),
    and the surface is clamped (``free`` given: the patch moves, whatever the genus of the whole mesh), open, or
    closed of genus 0. Otherwise "off", the paper's scheme. Measured reasons (docs/guide/tangential_control.md):
    curves are accurate without it; on a trimesh box (386 v, sharp edges) the first step with it failed at every tau
    from h to h/256, and fading the term at such nodes instead cost `torus_hole` (noisy fill) its rest and the
    vesicle cup its run; on a trimesh torus (R/r = 2.5, 512 v) the energy fell 3.6 % below the grid's Clifford torus
    by t = 0.13 with it, where the flow without it sits on it.
    """
    if method != "auto":
        return method
    if not (mesh.d == 2 and mesh.m == 3 and mesh_control == "auto" and variational):
        return "off"
    moving = np.ones(mesh.n_vertices, bool) if free is None else np.asarray(free, bool)
    if np.any(unresolved_nodes(mesh)[moving]):
        return "off"
    if free is not None or not mesh.is_closed:
        return "meanratio"
    from willmore_nlp.mesh.topology import components, euler_characteristic

    return "meanratio" if euler_characteristic(mesh.simplices) == 2 * components(mesh)[0] else "off"


def default_weight(mesh: Mesh, anisotropy: object, clamped: bool) -> float:
    """The control's weight when ``tangential_control_weight`` is not given:
    :data:`ANISOTROPIC_CLAMPED_CONTROL_WEIGHT` for a clamped surface with an ``anisotropy``, else
    :data:`DEFAULT_CONTROL_WEIGHT`."""
    if clamped and anisotropy is not None and mesh.d == 2:
        return ANISOTROPIC_CLAMPED_CONTROL_WEIGHT
    return DEFAULT_CONTROL_WEIGHT


@dataclass(frozen=True)
class TangentialControl:
    """A tangential control of the step.

    Attributes
    ----------
    method : "off" or "meanratio" ("auto" is resolved before, :func:`resolve_method`)
    weight : beta > 0, the weight of the tangential target term relative to the distance term
    time : relaxation time T_c >= 0 of the mesh: a step of size tau takes the fraction
        ``min(1, tau / T_c)`` of the mesh-improving step as its target (:meth:`fraction`); 0 takes all of it
    """

    method: str = "off"
    weight: float = DEFAULT_CONTROL_WEIGHT
    time: float = 0.0

    def __post_init__(self) -> None:
        if self.method not in CONTROL_METHODS[1:]:
            raise UserInputError(f"tangential_control must be one of {', '.join(map(repr, CONTROL_METHODS[1:]))}, "
                                 f"got {self.method!r}")
        w = self.weight
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not (np.isfinite(w) and w > 0):
            raise UserInputError(f"tangential_control_weight must be a number > 0, got {w!r}")
        t = self.time
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (np.isfinite(t) and t >= 0):
            raise UserInputError(f"tangential_control_time must be a number >= 0, got {t!r}")

    def fraction(self, tau: float) -> float:
        """Fraction ``min(1, tau / T_c)`` of the mesh-improving step targeted by a step of size tau (1 if T_c = 0)."""
        return 1.0 if self.time == 0 else min(1.0, tau / self.time)

    @property
    def enabled(self) -> bool:
        """True unless the method is "off"."""
        return self.method != "off"

    @property
    def tag(self) -> str:
        """Problem-name suffix (empty when off; the weight is a runtime parameter, not part of the name)."""
        return "" if not self.enabled else f"_tc{self.method}"


def n_nodal(m: int) -> int:
    """Per-node parameters of the control in R^m: the projector (m*m) and the target S (m)."""
    return m * m + m


def vertex_projectors(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Orthogonal projectors onto the vertex tangent spaces of a curve or a triangle surface in R^3.

    Curves: ``t t^T`` with t the normalised sum of the unit directions of the (at most two) edges
    at the node, oriented along the curve. Surfaces: ``I - n n^T`` with n the normalised sum of the
    incident triangles' area vectors. Nodes without simplices get the zero projector.

    Parameters
    ----------
    V : (N, m) vertices
    S : (K, d + 1) simplices, d = 1 or 2 (d = 2 needs m = 3)

    Returns
    -------
    (N, m, m) array
    """
    N, m = V.shape
    d = S.shape[1] - 1
    if d == 1:
        e = V[S[:, 1]] - V[S[:, 0]]
        u = e / np.linalg.norm(e, axis=1)[:, None]
        t = scatter_sum(N, [(S[:, 0], u), (S[:, 1], u)])
        ln = np.linalg.norm(t, axis=1)
        ok = ln > 0
        t[ok] /= ln[ok, None]
        return t[:, :, None] * t[:, None, :]
    if d == 2 and m == 3:
        n = vertex_normals_of(V, S)
        P = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
        P[~n.any(axis=1)] = 0.0
        return P
    raise ValueError(f"tangential control: simplices of dimension {d} in R^{m} are not supported")


def curve_displacement(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N, m) step of each node of a curve to the midpoint of its neighbours (0 at curve ends).

    Along the vertex tangent, ``(V_a + V_b) / 2 - V_i`` has the component ``(l_b - l_a) / 2`` (to first
    order; l the lengths of the edges to the neighbours a, b): equidistribution by arc length. (A
    1/length-weighted mean would have no tangential part at all: like the cotangent Laplacian of a
    surface it reproduces linear functions and sees only curvature, never the spacing.)
    """
    N = V.shape[0]
    c = scatter_sum(N, [(S[:, 0], V[S[:, 1]]), (S[:, 1], V[S[:, 0]])])
    deg = np.bincount(S.ravel(), minlength=N)
    out = np.zeros_like(V)
    two = deg == 2
    out[two] = c[two] / 2 - V[two]
    return out


def mean_ratio(V: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean-ratio distortion of triangles and the gradient of its sum.

    ``q_T = (|e_1|^2 + |e_2|^2 + |e_3|^2) / (4 sqrt(3) |T|)`` is 1 for an equilateral triangle and
    grows without bound as the triangle degenerates; it is invariant under scaling, so summing it
    over the mesh prefers no triangle size over another (unlike the spring energy of an umbrella
    step, which pulls nodes to where edges are short).

    Parameters
    ----------
    V : (N, 3) vertices
    S : (K, 3) triangles

    Returns
    -------
    q : (K,) distortions
    grad : (N, 3) gradient of sum_T q_T
    """
    cr = face_normals(V, S)
    A2 = np.linalg.norm(cr, axis=1)
    n = cr / A2[:, None]
    area = A2 / 2
    L2 = sum(np.sum((V[S[:, (j + 1) % 3]] - V[S[:, j]]) ** 2, axis=1) for j in range(3))
    c = 4 * np.sqrt(3) * area
    q = L2 / c
    parts = []
    for i in range(3):
        xi, xj, xk = V[S[:, i]], V[S[:, (i + 1) % 3]], V[S[:, (i + 2) % 3]]
        d_area = 0.5 * np.cross(n, xk - xj)
        parts.append((S[:, i], 2 * (2 * xi - xj - xk) / c[:, None] - (q / area)[:, None] * d_area))
    return q, scatter_sum(V.shape[0], parts)


RELAXATION = 0.5
"""Step length of the mean-ratio descent of :func:`surface_displacement`, relative to its diagonal Newton step."""


def surface_displacement(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N, 3) descent step of the summed mean-ratio distortion (:func:`mean_ratio`), diagonally scaled.

    ``-RELAXATION * grad_i / H_i`` with ``H_i = sum_{T at i} 1 / (sqrt(3) |T|)``, the second derivative
    of ``sum_T q_T`` in X_i through the edge terms: a length, of the order of the distance that node
    i would move to make its triangles equilateral.
    """
    _, grad = mean_ratio(V, S)
    cr = face_normals(V, S)
    inv = 2 / (np.sqrt(3) * np.linalg.norm(cr, axis=1))
    H = np.bincount(S.ravel(), weights=np.repeat(inv, 3), minlength=V.shape[0])
    out = np.zeros_like(V)
    ok = H > 0
    out[ok] = -RELAXATION * grad[ok] / H[ok, None]
    return out


SUBSTEPS = 4
"""Parts in which a surface's mesh-improving step is taken: the control's target S (:func:`nodal_parameters`) and
each pass of the light repair (:data:`willmore_nlp.remesh.RELAX_SUBSTEPS`). In one piece the step is a Jacobi
iteration, unstable on anisotropic triangles: a one-piece target let the 32x16 torus's flow with
``tangential_control = "meanratio"`` (weight 1) grow a short-wave azimuthal mode 5-fold per step, from 3e-15 at
step 7 to 1e-12 at step 11; in quarter steps it stays at 1e-15 (tests/test_rest.py)."""

MAX_STEP = 0.2
"""The target S_i is shortened to at most this fraction of the shortest edge at node i (no inversion from S)."""


def shortest_edges(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N,) length of the shortest edge at each node (inf for isolated nodes)."""
    out = np.full(V.shape[0], np.inf)
    d1 = S.shape[1]
    for a in range(d1):
        for b in range(a + 1, d1):
            ln = np.linalg.norm(V[S[:, a]] - V[S[:, b]], axis=1)
            np.minimum.at(out, S[:, a], ln)
            np.minimum.at(out, S[:, b], ln)
    return out


def _capped_step(V: np.ndarray, S: np.ndarray, P: np.ndarray, fraction: float) -> np.ndarray:
    """(N, m) tangential mesh-improving step of V (projected by P), capped at MAX_STEP shortest edges, times
    fraction."""
    U = curve_displacement(V, S) if S.shape[1] == 2 else surface_displacement(V, S)
    T = np.einsum("nab,nb->na", P, U)
    cap = MAX_STEP * shortest_edges(V, S) / np.maximum(np.linalg.norm(T, axis=1), 1e-300)
    return T * (fraction * np.minimum(1.0, cap))[:, None]


FEATURE_ANGLE = 35.0
"""Largest angle (degrees) between a node's vertex normal and the normals of its triangles at which the mesh
resolves a tangent plane there (:func:`unresolved_nodes`). Resolved smooth meshes stay well below it (11 deg on
icosphere(2), 21 on icosphere(1), 18 on the 24x12 torus, 13 on a 32x16 trimesh torus, 8 on `surface_blending`); a
box's edges and corners are at 45 and 55 deg, noise spikes of a 1 %-noisy trimesh capsule up to 86."""


def unresolved_nodes(mesh: Mesh) -> np.ndarray:
    """(N,) True at the nodes of a triangle surface where some incident triangle's normal is more than
    :data:`FEATURE_ANGLE` from the (area-weighted) vertex normal: the mesh has no tangent plane there."""
    from willmore_nlp.geometry import vertex_normals

    V, S = mesh.vertices, mesh.simplices
    vn = vertex_normals(mesh)
    cr = face_normals(V, S)
    fn = cr / np.maximum(np.linalg.norm(cr, axis=1), 1e-300)[:, None]
    c = np.ones(V.shape[0])
    for a in range(3):
        np.minimum.at(c, S[:, a], np.einsum("ij,ij->i", fn, vn[S[:, a]]))
    return c < np.cos(np.radians(FEATURE_ANGLE))


def nodal_parameters(V: np.ndarray, S: np.ndarray, free: np.ndarray | None = None, fraction: float = 1.0,
                     substeps: int = 1) -> np.ndarray:
    """Per-node data ``[vec(P_i), S_i]`` of the control at Xk = V (module docstring).

    Parameters
    ----------
    V : (N, m) Xk
    S : (K, d + 1) all simplices of the mesh (neighbours and tangent spaces are taken over all of them)
    free : (N,) bool, optional
        Nodes that move; fixed nodes get P = 0 and S = 0 (their term is constant anyway).
    fraction : float
        Factor of the mesh-improving step in S (:meth:`TangentialControl.fraction`).
    substeps : int
        Surfaces: the step is taken in this many parts, each from the state the earlier ones reached
        (:data:`SUBSTEPS`); S is the tangential part, at Xk, of their sum. Curves: one piece.

    Returns
    -------
    (N, m*m + m) array, node-major; ``P_i`` row-major (it is symmetric)
    """
    V = np.asarray(V, float)
    N, m = V.shape
    P = vertex_projectors(V, S)
    keep = np.ones(N) if free is None else np.asarray(free, float)
    parts = substeps if S.shape[1] == 3 else 1
    Xs = V + keep[:, None] * _capped_step(V, S, P, fraction / parts)
    for _ in range(parts - 1):  # each part from the state the earlier ones reached, fixed nodes kept
        Xs = Xs + keep[:, None] * _capped_step(Xs, S, vertex_projectors(Xs, S), fraction / parts)
    T = np.einsum("nab,nb->na", P, Xs - V)
    if free is not None:
        fixed = ~np.asarray(free, bool)
        P[fixed] = 0.0
        T[fixed] = 0.0
    return np.hstack([P.reshape(N, m * m), T])
