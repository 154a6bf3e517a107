"""Geometric quantities of meshes, computed independently of the time-stepping scheme."""

from __future__ import annotations

import numpy as np

from willmore_nlp.fem.assembly import element_geometry, lumped_mass, stiffness_action
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.topology import edge_triangles, scatter_sum
from willmore_nlp.mesh.validate import face_normals, simplex_volumes, vertex_normals_of


def mean_curvature_vector(mesh: Mesh) -> np.ndarray:
    """(N, m) discrete mean-curvature vector h n = -M_lumped^{-1} L X (h = sum of principal curvatures).

    On meshes with boundary the rows of boundary vertices contain the boundary term and
    are set to NaN.
    """
    LV, mass = stiffness_action(mesh.vertices, mesh.simplices)
    H = -LV / mass[:, None]
    if not mesh.is_closed:
        H[mesh.boundary_vertices] = np.nan
    return H


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """(N, m) unit vertex normals (zero rows where no normal is defined, e.g. curves in R^3)."""
    V, S = mesh.vertices, mesh.simplices
    if mesh.d == 2:
        return vertex_normals_of(V, S)
    if mesh.m != 2:
        return np.zeros_like(V)
    t = V[S[:, 1]] - V[S[:, 0]]
    rot = np.stack([t[:, 1], -t[:, 0]], axis=1)  # outward for counter-clockwise curves
    n = scatter_sum(V.shape[0], [(S[:, j], rot) for j in range(2)])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def special_conformal_map(X: np.ndarray, b: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """(N, 3) points X moved by the special conformal transformation with parameter ``b`` ((3,), in units of
    ``scale``) about ``centre``: y -> (y - b |y|^2) / (1 - 2 <b, y> + |b|^2 |y|^2) with y = (X - centre) / scale
    (an inversion, a translation by -b and the inversion again). These maps form an abelian group (b adds), and
    d/de at b = e v is the conformal field V_v(y) = 2 <v, y> y - |y|^2 v."""
    y = (np.asarray(X, float) - centre) / scale
    y2 = np.einsum("ij,ij->i", y, y)
    return centre + scale * (y - np.outer(y2, b)) / (1 - 2 * y @ b + (b @ b) * y2)[:, None]


def inverse_stereographic(X: np.ndarray, centre: np.ndarray, rho: float) -> np.ndarray:
    """(N, 4) points of the unit 3-sphere: the inverse stereographic projection of radius ``rho`` about ``centre``
    of the points X ((N, 3)), y = (2 rho (x - c), |x - c|^2 - rho^2) / (|x - c|^2 + rho^2)."""
    x = np.asarray(X, float) - centre
    r2 = np.einsum("ij,ij->i", x, x)
    return np.column_stack([2 * rho * x, r2 - rho**2]) / (r2 + rho**2)[:, None]


def stereographic_reprojection(X: np.ndarray, centre: np.ndarray, rho: float, pole: np.ndarray) -> np.ndarray:
    """(N, 3) image of the points X ((N, 3)) under a Moebius transformation given through the unit 3-sphere.

    X is lifted to S^3 by the inverse stereographic projection of radius ``rho`` about ``centre``
    (:func:`inverse_stereographic`) and projected back to R^3 from the unit
    4-vector ``pole`` (onto the orthogonal 3-space, in an orthonormal basis of it). Willmore energies of closed
    surfaces are unchanged (when the pole is not on the surface); a surface that is a stereographic image of a
    minimal surface in S^3 (:func:`willmore_nlp.analysis.minimal_s3_fit` gives ``centre`` and ``rho``) is
    mapped to another image of the same minimal surface.
    """
    Y = inverse_stereographic(X, centre, rho)
    p = np.asarray(pole, float) / np.linalg.norm(pole)
    Q = np.linalg.qr(np.column_stack([p, np.eye(4)]))[0]  # first column +-p, the others span its complement
    return (Y @ Q[:, 1:4]) / (1 - Y @ p)[:, None]


def conformal_normals(mesh: Mesh, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(N, 10) normal components of the ten conformal fields of R^3 at the vertices of a surface in R^3: the
    translations (3), the rotations (3), the dilation (1) and the special conformal fields V_j(y) = 2 y_j y - |y|^2 e_j
    (3), with y = (x - centre) / scale (centre the vertex mean, scale = sqrt(area / 4 pi)); with the centre and the
    scale. ``normals``: the (N, 3) unit vertex normals when the caller has them."""
    X = mesh.vertices
    n = vertex_normals(mesh) if normals is None else normals
    centre = X.mean(axis=0)
    scale = length_scale(measure(mesh), 2, True)
    y = (X - centre) / scale
    yn = np.einsum("ij,ij->i", y, n)
    y2 = np.einsum("ij,ij->i", y, y)
    rot = np.cross(y, n)  # <e_j x y, n> = (y x n)_j: the rotations
    return np.column_stack([n, rot, yn] + [2 * y[:, j] * yn - y2 * n[:, j] for j in range(3)]), centre, scale


def conformal_fit(mesh0: Mesh, X1: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Fit of the normal motion of a closed surface from ``mesh0`` (vertices X0, (N, 3)) to the positions X1
    ((N, 3)) of the same vertices by the ten conformal fields of R^3.

    The normal displacement <X1 - X0, n> is fitted in the lumped L^2 inner product of X0 by the normal
    components of the translations, rotations, the dilation and the three special conformal fields
    V_j(y) = 2 y_j y - |y|^2 e_j, with y = (x - centre) / scale (centre the vertex mean, scale =
    sqrt(area / 4 pi)). These are the zero modes of the Willmore energy of a closed surface (it is Moebius
    invariant), so the L^2 gradient flow of the smooth energy has no component along them.

    Returns
    -------
    coefficients : (10,) array
        Of the fields in the order translations (3), rotations (3), dilation (1), special conformal (3), for
        the normal displacement divided by ``scale``: the least-norm fit, ignoring combinations of the fields
        whose normal components are below 1e-2 of the largest. The dilation's coefficient c is the relative
        dilation of the motion: X1 - X0 has the normal part of c (X0 - centre).
    share : float
        Part of the squared L^2 norm of the normal displacement that the fit explains (0 to 1; 0 for no motion).
    centre : (3,) array
    scale : float
    """
    X0 = mesh0.vertices
    n = vertex_normals(mesh0)
    m = lumped_mass(X0, mesh0.simplices)
    B, centre, scale = conformal_normals(mesh0, n)
    d = np.einsum("ij,ij->i", np.asarray(X1, float) - X0, n) / scale
    w = np.sqrt(m)
    # rcond: directions whose normal component nearly vanishes are left alone (moving along them would only slide
    # the vertices); a surface with a continuous symmetry has such directions (a torus of revolution: the rotation
    # about its axis and one more, singular value 1e-4 of the largest on a 32 x 16 grid), and there the special
    # conformal coefficients also pick up part of a similarity (3e-4 from one of size 1e-3): meant for surfaces
    # without one, e.g. of genus 2 (the double torus: 1e-6)
    c = np.linalg.lstsq(B * w[:, None], d * w, rcond=1e-2)[0]
    total = float(np.sum(m * d**2))
    share = float(np.sum(m * (B @ c) ** 2)) / total if total > 0 else 0.0
    return c, min(share, 1.0), centre, scale


def conformal_motion(mesh0: Mesh, X1: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Special conformal part of the motion of a closed surface from ``mesh0`` (vertices X0, (N, 3)) to the
    positions X1 ((N, 3)) of the same vertices (:func:`conformal_fit`).

    A discrete flow can drift along the Moebius orbit of its limit (reports/mesh_quality_study.md, genus 2).
    Returns ``(b, centre, scale)``: the (3,) coefficients of the special conformal fields, so that
    :func:`special_conformal_map` with ``-b`` undoes that part of the motion to first order.
    """
    c, _, centre, scale = conformal_fit(mesh0, X1)
    return c[7:], centre, scale


def _sides(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(3, K) side lengths of triangles, side j opposite corner j."""
    return np.stack([np.linalg.norm(V[S[:, (j + 1) % 3]] - V[S[:, (j + 2) % 3]], axis=1) for j in range(3)])


def _corner_angles(sides: np.ndarray) -> np.ndarray:
    """(3, K) triangle angles (radians) at corners 0, 1, 2 from the sides of :func:`_sides` (law of cosines)."""
    a, b, c = sides
    return np.arccos(np.clip(np.stack([(b**2 + c**2 - a**2) / (2 * b * c), (a**2 + c**2 - b**2) / (2 * a * c),
                                       (a**2 + b**2 - c**2) / (2 * a * b)]), -1, 1))


def min_angles(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(K,) smallest angle (degrees) of each triangle ``S`` at positions ``V``."""
    return np.degrees(_corner_angles(_sides(V, S))).min(axis=0)


def gauss_curvature(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N,) discrete Gauss curvature of a closed triangulated surface: angle defect / lumped mass.

    ``K_i = (2 pi - sum of the triangle angles at vertex i) / m_i``, so that sum_i m_i K_i = 2 pi chi
    exactly (discrete Gauss-Bonnet).
    """
    V = np.asarray(V, float)
    ang = scatter_sum(V.shape[0], [(S.T.ravel(), _corner_angles(_sides(V, S)).ravel())])
    return (2 * np.pi - ang) / lumped_mass(V, S)


def willmore_energy(mesh: Mesh, nodes: np.ndarray | None = None, vertices: np.ndarray | None = None,
                    simplices: np.ndarray | None = None) -> float:
    """w = 1/2 int h^2 with h the sum of principal curvatures.

    Uses the stiffness matrix and the lumped mass: w = 1/2 sum_i |(L X)_i|^2 / m_i, over
    interior vertices only when the mesh has a boundary. A circle of radius R gives pi/R,
    a sphere 8 pi, the Clifford torus 4 pi^2 (in the limit of fine meshes).

    Parameters
    ----------
    mesh : Mesh
    nodes : (N,) bool array, optional
        Sum over these vertices only (e.g. a clamped patch and its boundary nodes).
    vertices : (N, m) float array, optional
        Positions to use instead of ``mesh.vertices`` with the mesh's connectivity (not validated:
        e.g. a k-fold covered circle, whose vertices coincide in pairs).
    simplices : (K, d + 1) int array, optional
        Connectivity to use instead of ``mesh.simplices``, of the same vertices with the same boundary (not
        validated: e.g. the mesh after interior edge flips, without building and checking a new Mesh).
    """
    V = mesh.vertices if vertices is None else np.asarray(vertices, float)
    S = mesh.simplices if simplices is None else np.asarray(simplices)
    LX, mi = stiffness_action(V, S)  # (four calls per relaxation step: not assembled)
    e = 0.5 * np.sum(LX**2, axis=1) / mi
    if not mesh.is_closed:
        e[mesh.boundary_vertices] = 0.0
    if nodes is not None:
        e = e[np.asarray(nodes, bool)]
    return float(e.sum())


def measure(mesh: Mesh, vertices: np.ndarray | None = None) -> float:
    """Total length (curves) or area (surfaces)."""
    V = mesh.vertices if vertices is None else vertices
    vol, _ = element_geometry(V, mesh.simplices)
    return float(vol.sum())


def length_scale(size: float, d: int, closed: bool) -> float:
    """The length L of a curve or surface of total length or area ``size``, for which Willmore flow's time scales as
    L^4 (X -> s X takes t -> s^4 t, the energy of a surface being scale invariant and that of a curve scaling as 1/s).

    The radius of the sphere (a closed surface, ``d = 2``) or the disk (an open one) of that area, of the circle (a
    closed curve, ``d = 1``) of that length, or half the length of an open curve: 1 for the unit sphere, disk and
    circle and for the segment [-1, 1].

    Parameters
    ----------
    size : float
        Total area (surfaces) or length (curves), :func:`measure`.
    d : int
        1 for curves, 2 for surfaces.
    closed : bool
        Whether the mesh has no boundary.

    Returns
    -------
    float
    """
    if d == 2:
        return float(np.sqrt(size / (4 * np.pi if closed else np.pi)))
    return size / (2 * np.pi) if closed else size / 2


def enclosed_volume(mesh: Mesh) -> float:
    """Signed enclosed area (closed curves in R^2, shoelace) or volume (closed surfaces); for closed curves in R^3
    the norm of the vector area 1/2 sum x_i x x_(i+1) (unsigned: the enclosed area of a plane curve in any plane,
    and for a space curve its largest projected area, independent of rotations; it was the area of the x1-x2
    projection, which a turning trefoil's report drew growing 22 -> 116: a new user's check). NaN for open meshes.
    """
    if not mesh.is_closed:
        return float("nan")
    V, S = mesh.vertices, mesh.simplices
    if mesh.d == 1:
        a, b = V[S[:, 0]], V[S[:, 1]]
        if mesh.m == 3:
            return float(np.linalg.norm(0.5 * np.cross(a, b).sum(axis=0)))
        return float(0.5 * np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    return float(np.einsum("ij,ij->i", V[S[:, 0]], np.cross(V[S[:, 1]], V[S[:, 2]])).sum() / 6.0)


def inward(mesh: Mesh) -> str:
    """How a closed mesh is oriented inward ("" when it is not): its signed enclosed volume (area of a plane curve)
    is <= 0, e.g. "the mesh is oriented inward (signed enclosed volume -5.666)"."""
    v = enclosed_volume(mesh)
    if not v <= 0:
        return ""
    if mesh.d == 2:
        return f"the mesh is oriented inward (signed enclosed volume {v:.4g})"
    # (not "runs clockwise": a figure eight has no sense of rotation; its clockwise loop enclosed more, a new user's)
    return (f"the curve's signed enclosed area is negative ({v:.4g}: it runs clockwise, or where it crosses itself "
            "its clockwise loops enclose more)")


def require_outward(mesh: Mesh, what: str) -> None:
    """Refuse (MeshError) a closed mesh oriented inward (:func:`inward`), for ``what`` (a volume constraint, c0), which
    takes the outward orientation."""
    from willmore_nlp.mesh.core import MeshError

    state = inward(mesh)
    if state:
        turn = "each triangle's vertex order (trimesh: mesh.invert())" if mesh.d == 2 else "the vertex order"
        raise MeshError(f"{mesh.source}: {state}: {what} takes the outward orientation; reverse {turn}")


def redistribute_curve(mesh: Mesh) -> np.ndarray:
    """Vertices of a closed curve moved along it to equal arc-length spacing (connectivity kept).

    Each closed component is walked from its lowest-numbered vertex in the direction of its first
    segment and its vertices are placed, in walk order, at equal arc length along the polygon
    (:func:`willmore_nlp.mesh.shapes.resample_closed_polyline`): a purely tangential move
    that changes the curve by O(h^2 kappa) (the new polygon cuts the old one's corners).

    Returns
    -------
    (N, m) new vertex positions.

    Raises
    ------
    MeshError
        When the mesh is not a closed curve.
    """
    from willmore_nlp.mesh.core import MeshError
    from willmore_nlp.mesh.shapes import resample_closed_polyline

    if mesh.d != 1 or not mesh.is_closed:
        raise MeshError(f"{mesh.source}: redistribution is implemented for closed curves")
    S = mesh.simplices
    nbrs: list[list[int]] = [[] for _ in range(mesh.n_vertices)]
    for a, b in S:
        nbrs[a].append(int(b))
        nbrs[b].append(int(a))
    X = np.array(mesh.vertices, dtype=float)
    seen = np.zeros(mesh.n_vertices, dtype=bool)
    for start in range(mesh.n_vertices):
        if seen[start]:
            continue
        order, prev, cur = [start], -1, start
        seen[start] = True
        while True:
            nxt = nbrs[cur][0] if nbrs[cur][0] != prev else nbrs[cur][1]
            if nxt == start:
                break
            order.append(nxt)
            seen[nxt] = True
            prev, cur = cur, nxt
        X[order] = resample_closed_polyline(X[order], len(order))
    return X


def triangle_quality(V: np.ndarray, S: np.ndarray, graded: bool = False) -> dict[str, float]:
    """Smallest angle (degrees) and longest/shortest edge ratio of the triangles ``S`` (a subset of a mesh).

    Parameters
    ----------
    V : (N, 3) positions
    S : (K, 3) triangles (may use only some of the vertices)
    graded : the edge ratio of a mesh whose resolution varies on purpose: the largest ratio within one triangle
        (instead of over all of them)
    """
    sides = _sides(np.asarray(V, float), np.asarray(S))
    ratio = (sides.max(axis=0) / sides.min(axis=0)).max() if graded else sides.max() / sides.min()
    return {"min_angle": float(np.degrees(_corner_angles(sides)).min()), "edge_ratio": float(ratio)}


def dihedral_angles(V: np.ndarray, F: np.ndarray, pairs: np.ndarray | None = None) -> np.ndarray:
    """(E,) angles in degrees between the unit normals of the two triangles of every interior edge: 0 where they
    lie flat, 180 where the surface folds back onto itself.

    Parameters
    ----------
    V : (N, 3) positions
    F : (K, 3) consistently oriented triangles
    pairs : (E, 2) the triangles of each edge (:func:`willmore_nlp.mesh.topology.edge_triangles`, computed when
        None)
    """
    if pairs is None:
        pairs = edge_triangles(F)[0]
    n = face_normals(np.asarray(V, float), np.asarray(F))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def quality(mesh: Mesh) -> dict[str, float]:
    """Mesh quality figures.

    Returns
    -------
    dict
        ``edge_ratio``: longest / shortest edge; ``min_edge``: shortest edge;
        for surfaces also ``min_angle`` (degrees) and ``max_aspect`` (longest edge over
        2 sqrt(3) times the inradius, so that an equilateral triangle has 1), and in R^3 ``max_dihedral``, the largest
        angle (degrees) between the normals of two adjacent triangles (:func:`dihedral_angles`: 180 for a fold).
    """
    ell = mesh.edge_lengths()
    q = {"edge_ratio": float(ell.max() / ell.min()), "min_edge": float(ell.min())}
    if mesh.d == 2:
        V, S = mesh.vertices, mesh.simplices
        sides = _sides(V, S)
        a, b, c = sides
        area = simplex_volumes(V, S)
        s = 0.5 * (a + b + c)
        inr = area / s
        longest = np.maximum(np.maximum(a, b), c)
        q["min_angle"] = float(min_angles(V, S).min())
        q["max_aspect"] = float((longest / (2 * np.sqrt(3) * inr)).max())
        if mesh.m == 3:
            dihedral = dihedral_angles(V, S)
            q["max_dihedral"] = float(dihedral.max()) if dihedral.size else 0.0
    return q
