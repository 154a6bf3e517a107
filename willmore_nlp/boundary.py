"""Clamped (C^1) boundary conditions: a free patch inside a fixed mesh (paper Secs. 2.2, 3.2).

A :class:`Boundary` says which vertices move (the *free* vertices, the interior of the patch)
and which variant of the paper is used (docs/theory/scheme.md, 'Clamped boundaries'):

``"conormal"`` (variant 1, prescribed co-normal)
    The boundary nodes Gamma of the patch are fixed; Y lives on all patch nodes and the inner
    equation carries the co-normal term,
    ``g = (M + tt L) Y - M X - tt Nco``, ``Nco_i = int_Gamma N^co Phi_i ds``.
    ``N^co`` is piecewise constant on boundary facets: the unit vector in the plane of the fixed
    outer simplex, perpendicular to the facet, pointing out of the patch (for a curve: the unit
    tangent from the end node into the fixed outer segment). It may instead be prescribed
    explicitly at the boundary nodes (``conormal=``), which also allows an open mesh without an
    outer ring (e.g. a curve with prescribed end points and end tangents).
``"ring"`` (variant 2, a fixed outer ring)
    One fixed layer of simplices around the patch. The inner problem lives on patch + ring, with
    Y = X on the ring's outer nodes and Y free on the patch nodes (interior and Gamma); W only
    integrates over the patch.

Terminology, for a mesh and a boolean mask ``free`` of its vertices:

* patch simplices: every simplex with a free vertex;
* Gamma (boundary nodes): the non-free vertices of patch simplices;
* ring: the simplices outside the patch with a vertex on Gamma (one layer by construction).

Constructors: :meth:`Boundary.from_indices`, :meth:`Boundary.from_predicate`,
:meth:`Boundary.from_region` (a ball), :meth:`Boundary.complement` (every vertex free except a
fixed set), :meth:`Boundary.outer_strip` (an open mesh held by its outermost strip of simplices)
and :func:`boundary_data`, which checks a selection and returns the index sets used by the step
problem, with errors that name the offending vertex or facet.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.fem.assembly import mass_stiffness
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.io import CURVE_FORMATS
from willmore_nlp.mesh.topology import boundary_facets, scatter_sum, simplex_facets, vertex_components

VARIANTS = ("conormal", "ring")
"""Boundary variants: prescribed co-normal (paper (2.6)) and fixed outer ring (paper (2.8))."""

CLAMPED_CURVE_WEIGHT = 10.0
"""The ``tangential_weight`` the clamped-curve problems give (``circle_arc``, curve files with ``clamp``). With the
paper's 1 the first free node slides onto Gamma: the 256-node ring arc (tau = h, tau_tilde = h^2 / 100) reached edge
ratio 7.4 by step 200 and stopped at step 226 (edge ratio 1.7e3; at h^2 / 10 and h^2 it ended 400 steps at edge
ratios 399 and 85 with the polygon's W 5.9 and 265 against 1.58); with 10 it ends 400 steps at 1.29, W 1.5754. The
restored arcs of n = 20 / 40 / 80 (150 steps, both variants) keep their distance to the circle to 4 digits (order
1.01 either way); measured 2026-11-30."""


class BoundaryError(MeshError):
    """A boundary selection is unusable; the message names the vertex, facet or option."""


@dataclass(frozen=True, eq=False)
class Boundary:
    """Which vertices move, and how the clamped boundary is imposed.

    Parameters
    ----------
    free : (N,) bool array
        Vertices whose positions are unknowns (the interior of the patch).
    variant : {"conormal", "ring"}
    conormal : (N, m) float array or {vertex: (m,) vector}, optional
        Prescribed outward unit co-normal at the boundary nodes Gamma ("conormal" variant only;
        rows of other vertices are ignored). Default: from the fixed outer ring.
    ring : (R,) int array, optional
        Simplices of the fixed outer ring ("ring" variant only). Default: every simplex outside
        the patch with a vertex on Gamma. An explicit ring is checked to be one layer that
        covers every boundary facet.
    """

    free: np.ndarray
    variant: str = "conormal"
    conormal: np.ndarray | Mapping[int, np.ndarray] | None = None
    ring: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise BoundaryError(f"boundary variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")
        free = np.asarray(self.free)
        if free.dtype != bool or free.ndim != 1:
            raise BoundaryError(f"boundary: free must be a 1-D boolean vertex mask, got {free.dtype} {free.shape}")
        object.__setattr__(self, "free", free.copy())
        if self.conormal is not None and self.variant != "conormal":
            raise BoundaryError("boundary: conormal= is only used by the 'conormal' variant")
        if self.ring is not None and self.variant != "ring":
            raise BoundaryError("boundary: ring= is only used by the 'ring' variant")

    def json_record(self) -> dict[str, Any]:
        """What a run directory's config.json records of the boundary: the variant, the fixed vertices (indices into
        the initial mesh), the vertex count, and whether a co-normal or ring was given (the dataclass's repr was
        recorded before, with numpy's mask cut to its first and last three entries above 1,000 vertices)."""
        return {"variant": self.variant, "fixed": np.flatnonzero(~self.free).tolist(),
                "n_vertices": int(self.free.size), "conormal": "given" if self.conormal is not None else None,
                "ring": "given" if self.ring is not None else None}

    # -- constructors ------------------------------------------------------------------
    @classmethod
    def from_indices(cls, mesh: Mesh, free: np.ndarray | list[int], variant: str = "conormal",
                     **kw: object) -> Boundary:
        """Free vertices given by index."""
        idx = np.asarray(free, dtype=np.int64).ravel()
        bad = idx[(idx < 0) | (idx >= mesh.n_vertices)]
        if bad.size:
            raise BoundaryError(f"{mesh.source}: free vertex index {bad[0]} out of range 0..{mesh.n_vertices - 1}")
        mask = np.zeros(mesh.n_vertices, bool)
        mask[idx] = True
        return cls(mask, variant, **kw)  # type: ignore[arg-type]

    @classmethod
    def from_predicate(cls, mesh: Mesh, predicate: Callable[[np.ndarray], np.ndarray],
                       variant: str = "conormal", **kw: object) -> Boundary:
        """Free vertices where ``predicate(vertices)`` ((N, m) -> (N,) bool) is true."""
        mask = np.asarray(predicate(np.asarray(mesh.vertices)), dtype=bool).reshape(-1)
        if mask.shape != (mesh.n_vertices,):
            raise BoundaryError(f"boundary predicate returned {mask.shape[0]} values for {mesh.n_vertices} vertices")
        return cls(mask, variant, **kw)  # type: ignore[arg-type]

    @classmethod
    def from_region(cls, mesh: Mesh, center: np.ndarray, radius: float, variant: str = "conormal",
                    **kw: object) -> Boundary:
        """Free vertices strictly inside the ball ``|x - center| < radius``."""
        c = np.asarray(center, float).reshape(1, -1)
        return cls.from_predicate(mesh, lambda V: np.linalg.norm(V - c, axis=1) < radius, variant, **kw)

    @classmethod
    def outer_strip(cls, mesh: Mesh, variant: str = "conormal") -> Boundary:
        """An open mesh clamped by its outermost strip: every simplex with a vertex on the mesh boundary
        is held fixed (it is the outer ring and gives the co-normal), every other vertex is free.

        For a surface patch this prescribes the boundary curve and the tangent plane along it (the
        strip's triangles); for an open curve, the end points and the end tangents (the end segments).
        """
        if mesh.is_closed:
            hint = (" (a curve file is read as closed unless a '# open' line comes before its vertices)"
                    if mesh.d == 1 and Path(mesh.source).suffix.lower() in CURVE_FORMATS else "")
            raise BoundaryError(f"{mesh.source}: the mesh is closed: there is no boundary to clamp{hint}")
        S = np.asarray(mesh.simplices)
        on_bd = np.zeros(mesh.n_vertices, bool)
        on_bd[mesh.boundary_vertices] = True
        fixed = np.zeros(mesh.n_vertices, bool)
        fixed[S[on_bd[S].any(axis=1)].ravel()] = True
        if fixed.all():  # (the general check's "empty patch: no free vertex selected" did not say why: a new user's)
            raise BoundaryError(f"{mesh.source}: no free vertex: every one of the {mesh.n_vertices} vertices lies in "
                                f"the clamped outer strip (the {'triangles' if mesh.d == 2 else 'segments'} that touch "
                                "the boundary); use a finer mesh")
        return cls(~fixed, variant)

    @classmethod
    def complement(cls, mesh: Mesh, fixed: np.ndarray | list[int], variant: str = "conormal",
                   **kw: object) -> Boundary:
        """Every vertex free except ``fixed`` (indices), e.g. an open curve clamped at its ends."""
        mask = np.ones(mesh.n_vertices, bool)
        mask[np.asarray(fixed, dtype=np.int64)] = False
        return cls(mask, variant, **kw)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class BoundaryData:
    """Index sets and fixed data of a checked boundary selection (see :func:`boundary_data`).

    Attributes
    ----------
    variant : "conormal" or "ring"
    free : (N,) bool, vertices with unknown positions
    patch : (K,) bool, patch simplices
    ring : (K,) bool, fixed outer-ring simplices (empty mask when there is none)
    gamma : (nG,) int, boundary nodes of the patch (fixed)
    patch_nodes : (N,) bool, free vertices and Gamma
    facets : (B, d) int, boundary facets of the patch
    facet_conormal : (B, m) float, unit outward co-normal on each boundary facet
    nco : (N, m) float, Nco_i = int_Gamma N^co Phi_i (zero off Gamma)
    """

    variant: str
    free: np.ndarray
    patch: np.ndarray
    ring: np.ndarray
    gamma: np.ndarray
    patch_nodes: np.ndarray
    facets: np.ndarray
    facet_conormal: np.ndarray
    nco: np.ndarray

    @property
    def simplices(self) -> np.ndarray:
        """(K',) simplex indices on which the inner problem lives: patch (+ ring for "ring")."""
        mask = self.patch | self.ring if self.variant == "ring" else self.patch
        return np.flatnonzero(mask)


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n <= 1e-300):
        raise BoundaryError(f"{what}: zero vector")
    return v / n


def check_mask_size(mesh: Mesh, boundary: Boundary) -> None:
    """BoundaryError unless ``boundary``'s free mask has one entry per vertex of ``mesh`` (a wrong length had ended
    as numpy's IndexError in the flow's input repair: a new user's check)."""
    if boundary.free.shape != (mesh.n_vertices,):
        raise BoundaryError(f"{mesh.source}: boundary mask has {boundary.free.shape[0]} entries, the mesh has "
                            f"{mesh.n_vertices} vertices")


def boundary_data(mesh: Mesh, boundary: Boundary) -> BoundaryData:
    """Check ``boundary`` on ``mesh`` and compute the patch, Gamma, ring and co-normal data.

    Raises
    ------
    BoundaryError
        Empty patch; a free vertex on the mesh boundary (its boundary condition would be missing);
        a patch component without fixed boundary nodes; a fixed vertex surrounded by the patch or
        a patch boundary that is not a set of simple closed curves; a boundary facet without an
        outer simplex (no ring, and no explicit co-normal); an explicit ring that is not one layer
        or does not cover every boundary facet; co-normals that are zero or tangent to Gamma.
    """
    src = mesh.source
    N, d = mesh.n_vertices, mesh.d
    S = np.asarray(mesh.simplices)
    free = boundary.free
    check_mask_size(mesh, boundary)
    if not free.any():
        raise BoundaryError(f"{src}: empty patch: no free vertex selected")
    if free.all():
        raise BoundaryError(f"{src}: every vertex is free: a clamped boundary needs fixed vertices "
                            "(use boundary=None for a closed mesh)")
    on_bd = free[mesh.boundary_vertices] if not mesh.is_closed else np.zeros(0, bool)
    if on_bd.any():
        v = int(mesh.boundary_vertices[np.flatnonzero(on_bd)[0]])
        raise BoundaryError(f"{src}: free vertex {v} lies on the mesh boundary, where no boundary condition "
                            "holds; fix it (it must be a boundary node of the patch)")
    patch = free[S].any(axis=1)
    Sp = S[patch]
    pnodes = np.zeros(N, bool)
    pnodes[Sp.ravel()] = True
    gamma = np.flatnonzero(pnodes & ~free)
    facets = boundary_facets(Sp)
    # every patch component must touch Gamma
    ncomp, lab = vertex_components(Sp, N)
    touched = np.zeros(ncomp, bool)
    touched[lab[gamma]] = True
    lonely = np.flatnonzero(~touched[lab[np.flatnonzero(free)]])
    if lonely.size:
        v = int(np.flatnonzero(free)[lonely[0]])
        raise BoundaryError(f"{src}: the patch component of free vertex {v} has no fixed boundary node "
                            "(it is a closed curve/surface: flow it without boundary)")
    # Gamma = the patch's boundary, a set of simple closed curves (surfaces) or end points (curves)
    cnt = np.bincount(facets.ravel(), minlength=N)
    inside = gamma[cnt[gamma] == 0]
    if inside.size:
        raise BoundaryError(f"{src}: fixed vertex {int(inside[0])} is surrounded by free vertices; a clamped "
                            "boundary must be the boundary of the patch (free it or fix a whole region)")
    want = 1 if d == 1 else 2
    pinched = gamma[cnt[gamma] != want]
    if pinched.size:
        v = int(pinched[0])
        raise BoundaryError(f"{src}: the patch boundary is not closed and simple at vertex {v} "
                            f"({cnt[v]} boundary facets meet there, expected {want})")
    ring = _ring(mesh, patch, gamma, facets, boundary)
    fco = _facet_conormal(mesh, patch, facets, boundary)
    explicit = boundary.conormal is not None
    nco = _integrate_conormal(mesh, facets, fco) if explicit else ring_conormal(mesh, ring, gamma)
    return BoundaryData(boundary.variant, free.copy(), patch, ring, gamma, pnodes, facets, fco, nco)


def _facet_keys(F: np.ndarray) -> np.ndarray:
    return np.sort(F, axis=1)


def _outer_simplex(mesh: Mesh, patch: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """(B,) index of the non-patch simplex across each patch boundary facet, -1 if none."""
    S = np.asarray(mesh.simplices)
    F, owner = simplex_facets(S)
    outside = ~patch[owner]
    keys = {tuple(k): int(o) for k, o in zip(_facet_keys(F[outside]), owner[outside], strict=True)}
    return np.array([keys.get(tuple(k), -1) for k in _facet_keys(facets)], dtype=np.int64)


def _ring(mesh: Mesh, patch: np.ndarray, gamma: np.ndarray, facets: np.ndarray, boundary: Boundary) -> np.ndarray:
    S = np.asarray(mesh.simplices)
    K = S.shape[0]
    on_gamma = np.zeros(mesh.n_vertices, bool)
    on_gamma[gamma] = True
    touching = ~patch & on_gamma[S].any(axis=1)
    outer = _outer_simplex(mesh, patch, facets)
    need_ring = boundary.variant == "ring" or boundary.conormal is None
    if need_ring and np.any(outer < 0):
        f = facets[np.flatnonzero(outer < 0)[0]]
        what = "boundary node" if mesh.d == 1 else "boundary edge"
        raise BoundaryError(f"{mesh.source}: no fixed outer simplex at the patch's {what} {f.tolist()}: the mesh "
                            "ends there; a clamped boundary needs one fixed layer of simplices around the patch"
                            + (" (or an explicit conormal=)" if boundary.variant == "conormal" else ""))
    if boundary.ring is None:
        return touching
    idx = np.asarray(boundary.ring, dtype=np.int64).ravel()
    bad = idx[(idx < 0) | (idx >= K)]
    if bad.size:
        raise BoundaryError(f"{mesh.source}: ring simplex index {bad[0]} out of range 0..{K - 1}")
    ring = np.zeros(K, bool)
    ring[idx] = True
    wrong = np.flatnonzero(ring & ~touching)
    if wrong.size:
        s = int(wrong[0])
        why = "is in the patch" if patch[s] else "does not touch the patch boundary"
        raise BoundaryError(f"{mesh.source}: the ring is not a single layer around the patch: simplex {s} {why}")
    missing = outer[~ring[outer]]
    if missing.size:
        raise BoundaryError(f"{mesh.source}: the ring does not cover the patch boundary: outer simplex "
                            f"{int(missing[0])} is missing")
    return ring


def _facet_conormal(mesh: Mesh, patch: np.ndarray, facets: np.ndarray, boundary: Boundary) -> np.ndarray:
    """(B, m) unit outward co-normal on each patch boundary facet."""
    V = np.asarray(mesh.vertices)
    d, m = mesh.d, mesh.m
    if boundary.conormal is not None:
        n_node = _explicit_conormal(mesh, boundary.conormal, np.unique(facets))
        if d == 1:
            return n_node[facets[:, 0]]
        t = _unit(V[facets[:, 1]] - V[facets[:, 0]], "boundary edge")
        v = n_node[facets[:, 0]] + n_node[facets[:, 1]]
        v = v - np.sum(v * t, axis=1, keepdims=True) * t
        if np.any(np.linalg.norm(v, axis=1) < 1e-8):
            i = int(np.flatnonzero(np.linalg.norm(v, axis=1) < 1e-8)[0])
            raise BoundaryError(f"{mesh.source}: prescribed co-normal is tangent to the boundary edge "
                                f"{facets[i].tolist()}")
        return _unit(v, "co-normal")
    # from the fixed outer simplex across each facet
    outer = _outer_simplex(mesh, patch, facets)
    S = np.asarray(mesh.simplices)
    So = S[outer]
    if d == 1:
        a = facets[:, 0]
        other = np.where(So[:, 0] == a, So[:, 1], So[:, 0])
        return _unit(V[other] - V[a], "outer segment")
    a, b = facets[:, 0], facets[:, 1]
    c = So[(So != a[:, None]) & (So != b[:, None])]
    t = _unit(V[b] - V[a], "boundary edge")
    w = V[c] - V[a]
    w = w - np.sum(w * t, axis=1, keepdims=True) * t
    return _unit(w, "outer triangle").reshape(-1, m)


def _few(items: list[int], n: int = 6) -> str:
    """The first ``n`` of ``items`` written out, with how many more."""
    head = ", ".join(map(str, items[:n]))
    return head + (f", ... ({len(items)} in all)" if len(items) > n else "")


def _explicit_conormal(mesh: Mesh, conormal: np.ndarray | Mapping[int, np.ndarray], nodes: np.ndarray) -> np.ndarray:
    N, m = mesh.n_vertices, mesh.m
    if isinstance(conormal, Mapping):
        arr = np.full((N, m), np.nan)
        on_gamma = set(np.asarray(nodes).tolist())
        for k, v in conormal.items():
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < N:
                raise BoundaryError(f"{mesh.source}: conormal given at vertex {k!r}: a vertex index in [0, {N})")
            if int(k) not in on_gamma:
                raise BoundaryError(f"{mesh.source}: conormal given at vertex {k}, which is not a node of the "
                                    f"clamped boundary (its nodes: {_few(sorted(on_gamma))})")
            vv = np.asarray(v, float).ravel()
            if vv.shape != (m,):
                raise BoundaryError(f"conormal at vertex {k}: expected {m} components, got {vv.size}")
            arr[int(k)] = vv
    else:
        arr = np.asarray(conormal, float)
        if arr.shape != (N, m):
            raise BoundaryError(f"conormal must have shape ({N}, {m}), got {arr.shape}")
    vals = arr[nodes]
    bad = ~np.all(np.isfinite(vals), axis=1) | (np.linalg.norm(np.nan_to_num(vals), axis=1) < 1e-12)
    if bad.any():
        raise BoundaryError(f"{mesh.source}: no usable prescribed co-normal at boundary node {int(nodes[bad][0])}")
    out = np.zeros((N, m))
    out[nodes] = _unit(vals, "co-normal")
    return out


def ring_conormal(mesh: Mesh, ring: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """(N, m) co-normal term of a fixed outer ring: ``Nco = -(L_ring X)`` on Gamma, zero elsewhere.

    ``L_ring`` is the stiffness matrix of the ring simplices. On a flat ring this is exactly
    ``int_Gamma N^co Phi_i`` with the per-facet co-normal of docs/theory/scheme.md (divergence theorem on each
    simplex); on a curved ring it adds the ring's own O(h^2) curvature terms, which makes the
    boundary nodes' equation consistent with the ring variant. Measured: with the per-facet
    formula a restored sphere cap (12 rings, tau = h, tau_tilde = h^2/100) collapses triangles at
    Gamma within 6 steps; with this one the minimal angle stays above 30 degrees.
    """
    _, L = mass_stiffness(np.asarray(mesh.vertices), np.asarray(mesh.simplices)[ring], mesh.n_vertices)
    out = np.zeros((mesh.n_vertices, mesh.m))
    out[gamma] = -(L @ np.asarray(mesh.vertices))[gamma]
    return out


def _integrate_conormal(mesh: Mesh, facets: np.ndarray, fco: np.ndarray) -> np.ndarray:
    """Nco_i = int_Gamma N^co Phi_i: point values for curves, |e|/2 per edge end for surfaces."""
    N = mesh.n_vertices
    if mesh.d == 1:
        return scatter_sum(N, [(facets[:, 0], fco)])
    V = np.asarray(mesh.vertices)
    ell = np.linalg.norm(V[facets[:, 1]] - V[facets[:, 0]], axis=1)
    return scatter_sum(N, [(facets[:, j], 0.5 * ell[:, None] * fco) for j in range(2)])
