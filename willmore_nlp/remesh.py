"""Mesh-quality repair of triangulated surfaces between time steps (geometry only; the policy is in flow.py).

Three operations, from the gentlest to the strongest:

* :func:`delaunay_flips` — edge flips until every flippable interior edge satisfies the Delaunay
  angle criterion alpha + beta <= pi (alpha, beta the angles opposite the edge, measured on the
  surface). Positions do not move; only the connectivity changes.
* :func:`tangential_smooth` — each free vertex moves toward the centroid of its neighbours, within
  its tangent plane, and is then projected back onto the surface before the move (closest point,
  :func:`gpytoolbox.squared_distance`), so the geometry is kept up to the projection tolerance.
* :func:`isotropic_remesh` — split, collapse, flip and smooth toward a target edge length
  (Botsch & Kobbelt, through :func:`gpytoolbox.remesh_botsch`, with projection onto the input), the new
  vertices then placed on the smooth surface of quadric fits of the old 1-rings (:func:`smooth_lift`).
* :func:`tangential_relax` — the light repair after every step: mean-ratio tangential moves placed
  on a local quadric fit of each 1-ring (:func:`quadric_offsets`), so that the shape is kept to
  third order and repeated use does not shrink the surface (a polyhedral projection would).

Fixed vertices (the mesh boundary and the fixed part of a clamped problem,
:class:`~willmore_nlp.boundary.Boundary`) are never moved, and their positions are carried over
bit for bit. For a clamped problem only the *patch* (the triangles with a free vertex) is
changed: the fixed triangles (ring and beyond) keep their vertices, so Gamma and the ring are
the same curves and triangles after every operation, and the :class:`Boundary` is carried over
to the new connectivity (:func:`carry_boundary`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.topology import boundary_facets, euler_characteristic, scatter_sum, unique_edges, unique_rows
from willmore_nlp.mesh.validate import simplex_volumes, vertex_normals_of
from willmore_nlp.tangential import SUBSTEPS


class RemeshError(MeshError):
    """A remeshing operation would change the topology or produce an invalid mesh."""


def _cross(P: list[list[float]], i: int, j: int, k: int) -> tuple[float, float, float]:
    """(P_j - P_i) x (P_k - P_i) for points held as Python lists (the flip loop's scalar arithmetic)."""
    (x, y, z), (a0, a1, a2), (b0, b1, b2) = P[i], P[j], P[k]
    u0, u1, u2, v0, v1, v2 = a0 - x, a1 - y, a2 - z, b0 - x, b1 - y, b2 - z
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0


def _angle(P: list[list[float]], i: int, j: int, k: int) -> float:
    """Angle at P_i of the triangle (P_i, P_j, P_k), radians."""
    (x, y, z), (a0, a1, a2), (b0, b1, b2) = P[i], P[j], P[k]
    dot = (a0 - x) * (b0 - x) + (a1 - y) * (b1 - y) + (a2 - z) * (b2 - z)
    return math.atan2(math.hypot(*_cross(P, i, j, k)), dot)


def _dot(u: tuple[float, ...], v: tuple[float, ...]) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def opposite_angle_sums(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges and the sum of the two angles opposite each (the Delaunay test: <= pi).

    Returns
    -------
    edges : (E, 2) int, interior edges (sorted vertex pairs)
    sums : (E,) alpha + beta in radians
    """
    V = np.asarray(V, float)
    F = np.asarray(F)
    he = np.concatenate([F[:, [1, 2]], F[:, [2, 0]], F[:, [0, 1]]])  # half-edge opposite corner j
    corner = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    p, a, b = V[corner], V[he[:, 0]], V[he[:, 1]]
    u, v = a - p, b - p
    ang = np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ij,ij->i", u, v))
    key = np.sort(he, axis=1)
    uk, inv, cnt = unique_rows(key, return_inverse=True, return_counts=True)
    sums = np.bincount(inv.ravel(), weights=ang, minlength=uk.shape[0])
    interior = cnt == 2
    return uk[interior], sums[interior]


def _patch_ok(free: np.ndarray, *tris: tuple[int, int, int]) -> bool:
    """Every triangle has a free vertex (a flip keeps the patch of a clamped problem)."""
    return all(free[list(t)].any() for t in tris)


def delaunay_flips(V: np.ndarray, F: np.ndarray, free: np.ndarray | None = None, *, tol: float = 1e-10,
                   max_dihedral: float = 60.0, max_flips: int | None = None) -> tuple[np.ndarray, int]:
    """Flip edges until every flippable interior edge is Delaunay (alpha + beta <= pi + tol).

    An edge is flippable when it is interior, its flipped edge does not exist yet, the two
    triangles meet at a dihedral angle below ``max_dihedral`` degrees (a flip across a fold would
    change the shape), both new triangles keep the orientation of the pair, and, when ``free`` is
    given, the four triangles involved each have a free vertex (so the patch of a clamped problem,
    its boundary Gamma and the fixed ring are unchanged). Each flip strictly lowers the sum of
    circumcircle-violating angles of the pair, so the loop ends; ``max_flips`` (default 20 per
    edge) is a safety net.

    Parameters
    ----------
    V : (N, 3) float, positions (not changed)
    F : (K, 3) int, consistently oriented triangles
    free : (N,) bool, optional, vertices that may be moved (default: all)

    Returns
    -------
    F : (K, 3) int, the flipped triangles (same count, same orientation)
    n : number of flips
    """
    V = np.asarray(V, float)
    F = np.array(F, dtype=np.int64, copy=True)
    # an edge none of whose two triangles has changed keeps its angle sum: test those all at once
    edges, sums = opposite_angle_sums(V, F)
    if np.all(sums <= np.pi + tol):  # every interior edge Delaunay: nothing to flip (common after a step)
        return F, 0
    free = np.ones(V.shape[0], bool) if free is None else np.asarray(free, bool)
    cos_max = np.cos(np.radians(max_dihedral))
    P = V.tolist()
    # directed half-edge (a, b) -> face containing a -> b
    owner: dict[tuple[int, int], int] = {}
    for f, (i, j, k) in enumerate(F.tolist()):
        owner[(i, j)], owner[(j, k)], owner[(k, i)] = f, f, f
    stack = list(map(tuple, unique_edges(F).tolist()))  # sorted
    limit = 20 * len(stack) if max_flips is None else int(max_flips)
    delaunay = set(map(tuple, edges[sums <= np.pi + tol].tolist()))
    n = 0
    while stack and n < limit:
        a, b = stack.pop()
        f1, f2 = owner.get((a, b)), owner.get((b, a))
        if f1 is None or f2 is None or (a, b) in delaunay:
            continue
        t1, t2 = F[f1].tolist(), F[f2].tolist()
        c = t1[(t1.index(a) + 2) % 3]  # t1 = (a, b, c) up to rotation
        d = t2[(t2.index(b) + 2) % 3]  # t2 = (b, a, d)
        if c == d or (c, d) in owner or (d, c) in owner:
            continue
        if _angle(P, c, a, b) + _angle(P, d, a, b) <= np.pi + tol:
            continue
        n1, n2 = _cross(P, *t1), _cross(P, *t2)
        if _dot(n1, n2) < cos_max * math.hypot(*n1) * math.hypot(*n2):
            continue
        new1, new2 = (c, a, d), (d, b, c)
        m = (n1[0] + n2[0], n1[1] + n2[1], n1[2] + n2[2])
        if _dot(_cross(P, *new1), m) <= 0 or _dot(_cross(P, *new2), m) <= 0:
            continue
        if not _patch_ok(free, tuple(t1), tuple(t2), new1, new2):
            continue
        for e in ((a, b), (b, c), (c, a)):
            owner.pop(e, None)
        for e in ((b, a), (a, d), (d, b)):
            owner.pop(e, None)
        F[f1], F[f2] = new1, new2
        for f, t in ((f1, new1), (f2, new2)):
            i, j, k = t
            owner[(i, j)], owner[(j, k)], owner[(k, i)] = f, f, f
        n += 1
        quad = [(min(a, c), max(a, c)), (min(c, b), max(c, b)), (min(b, d), max(b, d)), (min(d, a), max(d, a))]
        delaunay.difference_update(quad)  # their triangles changed
        stack.extend(quad)
    return F, n


def closest_on_mesh(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of ``P`` ((n, 3)) on the triangle mesh (V, F) (libigl's AABB tree via gpytoolbox).

    Returns
    -------
    face : (n,) int, the triangle of each closest point
    bary : (n, 3) float, its barycentric coordinates in that triangle
    """
    import gpytoolbox

    _, idx, bary = gpytoolbox.squared_distance(np.asarray(P, float), np.asarray(V, float),
                                               np.asarray(F, dtype=np.int32), use_cpp=True)
    return idx.astype(np.int64), np.asarray(bary, float)


def project_to_surface(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, 3) closest points of ``P`` on the triangle mesh (V, F) (:func:`closest_on_mesh`)."""
    face, bary = closest_on_mesh(P, V, F)
    tri = np.asarray(V, float)[np.asarray(F)[face]]  # n, 3, 3
    return np.einsum("ij,ijk->ik", bary, tri)


def _movable(V: np.ndarray, F: np.ndarray, free: np.ndarray | None) -> np.ndarray:
    """(N,) bool: the vertices a repair may move, i.e. the free ones (all without ``free``) off the mesh boundary."""
    move = np.ones(V.shape[0], bool) if free is None else np.asarray(free, bool).copy()
    move[boundary_facets(np.asarray(F)).ravel()] = False
    return move


def tangential_smooth(V: np.ndarray, F: np.ndarray, free: np.ndarray | None = None, *, iterations: int = 3,
                      step: float = 0.5) -> np.ndarray:
    """Tangential Laplacian smoothing projected back onto the input surface.

    Each iteration moves every free vertex by ``step`` times the tangential part (w.r.t. its
    area-weighted vertex normal) of the vector to the centroid of its neighbours, then projects
    the moved vertices onto the *input* triangle mesh, so the shape is kept up to the projection
    (closest point) while the vertices spread evenly. Fixed vertices and the mesh boundary do not
    move (their rows are returned bit-identical).

    Returns
    -------
    (N, 3) float, new positions
    """
    V0 = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    N = V0.shape[0]
    move = _movable(V0, F, free)
    e = unique_edges(F)
    deg = np.bincount(e.ravel(), minlength=N).astype(float)
    X = V0.copy()
    idx = np.flatnonzero(move)
    for _ in range(iterations):
        s = scatter_sum(N, [(e[:, 0], X[e[:, 1]]), (e[:, 1], X[e[:, 0]])])
        dvec = s / np.maximum(deg, 1)[:, None] - X
        n = vertex_normals_of(X, F)
        dvec -= np.einsum("ij,ij->i", dvec, n)[:, None] * n
        P = X[idx] + step * dvec[idx]
        X[idx] = project_to_surface(P, V0, F)
    return X


def equilateral_edge(V: np.ndarray, F: np.ndarray, free: np.ndarray | None = None) -> float:
    """Edge length of equilateral triangles with the area and count of the patch triangles (a free vertex).

    The default target of :func:`isotropic_remesh` in the flow: remeshing toward it keeps the number of
    triangles, hence the resolution, where the mean edge of an anisotropic grid (a torus of revolution)
    would coarsen the mesh.
    """
    F = np.asarray(F)
    if free is not None:
        F = F[np.asarray(free, bool)[F].any(axis=1)]
    area = simplex_volumes(np.asarray(V, float), F).sum()
    return float(np.sqrt(4.0 * area / (np.sqrt(3.0) * F.shape[0])))


@dataclass
class Remeshed:
    """Result of :func:`isotropic_remesh`.

    Attributes
    ----------
    vertices : (N', 3) float
    simplices : (K', 3) int
    free : (N',) bool, free vertices of the new mesh
    vertex_map : (N,) int, new index of each old fixed vertex (-1 for old free vertices)
    face_map : (K,) int, new index of each old fixed triangle (-1 for old patch triangles)
    """

    vertices: np.ndarray
    simplices: np.ndarray
    free: np.ndarray
    vertex_map: np.ndarray
    face_map: np.ndarray


def isotropic_remesh(V: np.ndarray, F: np.ndarray, target: float, free: np.ndarray | None = None, *,
                     iterations: int = 10, smooth: bool = True) -> Remeshed:
    """Isotropic remeshing of the free part toward edge length ``target`` (gpytoolbox.remesh_botsch).

    Only the patch (triangles with a free vertex) is remeshed, with the new vertices projected
    onto it; the fixed vertices and triangles are kept, fixed vertices first in their old order,
    then the new free vertices. The Euler characteristic and manifoldness are checked.

    ``smooth`` (default): the new free vertices off the mesh boundary are then placed on the smooth surface
    of quadric fits of the old 1-rings (:func:`smooth_lift`, O(h^3) from a smooth surface that the old mesh
    samples) instead of on the old flat triangles, which lie O(h^2) inside it (on the genus-2 flow of
    docs/guide/mesh_quality.md that lifted the Willmore energy by up to 19 % at a remeshing).
    ``smooth=False`` keeps them on the old polyhedron (the starts of :func:`willmore_nlp.mesh.shapes.lawson_genus2`,
    those of the cached studies).

    Raises
    ------
    RemeshError
        When the result has another Euler characteristic or is not a valid mesh.
    """
    import gpytoolbox

    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    N = V.shape[0]
    free = np.ones(N, bool) if free is None else np.asarray(free, bool)
    patch = free[F].any(axis=1)
    if not patch.any():  # (a local region of fixed vertices only: gpytoolbox asserts on an empty face set)
        raise RemeshError("no triangle with a vertex that may move")
    used = np.unique(F[patch])
    local = np.full(N, -1, dtype=np.int64)
    local[used] = np.arange(used.size)
    Fp = local[F[patch]]
    feat_old = used[~free[used]]  # fixed vertices of the patch (Gamma), in old order
    U, G = gpytoolbox.remesh_botsch(V[used].copy(), Fp.astype(np.int32), iterations, float(target), True,
                                    feature=local[feat_old].astype(np.int32))
    U = np.asarray(U, float)
    G = np.asarray(G, dtype=np.int64)
    nf = feat_old.size
    fixed_old = np.flatnonzero(~free)
    vmap = np.full(N, -1, dtype=np.int64)
    vmap[fixed_old] = np.arange(fixed_old.size)
    if nf and not np.array_equal(U[:nf], V[feat_old]):
        raise RemeshError("remeshing moved a fixed vertex")
    new_of_local = np.concatenate([vmap[feat_old], fixed_old.size + np.arange(U.shape[0] - nf)])
    if smooth:
        lift = np.ones(U.shape[0], bool)
        lift[:nf] = False
        lift[boundary_facets(G).ravel()] = False  # the boundary curve of an open patch stays where it is
        U[lift] = smooth_lift(U[lift], V, F)
    Vn = np.vstack([V[fixed_old], U[nf:]])
    fmap = np.full(F.shape[0], -1, dtype=np.int64)
    fmap[~patch] = np.arange(int((~patch).sum()))
    Fn = np.vstack([vmap[F[~patch]], new_of_local[G]])
    freen = np.concatenate([np.zeros(fixed_old.size, bool), np.ones(U.shape[0] - nf, bool)])
    if euler_characteristic(Fn) != euler_characteristic(F):
        raise RemeshError(f"remeshing changed the Euler characteristic {euler_characteristic(F)} -> "
                          f"{euler_characteristic(Fn)}")
    try:
        Mesh(Vn, Fn)
    except MeshError as exc:
        raise RemeshError(f"remeshing produced an invalid mesh: {exc}") from exc
    return Remeshed(Vn, Fn, freen, vmap, fmap)


def carry_boundary(boundary: object, r: Remeshed) -> object:
    """The :class:`~willmore_nlp.boundary.Boundary` of the remeshed mesh (free mask, co-normals, ring)."""
    from willmore_nlp.boundary import Boundary

    assert isinstance(boundary, Boundary)
    conormal = boundary.conormal
    if conormal is not None:
        old = np.flatnonzero(r.vertex_map >= 0)
        if isinstance(conormal, Mapping):
            conormal = {int(r.vertex_map[k]): v for k, v in conormal.items()}
        else:
            arr = np.zeros((r.vertices.shape[0], r.vertices.shape[1]))
            arr[r.vertex_map[old]] = np.asarray(conormal, float)[old]
            conormal = arr
    ring = None if boundary.ring is None else r.face_map[np.asarray(boundary.ring, dtype=np.int64)]
    free = r.free.copy()  # the new vertices, and the kept ones that were free (a remeshing of a part of the patch)
    kept = np.flatnonzero(r.vertex_map >= 0)
    free[r.vertex_map[kept]] = np.asarray(boundary.free, bool)[kept]
    return Boundary(free, boundary.variant, conormal, ring)


def one_rings(F: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Padded vertex neighbourhoods of a triangle mesh.

    Returns
    -------
    nbr : (N, kmax) int, the neighbours of each vertex, padded with the vertex itself
    mask : (N, kmax) bool, True for real neighbours
    """
    F = np.asarray(F, dtype=np.int64)
    e = unique_edges(F)
    e = np.vstack([e, e[:, ::-1]])
    e = e[np.lexsort((e[:, 1], e[:, 0]))]
    deg = np.bincount(e[:, 0], minlength=N)
    kmax = int(deg.max()) if N else 0
    start = np.concatenate([[0], np.cumsum(deg)[:-1]])
    slot = np.arange(e.shape[0]) - start[e[:, 0]]
    nbr = np.repeat(np.arange(N)[:, None], kmax, axis=1)
    nbr[e[:, 0], slot] = e[:, 1]
    mask = np.zeros((N, kmax), bool)
    mask[e[:, 0], slot] = True
    return nbr, mask


def quadric_fits(V: np.ndarray, F: np.ndarray, idx: np.ndarray,
                 rings: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Local quadric fits of the 1-rings of the vertices ``idx`` (the smooth surface of :func:`quadric_offsets`
    and :func:`smooth_lift`).

    For each vertex i the surface near i is the graph ``z = c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2`` over its
    tangent plane (area-weighted vertex normal n_i, through V_i, tangent basis t1_i, t2_i), fitted by least
    squares to the 1-ring (columns scaled by the ring's mean radius; a 1e-8 ridge makes rings of fewer than
    five neighbours solvable, taking the fit of least scaled norm). On a smooth surface the fit deviates
    from it by O(h^3) within O(h) of V_i.

    Parameters
    ----------
    V : (N, 3) positions; F : (K, 3) triangles; idx : (n,) vertices
    rings : :func:`one_rings` of F, optional (computed when not given)

    Returns
    -------
    frames : (n, 3, 3) rows t1, t2, n of each vertex's frame
    coefficients : (n, 5) c1 ... c5
    """
    n = vertex_normals_of(V, F)
    nbr, mask = one_rings(F, V.shape[0]) if rings is None else rings
    nbr, mask = nbr[idx], mask[idx]
    ni = n[idx]
    a = np.where(np.abs(ni[:, 0:1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(ni, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(ni, t1)
    R = V[nbr] - V[idx][:, None, :]  # n, k, 3
    x, y, z = (np.einsum("nkc,nc->nk", R, t) for t in (t1, t2, ni))
    A = np.stack([x, y, x * x, x * y, y * y], axis=2) * mask[..., None]  # n, k, 5
    s2 = np.einsum("nk,nk->n", x * x + y * y, mask) / np.maximum(mask.sum(axis=1), 1)  # mean squared radius
    scale = np.stack([np.sqrt(s2), np.sqrt(s2), s2, s2, s2], axis=1)  # column scaling of A
    As = A / scale[:, None, :]
    G = np.einsum("nki,nkj->nij", As, As) + 1e-8 * np.eye(5)[None]
    c = np.linalg.solve(G, np.einsum("nki,nk->ni", As, z * mask)[..., None])[..., 0] / scale
    return np.stack([t1, t2, ni], axis=1), c


def _on_quadric(frames: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(n, 3) the tangential part of the offsets ``d`` ((n, 3), from each fit's vertex) plus the fit's height there."""
    dx, dy = np.einsum("nc,nc->n", d, frames[:, 0]), np.einsum("nc,nc->n", d, frames[:, 1])
    z = c[:, 0] * dx + c[:, 1] * dy + c[:, 2] * dx * dx + c[:, 3] * dx * dy + c[:, 4] * dy * dy
    return dx[:, None] * frames[:, 0] + dy[:, None] * frames[:, 1] + z[:, None] * frames[:, 2]


def quadric_offsets(V: np.ndarray, F: np.ndarray, D: np.ndarray, idx: np.ndarray,
                    rings: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Normal offsets that put tangential moves of vertices onto a local quadric fit of their 1-ring.

    For each vertex i in ``idx`` the move D_i (tangent) gets the offset ``z(D_i) n_i`` of the fit of
    :func:`quadric_fits`. The new point lies on the fitted smooth surface, which deviates from the true one
    by O(h^3) on a smooth surface, whereas a projection onto the polyhedron would lie O(|D| h kappa) inside
    it (a systematic shrinkage when repeated after every step).

    Parameters
    ----------
    V : (N, 3) positions; F : (K, 3) triangles; D : (N, 3) tangential moves; idx : (n,) vertices to place
    rings : :func:`one_rings` of F, optional

    Returns
    -------
    (n, 3) the moves D[idx] plus their normal offsets
    """
    frames, c = quadric_fits(V, F, idx, rings)
    return _on_quadric(frames, c, D[idx])


def smooth_lift(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Points near the triangle mesh (V, F) placed on a smooth surface through its vertices.

    Each point goes to its closest point on the polyhedron (triangle T, barycentric weights b_j), then each
    vertex j of T places it on the quadric fit of its 1-ring (:func:`quadric_fits`: the closest point's
    tangential offset from V_j plus the fit's height there), and the three placements are blended with the
    weights b_j. Each placement lies on its fit, O(h^3) from a smooth surface that the mesh samples, and the
    placements differ from each other by O(h^3) along the surface (their directions n_j differ by O(h), their
    heights above T are O(h^2)), so the blend is O(h^3) from the surface where the closest point on the
    polyhedron is O(h^2) inside it (tested: orders over refinements on the sphere and a torus). The blend is
    continuous across edges and vertices (weights 0 and 1 there), and a point at a vertex stays at it.

    Parameters
    ----------
    P : (n, 3) points; V : (N, 3) positions; F : (K, 3) triangles

    Returns
    -------
    (n, 3) the lifted points
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    face, bary = closest_on_mesh(P, V, F)
    corners = F[face]  # n, 3
    used, inv = np.unique(corners, return_inverse=True)
    frames, c = quadric_fits(V, F, used)
    Q = np.einsum("ij,ijk->ik", bary, V[corners])  # the closest points
    fit = inv.reshape(corners.shape)  # n, 3: the fit of each corner
    lift = np.zeros_like(Q)
    for j in range(3):
        k = fit[:, j]
        lift += bary[:, j:j + 1] * (V[corners[:, j]] + _on_quadric(frames[k], c[k], Q - V[corners[:, j]]))
    return lift


RELAX_SUBSTEPS = SUBSTEPS
"""Each pass of :func:`tangential_relax` is taken as this many sub-steps, each 1/RELAX_SUBSTEPS of the mean-ratio
step (:func:`willmore_nlp.tangential.surface_displacement`) and of the cap. The step moves every vertex at once by
a diagonally scaled descent step (a Jacobi iteration), which in one piece is unstable on anisotropic triangles: on
the 32x16 torus six steps into its flow (min angle 20 deg), a short-wave azimuthal mode of the inner equator
(wavenumbers 12-14 of 32) grew by a factor 25 per two passes from round-off (1e-12) until the move cap stopped it
at 2e-3 r, which broke the torus's rotational symmetry within ten steps of its flow. At a quarter step the
symmetric state stays symmetric to round-off (tested); four quarter steps move the mesh as far as one step. The
in-step control's target is taken in the same parts (:data:`willmore_nlp.tangential.SUBSTEPS`)."""


def tangential_relax(V: np.ndarray, F: np.ndarray, free: np.ndarray | None = None, *,
                     iterations: int = 2, cap: np.ndarray | None = None) -> np.ndarray:
    """Mesh-improving tangential moves placed on the smooth surface (the light repair after every step).

    Each iteration moves every free interior vertex by the tangential part of a mean-ratio descent
    step (:func:`willmore_nlp.tangential.nodal_parameters`: scale invariant, it drives each triangle
    toward equilateral, capped at a fifth of the shortest edge at the vertex; taken in ``RELAX_SUBSTEPS``
    parts, where the simultaneous update is stable) and places it on the
    local quadric fit of its 1-ring (:func:`quadric_offsets`), so that the shape is kept to O(h^3)
    per move and the surface neither shrinks nor grows systematically. Fixed vertices and the mesh
    boundary keep their rows bit for bit. ``cap`` (N,), optional: the largest move of each vertex per pass.

    Returns
    -------
    (N, 3) float, new positions
    """
    from willmore_nlp.tangential import nodal_parameters

    X = np.array(V, float)
    F = np.asarray(F, dtype=np.int64)
    move = _movable(X, F, free)
    idx = np.flatnonzero(move)
    sub = None if cap is None else np.asarray(cap, float) / RELAX_SUBSTEPS
    rings = one_rings(F, X.shape[0])
    for _ in range(iterations * RELAX_SUBSTEPS):
        S = nodal_parameters(X, F, fraction=1.0 / RELAX_SUBSTEPS)[:, 9:]
        if sub is not None:
            ln = np.linalg.norm(S, axis=1)
            S *= (np.minimum(ln, sub) / np.maximum(ln, 1e-300))[:, None]
        X[idx] = X[idx] + quadric_offsets(X, F, S, idx, rings)
    return X
