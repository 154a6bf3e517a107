"""Small analysis helpers shared by tests, studies and reports."""

from __future__ import annotations

from typing import Any

import numpy as np


def fit_order(h: np.ndarray | list[float], err: np.ndarray | list[float]) -> float:
    """Least-squares slope of log(err) against log(h): the observed convergence order.

    Parameters
    ----------
    h : (n,) mesh sizes or step sizes, n >= 2
    err : (n,) positive errors
    """
    h_, e_ = np.asarray(h, float), np.asarray(err, float)
    if h_.size < 2 or h_.size != e_.size or np.any(h_ <= 0) or np.any(e_ <= 0):
        raise ValueError("fit_order needs at least two positive (h, err) pairs")
    return float(np.polyfit(np.log(h_), np.log(e_), 1)[0])


def winding_number(V: np.ndarray, center: np.ndarray | None = None) -> float:
    """Winding number of a closed polygon (vertices in order, (n, 2+) array) around ``center``.

    Uses the x1-x2 projection; ``center`` defaults to the vertex mean.
    """
    c = V[:, :2] - (V[:, :2].mean(axis=0) if center is None else np.asarray(center)[:2])
    z = c[:, 0] + 1j * c[:, 1]
    dphi = np.angle(np.roll(z, -1) / z)
    return float(dphi.sum() / (2 * np.pi))


def circle_step_radius(Rk: float, tau: float, tt: float) -> float:
    """Radius after one step of the time-discrete, space-continuous scheme for a circle (Sec. 2.1).

    Solves (R - Rk)/tau = 1/2 (R^4 - 3 R^2 tt) / ((R^2 + tt)^3 Rk) for the root near Rk.
    """
    from scipy.optimize import brentq

    def F(R: float) -> float:
        return (R - Rk) / tau - 0.5 * (R**4 - 3 * R**2 * tt) / ((R**2 + tt) ** 3 * Rk)

    return float(brentq(F, 0.5 * Rk, 2.0 * Rk + 10 * tau / Rk**3))


def sphere_step_radius(Rk: float, tau: float, tt: float, lam: float = 0.0) -> float:
    """Radius after one step of the time-discrete, space-continuous scheme for a round sphere.

    With Y = X / (1 + 2 tt/R^2) the inner step, e(R) = 8 pi / (1 + 2 tt/R^2)^2 + lam 4 pi R^2,
    and stationarity of 4 pi Rk^2 (R - Rk)^2 + 2 tau e(R) gives
    R - Rk = -(tau / Rk^2) (16 tt / (R^3 (1 + 2 tt/R^2)^3) + 2 lam R).
    (The scheme shrinks spheres at the rate 16 tt / R^5 for lam = 0: an O(tt) consistency error.)
    """
    from scipy.optimize import brentq

    def F(R: float) -> float:
        return R - Rk + tau / Rk**2 * (16 * tt / (R**3 * (1 + 2 * tt / R**2) ** 3) + 2 * lam * R)

    # the root nearest below Rk (F(Rk) >= 0): the step's, continuous in tau from 0. Farther down the 16 tt / R^3 term
    # can make F positive again, and a fixed bracket [1e-3 Rk, Rk] then had no sign change (Rk = 1, tau = 0.01,
    # tt = 1e-6, lam = 1: a new user's check)
    if F(Rk) == 0:
        return float(Rk)
    hi = float(Rk)
    for R in [Rk * (1 - 2.0**-j) for j in range(40, 0, -1)] + [Rk * 2.0**-j for j in range(2, 41)]:  # (descending)
        if F(R) <= 0:
            return float(brentq(F, R, hi, xtol=1e-15 * Rk, rtol=4 * np.finfo(float).eps))
        hi = R
    raise ValueError(f"sphere_step_radius: no root in (0, Rk), Rk = {Rk:g}, tau = {tau:g}, tt = {tt:g}, lam = {lam:g}")


def polygon_equilibrium_radius(n: int, k: int, tt: float, lam: float) -> float:
    """Radius minimising the scheme's energy e(R) over regular k-fold covered n-gons (closed form in R).

    For the rotating radial field of a regular polygon with angle th = 2 pi k / n per segment, the
    consistent mass and the stiffness act as scalars mm = l (4 + 2 cos th)/6 and ll = 2 (1 - cos th)/l
    (l the edge length), so e(R) = n/2 mm R^2 ll^2 / (mm + tt ll)^2 + lam n l; stationary k-fold
    polygons of the flow sit at its minimiser (-> 1/sqrt(2 lam) as n -> oo, tt -> 0).
    """
    from scipy.optimize import minimize_scalar

    th = 2 * np.pi * k / n

    def e(R: float) -> float:
        ell = 2 * R * np.sin(th / 2)
        mm = ell * (4 + 2 * np.cos(th)) / 6
        ll = 2 * (1 - np.cos(th)) / ell
        return n / 2 * mm * R**2 * ll**2 / (mm + tt * ll) ** 2 + lam * n * ell

    R0 = 1 / np.sqrt(2 * lam)
    return float(minimize_scalar(e, bounds=(0.1 * R0, 10 * R0), method="bounded", options={"xatol": 1e-12}).x)


WIDTH_DIRECTIONS = np.array([[1.0, 0.0], [0.0, 1.0], [np.sqrt(0.5), np.sqrt(0.5)], [np.sqrt(0.5), -np.sqrt(0.5)]])
"""Unit directions of :func:`axis_widths` and :func:`wulff_widths` in the plane: x1, x2 and the two diagonals."""


def axis_widths(X: np.ndarray) -> np.ndarray:
    """Widths of a point set along the coordinate axes and, for planar sets, the two diagonals.

    Parameters
    ----------
    X : (N, m) points

    Returns
    -------
    (4,) widths along x1, x2, (x1 + x2)/sqrt 2, (x1 - x2)/sqrt 2 for m = 2, or (m,) axis widths
    otherwise. For m = 2 the ratio of the mean diagonal to the mean axial width is 1 for a circle
    and sqrt 2 for an axis-aligned square (used to measure anisotropic shapes).
    """
    X = np.asarray(X, float)
    if X.shape[1] != 2:
        return X.max(axis=0) - X.min(axis=0)
    P = X @ WIDTH_DIRECTIONS.T
    return P.max(axis=0) - P.min(axis=0)


def polygon_distance(A: np.ndarray, B: np.ndarray) -> float:
    """Symmetric vertex-to-polygon distance of two closed polygons.

    Parameters
    ----------
    A, B : (n, m) and (k, m) vertices of closed polygons (in order)

    Returns
    -------
    max(largest distance from a vertex of A to the polygon B, and the same with A and B swapped).
    """

    def one_way(P: np.ndarray, Q: np.ndarray) -> float:
        E = np.roll(Q, -1, axis=0) - Q
        worst = 0.0
        for a in P:
            t = np.clip(np.einsum("ij,ij->i", a - Q, E) / np.einsum("ij,ij->i", E, E), 0.0, 1.0)
            worst = max(worst, float(np.min(np.linalg.norm(Q + t[:, None] * E - a, axis=1))))
        return worst

    A, B = np.asarray(A, float), np.asarray(B, float)
    return max(one_way(A, B), one_way(B, A))


def wulff_widths(anisotropy: Any) -> np.ndarray:
    """Widths 2 gamma(n) of the Wulff shape of a planar anisotropy along the directions of :func:`axis_widths`.

    ``anisotropy`` is an :class:`willmore_nlp.anisotropy.Anisotropy` on R^2 or anything
    :func:`willmore_nlp.anisotropy.get_anisotropy` accepts ("gamma1", "gamma2:1e-2", ...).
    For a convex, even gamma the Wulff shape's support function is gamma, so the width along n is 2 gamma(n).

    Returns
    -------
    (4,) widths along x1, x2, (x1 + x2)/sqrt 2, (x1 - x2)/sqrt 2.
    """
    from willmore_nlp.anisotropy import get_anisotropy

    return 2.0 * get_anisotropy(anisotropy, 2)(WIDTH_DIRECTIONS)


def _torus_grid_departure(X: np.ndarray, n_major: int, n_minor: int) -> np.ndarray | None:
    """(n_major, n_minor, 3) cylindrical coordinates (rho, z, rho dphi) of a torus grid's vertices about the
    centroid, dphi the angle from each copy's own meridian plane (see :func:`torus_grid_asymmetry`); None when X
    has another vertex count."""
    X = np.asarray(X, float)
    if X.shape[0] != n_major * n_minor:
        return None
    Y = X - X.mean(axis=0)
    rho, phi = np.hypot(Y[:, 0], Y[:, 1]), np.arctan2(Y[:, 1], Y[:, 0])
    dphi = np.angle(np.exp(1j * (phi - 2 * np.pi * (np.arange(X.shape[0]) // n_minor) / n_major)))
    return np.stack([rho, Y[:, 2], rho * dphi], -1).reshape(n_major, n_minor, 3)


def torus_grid_asymmetry(X: np.ndarray, n_major: int, n_minor: int) -> float:
    """Departure of a torus grid's state from the grid's n_major-fold rotational symmetry about x3.

    For the vertices numbered as :func:`willmore_nlp.mesh.shapes.torus` does (index = i n_minor + j, i around
    the axis), the largest standard deviation over the n_major rotated copies i of (rho, z, rho dphi) about the
    centroid, with dphi the angle from the copy's own meridian plane: 0 (round-off) for a state with that
    symmetry, whatever the connectivity. NaN when X has another vertex count (after a remeshing).
    """
    C = _torus_grid_departure(X, n_major, n_minor)
    return float("nan") if C is None else float(C.std(axis=0).max())


def torus_grid_asymmetry_wavenumber(X: np.ndarray, n_major: int, n_minor: int) -> int:
    """Azimuthal wavenumber (1 ... n_major/2) that carries most of the departure of :func:`torus_grid_asymmetry`.

    The copies' (rho, z, rho dphi) are Fourier transformed over i; the wavenumber with the largest summed
    amplitude is returned (n_major/2: neighbouring meridians move in opposite directions, a mesh-scale mode;
    1: the tilt or shift of a cyclide, the direction along which the smooth energy is Moebius invariant).
    -1 when X has another vertex count.
    """
    C = _torus_grid_departure(X, n_major, n_minor)
    if C is None:
        return -1
    amp = np.abs(np.fft.rfft(C, axis=0)).sum(axis=(1, 2))
    return int(np.argmax(amp[1:]) + 1)


def normal_jumps(V: np.ndarray, F: np.ndarray, free: np.ndarray) -> dict[str, float]:
    """Largest angles (degrees) between the normals of adjacent triangles, by where their edge lies.

    The C^1 match of a clamped patch across its boundary Gamma: the ``gamma`` value (edges with two
    fixed end points between a patch triangle, one with a free vertex, and a fixed one) is O(h) times
    the curvature for a smooth match, like the ``patch`` (edges with a free end point) and ``fixed``
    (the edges of the fixed surface with an end point on Gamma, which the flow never changes) values;
    a kink keeps ``gamma`` above them as h -> 0.

    Parameters
    ----------
    V : (N, 3) vertices
    F : (K, 3) triangles, consistently oriented (edges with one or more than two triangles are ignored)
    free : (N,) bool, the patch's free vertices
    """
    from willmore_nlp.geometry import dihedral_angles
    from willmore_nlp.mesh.topology import edge_triangles

    pairs, ends = edge_triangles(F)
    ang = dihedral_angles(V, F, pairs)
    t1, t2 = pairs[:, 0], pairs[:, 1]
    patch_tri = free[F].any(axis=1)
    gamma_node = np.zeros(len(V), bool)
    gamma_node[F[patch_tri].ravel()] = True
    gamma_node &= ~free
    on_free = free[ends].any(axis=1)
    gamma = ~on_free & (patch_tri[t1] != patch_tri[t2])
    fixed = ~on_free & ~patch_tri[t1] & ~patch_tri[t2] & gamma_node[ends].any(axis=1)

    def top(mask: np.ndarray) -> float:
        return float(ang[mask].max()) if mask.any() else float("nan")

    return {"gamma": top(gamma), "patch": top(on_free), "fixed": top(fixed)}


def _circle_fit(rho: np.ndarray, z: np.ndarray) -> tuple[float, float, float]:
    """(centre rho, centre z, radius) of the least-squares (algebraic) circle through the (K,) points (rho, z)."""
    A = np.column_stack([2 * rho, 2 * z, np.ones_like(rho)])
    (a, b, c), *_ = np.linalg.lstsq(A, rho**2 + z**2, rcond=None)
    return float(a), float(b), float(np.sqrt(c + a * a + b * b))


def torus_fit(V: np.ndarray) -> tuple[float, float]:
    """(R, r) of a torus of revolution about x3 by a least-squares circle fit of the cross-section (rho, x3)."""
    R, _, r = _circle_fit(np.hypot(V[:, 0], V[:, 1]), V[:, 2] - V[:, 2].mean())
    return R, r


def torus_frame(V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, np.ndarray]:
    """The torus of revolution nearest to the points V ((N, 3)) with free centre and axis, and V in its frame.

    Least squares of the point-surface distance over the centre c, the axis a (two angles), R and r, started
    from the vertex centroid, x3 and :func:`torus_fit`. Unlike :func:`torus_fit` (axis x3 through the origin) and
    :func:`sector_circles` (centroid, principal axis), it is not biased by a translation or tilt of the surface
    or by vertices gathering on one side of it.

    Returns
    -------
    (W, c, a, R, r, d): W (N, 3) the points in the torus's frame (c at the origin, a along x3; pass it to
    :func:`torus_fit`, :func:`clifford_reference` and, with ``centred=True``, :func:`sector_circles` and the
    functions built on it), c (3,), a (3,) unit, R, r, d (N,) the signed distances from the fitted torus.
    """
    from scipy.optimize import least_squares

    V = np.asarray(V, float)

    def axis(p: np.ndarray) -> np.ndarray:
        return np.array([np.sin(p[3]) * np.cos(p[4]), np.sin(p[3]) * np.sin(p[4]), np.cos(p[3])])

    def dist(p: np.ndarray) -> np.ndarray:
        q = V - p[:3]
        z = q @ axis(p)
        return np.hypot(np.linalg.norm(q - np.outer(z, axis(p)), axis=1) - p[5], z) - p[6]

    # theta starts off 0, where the azimuth phi has no derivative
    p = least_squares(dist, np.r_[V.mean(axis=0), 1e-3, 0.0, torus_fit(V)], xtol=1e-14, ftol=1e-14).x
    a = axis(p)
    e1 = np.cross(a, [0.0, 1.0, 0.0] if abs(a[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    W = (V - p[:3]) @ np.column_stack([e1, np.cross(a, e1), a])
    return W, p[:3], a, float(p[5]), float(p[6]), dist(p)


def sector_circles(V: np.ndarray, sectors: int = 8, centred: bool = False) -> np.ndarray:
    """(sectors, 3) cross-section circles (distance of the centre from the axis, its height, radius), fitted by
    least squares in each of ``sectors`` equal angular sectors about the principal axis (the direction of least
    extent) through the centroid, or with ``centred`` about x3 through the origin (V in the frame of
    :func:`torus_frame`)."""
    if centred:
        Y = np.asarray(V, float)
    else:
        c = V.mean(axis=0)
        _, vec = np.linalg.eigh(np.cov((V - c).T))
        axis, e1 = vec[:, 0], vec[:, 2]
        Y = (V - c) @ np.column_stack([e1, np.cross(axis, e1), axis])
    k = np.floor((np.arctan2(Y[:, 1], Y[:, 0]) + np.pi) / (2 * np.pi / sectors)).astype(int) % sectors
    out = np.empty((sectors, 3))
    for i in range(sectors):
        out[i] = _circle_fit(np.hypot(Y[k == i, 0], Y[k == i, 1]), Y[k == i, 2])
    return out


def sector_ratios(V: np.ndarray, sectors: int = 8, centred: bool = False) -> np.ndarray:
    """R/r of the :func:`sector_circles`: all equal on a torus of revolution; they spread when the flow leaves
    the rotational symmetry (a Moebius image of a torus, a cyclide, has the same smooth energy)."""
    C = sector_circles(V, sectors, centred)
    return C[:, 0] / C[:, 2]


def conformal_ratios(V: np.ndarray, sectors: int = 8, centred: bool = False) -> np.ndarray:
    """(sectors/2,) R/r of the torus of revolution Moebius-equivalent to the shape, from opposite sector circles.

    Two circles of one meridian plane (radii r1, r2, centres d apart) have the Moebius-invariant inversive
    distance delta = (d^2 - r1^2 - r2^2) / (2 r1 r2), which is 2 (R/r)^2 - 1 on a torus of revolution. On the
    64x32 Clifford torus inverted in spheres centred 3 and 4 away, where the circle fit gives R/r = 1.26 and
    1.76, these give 1.36-1.42 and 1.42-1.44 (sectors are wedges, not the cyclide's planes of circles).
    """
    C = sector_circles(V, sectors, centred)
    h = sectors // 2
    (Ra, za, ra), (Rb, zb, rb) = C[:h].T, C[h:].T
    delta = ((Ra + Rb) ** 2 + (za - zb) ** 2 - ra**2 - rb**2) / (2 * ra * rb)
    return np.sqrt((delta + 1) / 2)


def torus_projection(V: np.ndarray, R: float, r: float) -> np.ndarray:
    """Closest points of V on the torus of revolution (R, r) about x3 through the centroid height."""
    zc = V[:, 2].mean()
    rho = np.hypot(V[:, 0], V[:, 1])
    d = np.column_stack([rho - R, V[:, 2] - zc])
    d *= r / np.linalg.norm(d, axis=1, keepdims=True)
    rr = R + d[:, 0]
    return np.column_stack([rr * V[:, 0] / rho, rr * V[:, 1] / rho, zc + d[:, 1]])


def torus_distance(V: np.ndarray, R: float, r: float) -> np.ndarray:
    """(N,) distance of the points V ((N, 3)) from the torus of revolution (R, r) about the x3 axis, centred at
    the origin (the exact surface of ``shapes.torus(R, r, ...)``)."""
    return np.abs(np.hypot(np.hypot(V[:, 0], V[:, 1]) - R, V[:, 2]) - r)


def clifford_reference(V: np.ndarray, simplices: np.ndarray) -> float:
    """Willmore energy of the mesh-matched Clifford torus: the same vertices and connectivity, each vertex moved to
    its closest point on the Clifford torus (R/r = sqrt 2) whose tube radius r is the circle fit's
    (:func:`torus_fit`).

    The grid Clifford torus is a different mesh; this is the reference of the issue's "W never more than 0.5 %
    below the Clifford torus meshed at the same resolution" (docs/guide/mesh_quality.md).
    """
    from willmore_nlp.geometry import willmore_energy
    from willmore_nlp.mesh.core import Mesh

    _, r = torus_fit(V)
    return willmore_energy(Mesh(torus_projection(V, np.sqrt(2) * r, r), simplices))


def minimal_s3_fit(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, float, float]:
    """How far a closed surface ((N, 3) vertices, (K, 3) outward triangles) is from a stereographic image of a
    minimal surface in S^3 (the Clifford torus R/r = sqrt 2, Lawson's surfaces and their Moebius images).

    Such an image of the minimal surface in the unit sphere, projected with radius rho about the centre c,
    has the mean curvature H = (k1 + k2) / 2 = 2 <x - c, n> / (rho^2 + |x - c|^2) (n the outward normal;
    exact for the torus R = sqrt 2, r = 1 about the origin with rho = 1). c and rho are fitted by least
    squares in the lumped L^2 norm, H from :func:`willmore_nlp.geometry.mean_curvature_vector`.

    Returns
    -------
    (centre (3,), rho, residual): residual = the fit's L^2 error relative to the L^2 norm of H; O(h^2) on
    meshes of such surfaces (the Clifford torus on n x n/2 grids: 0.021, 0.0055, 0.0014 for n = 24, 48, 96),
    0.48 on the torus R/r = 2.
    """
    from scipy.optimize import least_squares

    from willmore_nlp.fem.assembly import lumped_mass
    from willmore_nlp.geometry import mean_curvature_vector, vertex_normals
    from willmore_nlp.mesh.core import Mesh

    V = np.asarray(V, float)
    mesh = Mesh(V, F)
    n = vertex_normals(mesh)
    H = -0.5 * np.einsum("ij,ij->i", mean_curvature_vector(mesh), n)
    m = lumped_mass(V, mesh.simplices)
    w = np.sqrt(m)

    def residual(q: np.ndarray) -> np.ndarray:
        x = V - q[:3]
        return w * (H - 2 * np.einsum("ij,ij->i", x, n) / (np.exp(2 * q[3]) + np.einsum("ij,ij->i", x, x)))

    size = np.log(np.sqrt(V.var(axis=0).sum()))
    best = min((least_squares(residual, np.r_[V.mean(axis=0), size + s]) for s in (-1.0, 0.0, 1.0)),
               key=lambda o: o.cost)
    return best.x[:3], float(np.exp(best.x[3])), float(np.sqrt(2 * best.cost / np.sum(m * H**2)))


def surface_distance(Va: np.ndarray, Fa: np.ndarray, Vb: np.ndarray, Fb: np.ndarray) -> float:
    """Symmetric max distance between two triangle meshes ((N, 3) vertices, (K, 3) triangles each): the largest
    distance of a vertex of either to the other's triangles (gpytoolbox's exact point-triangle distance), a
    Hausdorff distance sampled at the vertices, blind to tangential motion."""
    import gpytoolbox

    dab = gpytoolbox.squared_distance(np.asarray(Va, float), np.asarray(Vb, float), np.asarray(Fb), use_cpp=True)[0]
    dba = gpytoolbox.squared_distance(np.asarray(Vb, float), np.asarray(Va, float), np.asarray(Fa), use_cpp=True)[0]
    return float(np.sqrt(max(dab.max(), dba.max())))


def rigid_align(A: np.ndarray, B: np.ndarray, iterations: int = 20) -> np.ndarray:
    """(N, 3) points A moved rigidly (rotation and translation) toward the point cloud B ((M, 3)): centroids
    matched, then iterated closest points (trimesh's ``registration.icp``: nearest vertices of B as partners,
    a proper rotation and a translation, no scaling or reflection, ``iterations`` rounds).

    For comparing two surfaces that differ by a rigid motion plus a small change of shape; it finds the local
    optimum near the identity (the shapes are assumed roughly aligned already: a rotation of 0.05 rad of an
    ellipsoid's 642 vertices, moving them by up to 0.3 h, is undone to round-off; 0.1 rad stalls at 0.1).
    """
    from trimesh.registration import icp

    A, B = np.asarray(A, float), np.asarray(B, float)
    start = np.eye(4)
    start[:3, 3] = B.mean(axis=0) - A.mean(axis=0)
    _, X, _ = icp(A, B, initial=start, threshold=0.0, max_iterations=iterations, reflection=False, scale=False)
    return np.asarray(X)
