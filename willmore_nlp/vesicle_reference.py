"""Axisymmetric vesicle shapes of minimal bending energy at fixed area and volume (c0 = 0).

An independent reference for the vesicle problem: the shape equations of the spontaneous-curvature
model reduce, for surfaces of revolution, to a one-dimensional variational problem for the
generating curve (Seifert, Berndl & Lipowsky, Phys. Rev. A 44, 1182 (1991), Sec. II; Seifert,
Adv. Phys. 46, 13 (1997), Sec. 4.2). This module solves that problem directly, without any
triangulated surface: the contour is parametrised by arc length s in [0, L] and the tangent angle
psi(s) (psi = 0 at the lower pole, psi = pi at the upper pole); with x the distance to the axis,

    x' = cos psi,  z' = sin psi,  k1 = psi',  k2 = sin(psi) / x,
    w = 1/2 int (k1 + k2)^2 dA = pi int x (psi' + sin(psi)/x)^2 ds,
    A = 2 pi int x ds,  V = pi int x^2 sin(psi) ds.

Discretisation: psi at ``n + 1`` equally spaced nodes, x and z by the midpoint rule, the energy,
area and volume integrands at segment midpoints (second order in 1/n). The constraints x(L) = 0,
A = 4 pi and V = v 4 pi / 3 (reduced volume v = 6 sqrt(pi) V / A^(3/2)) are imposed exactly and the
energy is minimised by IPOPT (CasADi, exact Hessian; the nodes' x are unknowns too, tied to psi by the midpoint
rule as constraints, which keeps the Hessian sparse: the same solutions to 1e-14 as with x the cumulative sums
of psi, 8-15 times faster at 200 + 400 segments, measured). The branch (prolate, oblate/discocyte,
stomatocyte) is chosen by the starting contour. The energy is reported in units of the sphere's
8 pi (= 8 pi kappa in the papers' units, since this library's w is the papers' F / kappa).

Checks (tests/test_vesicle_reference.py): v = 1 gives the sphere (w / 8 pi = 1); the energy of a
spheroid contour (no minimisation) matches the closed form of the spheroid's bending energy; the
minimised energies converge at second order in n; the prolate branch tends to 2 (two spheres)
as v -> 1/sqrt(2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from willmore_nlp.mesh.core import Mesh

BRANCHES = ("prolate", "oblate", "stomatocyte")


@dataclass(frozen=True)
class AxisymmetricShape:
    """A minimised contour.

    Attributes
    ----------
    branch : the starting branch ("prolate", "oblate" or "stomatocyte")
    v : reduced volume
    energy : w / (8 pi), w = 1/2 int (k1 + k2)^2 dA
    length : contour length L (area 4 pi)
    psi : (n + 1,) tangent angles at the nodes
    x, z : (n + 1,) node positions (distance to the axis, height)
    converged : whether IPOPT reported success
    """

    branch: str
    v: float
    energy: float
    length: float
    psi: np.ndarray
    x: np.ndarray
    z: np.ndarray
    converged: bool


def _dx(psi, L, lib=np):  # numpy arrays or CasADi symbols
    """(n,) the segments' steps in x, (L / n) cos(psi at their midpoints): the midpoint rule of x' = cos psi for the
    (n + 1,) tangent angles ``psi`` at the nodes and the length ``L``."""
    return L / (psi.shape[0] - 1) * lib.cos(0.5 * (psi[1:] + psi[:-1]))


def _contour(psi: np.ndarray, L: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, z) at the nodes from tangent angles at the nodes and the length (midpoint rule)."""
    h = L / (psi.size - 1)
    x = np.concatenate([[0.0], np.cumsum(_dx(psi, L))])
    z = np.concatenate([[0.0], np.cumsum(h * np.sin(0.5 * (psi[1:] + psi[:-1])))])
    return x, z


def contour_energy_area_volume(psi, L, lib=np, x=None):  # numpy arrays or CasADi symbols
    """Discrete w, A, V and end point x(L) of a contour (numpy or CasADi expressions).

    Parameters
    ----------
    psi : (n + 1,) tangent angles at the nodes
    L : contour length
    lib : ``numpy`` or ``casadi`` (the functions ``cos``, ``sin``, ``cumsum``, ``sum1``/``sum`` used)
    x : (n + 1,) distances of the nodes to the axis, optional: the integrals at these x instead of the ones that
        psi and L give (the lifted NLP of :func:`solve_axisymmetric`, which imposes x[i+1] - x[i] = (L / n)
        cos(psi at the midpoint) as constraints; the same at its solutions)

    Returns
    -------
    (w, A, V, x) with x the (n + 1,) distances of the nodes to the axis (x[0] = 0; closure needs x[n] = 0)
    """
    n = psi.shape[0] - 1
    h = L / n
    pm = 0.5 * (psi[1:] + psi[:-1])
    total = np.sum if lib is np else lib.sum1
    if x is None:
        dx = _dx(psi, L, lib)
        x = np.concatenate([[0.0], np.cumsum(dx)]) if lib is np else lib.vertcat(0, lib.cumsum(dx))
    xm = 0.5 * (x[1:] + x[:-1])
    k = (psi[1:] - psi[:-1]) / h + lib.sin(pm) / xm
    w = np.pi * total(h * xm * k**2)
    A = 2 * np.pi * total(h * xm)
    V = np.pi * total(h * xm**2 * lib.sin(pm))
    return w, A, V, x


def _start(branch: str, v: float, n: int) -> tuple[np.ndarray, float]:
    """Starting contour (psi at n + 1 nodes, L) of the branch, area about 4 pi."""
    u = np.linspace(0.0, 1.0, n + 1)
    if branch in ("prolate", "oblate"):
        from willmore_nlp.mesh.shapes import _spheroid_ratio, spheroid_area_volume

        r = _spheroid_ratio(v, branch) if v < 1 else 1.0
        t = np.linspace(0.0, np.pi, 20001)
        xs, zs = np.sin(t), -r * np.cos(t)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(zs)))])
        ang = np.arctan2(r * np.sin(t), np.cos(t))
        ang[0], ang[-1] = 0.0, np.pi
        scale = np.sqrt(4 * np.pi / spheroid_area_volume(1.0, r)[0])
        return np.interp(u * s[-1], s, ang), float(scale * s[-1])
    # stomatocyte: outer sphere turning to psi = 0.8 pi, a tight rim turning to 1.5 pi, an inner cap back to pi
    knots_u, knots_psi = [0.0, 0.62, 0.70, 1.0], [0.0, 0.8 * np.pi, 1.5 * np.pi, np.pi]
    return np.interp(u, knots_u, knots_psi), 4.0


def solve_axisymmetric(v: float, branch: str, n: int = 200, start: AxisymmetricShape | None = None,
                       tol: float = 1e-12) -> AxisymmetricShape:
    """Minimal-energy contour of reduced volume ``v`` on a branch, area 4 pi, c0 = 0.

    Parameters
    ----------
    v : reduced volume in (0, 1]
    branch : "prolate", "oblate" (discocytes below v ~ 0.7) or "stomatocyte"
    n : number of contour segments
    start : a previous solution to start from (continuation in v or n); its contour is resampled
    tol : IPOPT tolerance

    Returns
    -------
    AxisymmetricShape
    """
    import casadi as ca

    if branch not in BRANCHES:
        raise ValueError(f"branch must be one of {BRANCHES}, got {branch!r}")
    if start is None:
        psi0, L0 = _start(branch, v, n)
    else:
        psi0 = np.interp(np.linspace(0, 1, n + 1), np.linspace(0, 1, start.psi.size), start.psi)
        L0 = start.length
    p = ca.SX.sym("p", n - 1)
    L = ca.SX.sym("L")
    xi = ca.SX.sym("x", n - 1)  # the interior nodes' distances to the axis, lifted (x[0] = x[n] = 0: closure)
    psi = ca.vertcat(0, p, np.pi)
    x = ca.vertcat(0, xi, 0)
    w, A, V, _ = contour_energy_area_volume(psi, L, ca, x=x)
    # x[i+1] - x[i] = h cos(psi_mid) (the midpoint rule, closure included), area 4 pi, volume v 4 pi / 3; interior
    # nodes off the axis (x > 0). Lifted: every row depends on a few unknowns and L, so the Hessian is sparse (with x
    # the cumulative sums of psi it was dense: building the n = 400 solver took 23 s, solving it 0.5 s)
    nlp = {"x": ca.vertcat(p, L, xi), "f": w / (8 * np.pi),
           "g": ca.vertcat(x[1:] - x[:-1] - _dx(psi, L, ca), A / (4 * np.pi) - 1, V / (4 * np.pi / 3) - v, xi)}
    opts: dict[str, object] = {"print_level": 0, "tol": tol, "max_iter": 3000, "sb": "yes"}
    if start is not None:
        # a warm start: a small initial barrier keeps IPOPT near the given contour (the default 0.1
        # pushes a stomatocyte's narrow neck off the axis and lands on wound contours, w / 8 pi ~ 10)
        opts["mu_init"] = 1e-6
    solver = ca.nlpsol("axisym", "ipopt", nlp, {"print_time": False, "ipopt": opts})
    x0 = _contour(psi0, L0)[0][1:-1]  # (the start's x; its last node is the start's closure error, not imposed)
    res = solver(x0=np.concatenate([psi0[1:-1], [L0], x0]), lbg=0, ubg=[0.0] * (n + 2) + [np.inf] * (n - 1),
                 lbx=[-np.inf] * (n - 1) + [1e-3] + [-np.inf] * (n - 1), ubx=np.inf)
    sol = np.asarray(res["x"]).ravel()[:n]
    psi_n = np.concatenate([[0.0], sol[:-1], [np.pi]])
    x, z = _contour(psi_n, float(sol[-1]))
    return AxisymmetricShape(branch, float(v), float(res["f"]), float(sol[-1]), psi_n, x, z,
                             bool(solver.stats()["success"]))


def classify(shape: AxisymmetricShape) -> str:
    """Name of the shape: "stomatocyte" (the contour turns past straight down, psi > 3 pi / 2, into an
    invagination at the upper pole, or psi < -pi / 2 at the lower one), "discocyte" (psi < 0 near the
    pole: a dimple, biconcave), "prolate" (longer along the axis than across) or "oblate"."""
    if shape.psi.max() > 1.5 * np.pi or shape.psi.min() < -0.5 * np.pi:
        return "stomatocyte"
    if shape.psi.min() < -1e-6:
        return "discocyte"
    return "prolate" if np.ptp(shape.z) > 2 * shape.x.max() else "oblate"


STOMATOCYTE_SEED_V = 0.55
"""Reduced volume at which the stomatocyte start contour converges to a stomatocyte (at n = 100);
other v on that branch are reached by continuation in v from there."""


def branch_energy(v: float, branch: str, n: int = 200, dv: float = 0.01) -> AxisymmetricShape:
    """Minimal contour on a branch, reached robustly.

    The prolate and oblate branches start from the spheroid of reduced volume ``v`` at n = 100; the
    stomatocyte branch starts from the stomatocyte contour at v = 0.55 and follows the branch in steps
    of ``dv`` to ``v`` (its start contour alone lands on a discocyte or a multiply wound contour at
    other v). The n = 100 solution is then refined to ``n``.

    Returns
    -------
    AxisymmetricShape (check :func:`classify`: a branch can end, e.g. the stomatocyte turns into a
    discocyte above v ~ 0.6).
    """
    n0 = min(n, 100)
    if branch == "stomatocyte":
        s = solve_axisymmetric(STOMATOCYTE_SEED_V, branch, n0)
        steps = max(1, int(np.ceil(abs(v - STOMATOCYTE_SEED_V) / dv)))
        for vi in np.linspace(STOMATOCYTE_SEED_V, v, steps + 1)[1:]:
            s = solve_axisymmetric(float(vi), branch, n0, start=s)
    else:
        s = solve_axisymmetric(v, branch, n0)
    return s if n == n0 else solve_axisymmetric(v, branch, n, start=s)


def extrapolated_energy(v: float, branch: str, n: int = 200) -> tuple[AxisymmetricShape, AxisymmetricShape, float]:
    """The minimal contours at ``n`` and ``2 n`` segments and the Richardson extrapolation (second order) of their
    energies.

    Returns
    -------
    (a, b, e_inf): the shapes at n and 2 n segments (energies a.energy, b.energy; check ``converged``) and
    e_inf = (4 b.energy - a.energy) / 3, in units of 8 pi.
    """
    a = branch_energy(v, branch, n)
    b = solve_axisymmetric(v, branch, 2 * n, start=a)
    return a, b, (4 * b.energy - a.energy) / 3


def revolve_contour(shape: AxisymmetricShape, subdivisions: int = 3) -> Mesh:
    """The surface of revolution of a contour with an icosphere's connectivity.

    Icosphere vertex at polar angle theta (from the lower pole) and azimuth phi goes to the contour
    point at arc length s = L theta / pi, azimuth kept (exact for the sphere). Arc length rather than
    area fraction: a stomatocyte's neck has little area but a long contour, and mapping by area put
    too few vertices there (measured at 642 vertices: zig-zag triangles, mesh area 9 % above 4 pi).
    Orientation is kept (outward normals), so the mesh can start a flow or an Evolver run on the
    branch of ``shape`` (e.g. a stomatocyte).

    Returns
    -------
    Mesh with 10 * 4**subdivisions + 2 vertices, symmetry axis x3, area close to 4 pi.
    """
    from willmore_nlp.mesh.shapes import icosphere

    ico = icosphere(subdivisions)
    U = ico.vertices / np.linalg.norm(ico.vertices, axis=1, keepdims=True)
    s = np.arccos(np.clip(-U[:, 2], -1.0, 1.0)) / np.pi * shape.length
    sn = np.linspace(0.0, shape.length, shape.psi.size)
    rho, z = np.interp(s, sn, shape.x), np.interp(s, sn, shape.z)
    phi = np.arctan2(U[:, 1], U[:, 0])
    X = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z - 0.5 * (shape.z.max() + shape.z.min())])
    return Mesh(X, ico.simplices, f"revolved {classify(shape)} (v={shape.v}, {X.shape[0]} vertices)")


REFERENCE_ENERGIES: dict[tuple[float, str], float] = {
    (0.85, "prolate"): 1.285676,
    (0.85, "discocyte"): 1.333543,
    (0.65, "prolate"): 1.827930,
    (0.65, "discocyte"): 1.826233,
    (0.59, "discocyte"): 1.981835,
    (0.59, "stomatocyte"): 1.978893,
    (0.55, "discocyte"): 2.087298,
    (0.55, "stomatocyte"): 1.983834,
}
"""w / (8 pi) of the axisymmetric minimisers at c0 = 0, keyed by (v, shape), Richardson-extrapolated from
n = 200 and 400 (:func:`extrapolated_energy`; regenerated with all digits by reports/vesicle_evolver.py,
where n = 200 and 400 differ by at most 1.5e-4). The lowest shape: prolate above v = 0.6511, discocyte
down to 0.5912, stomatocyte below (Seifert, Berndl & Lipowsky 1991 quote 0.652 and 0.591)."""


def _piercings(X: np.ndarray, F: np.ndarray, x: float, y: float) -> np.ndarray:
    """Heights where the vertical line through (x, y) pierces the triangles F of the vertices X ((N, 3))."""
    T = X[F] - [x, y, 0.0]  # (F, 3, 3)
    a, b, c = T[:, 0, :2], T[:, 1, :2], T[:, 2, :2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-300  # triangles seen edge-on along the axis cannot be pierced
    d = np.where(ok, det, 1.0)
    l1 = np.where(ok, (-a[:, 0] * (c[:, 1] - a[:, 1]) + (c[:, 0] - a[:, 0]) * a[:, 1]) / d, -1.0)
    l2 = np.where(ok, (-(b[:, 0] - a[:, 0]) * a[:, 1] + a[:, 0] * (b[:, 1] - a[:, 1])) / d, -1.0)
    eps = 1e-9  # the axis through a vertex (an icosphere's poles, kept there to 1e-10 by a flow): hit all its triangles
    hit = ok & (l1 >= -eps) & (l2 >= -eps) & (l1 + l2 <= 1 + eps)
    return ((1 - l1 - l2) * T[:, 0, 2] + l1 * T[:, 1, 2] + l2 * T[:, 2, 2])[hit]


def axis_profile(M: Mesh) -> tuple[float, float]:
    """Where the symmetry axis (through the vertex mean, along x3) pierces the surface: (distance of the
    lowest and highest piercing / height, their centre's offset from mid-height / height). A convex shape
    gives (1, 0), a discocyte (< 1, 0), a stomatocyte an offset (both poles on one side)."""
    X = M.vertices - M.vertices.mean(axis=0)
    z = _piercings(X, M.simplices, 0.0, 0.0)
    height = np.ptp(X[:, 2])
    mid = 0.5 * (X[:, 2].max() + X[:, 2].min())
    return float(np.ptp(z) / height), float((0.5 * (z.max() + z.min()) - mid) / height)


def has_pocket(M: Mesh, radius: float = 0.25, n: int = 9) -> bool:
    """Whether the surface has an inner pocket (a stomatocyte): some vertical line through a point within
    ``radius`` x (the surface's half-width) of the vertex mean pierces it 4 or more times (outer wall, pocket
    floor, pocket wall near the neck, outer wall). Unlike :func:`axis_profile` it does not need the neck's
    opening on the axis (a stomatocyte whose neck moved sideways); a discocyte, however deep its dimples,
    and a convex shape give 2 on every such line. ``n`` x ``n`` lines on a square grid."""
    X = M.vertices - M.vertices.mean(axis=0)
    r = radius * 0.5 * np.ptp(X[:, 0])
    g = np.linspace(-r, r, n)
    counts = [len(np.unique(np.round(_piercings(X, M.simplices, x, y), 9))) for x in g for y in g]
    return max(counts) >= 4


def invagination_depth(M: Mesh) -> float:
    """Depth of the invagination opening towards +x3, from :func:`axis_profile`: (top of the surface - the
    highest point where the axis pierces it) / height = 1/2 - offset - thick/2. 0 for a convex shape, the
    dimple's depth for a discocyte (< 1/2), about 0.8 for the stomatocyte of v = 0.55 (its contour's
    (z_max - z(inner pole)) / height is 0.797). The cup start (:func:`willmore_nlp.mesh.shapes.cup_of_reduced_volume`)
    opens towards +x3."""
    thick, offset = axis_profile(M)
    return 0.5 - offset - 0.5 * thick


def symmetry_axis(M: Mesh) -> tuple[np.ndarray, bool]:
    """The symmetry axis of a nearly axisymmetric closed surface, from the second moments of its area about its
    centroid: the principal direction whose moment is farthest, by ratio, from the other two.

    Returns
    -------
    axis : (3,) unit vector, its x3 component >= 0
    elongated : True when that moment is the largest (prolate, dumbbell), False when it is the smallest (oblate,
        discocyte)
    """
    from willmore_nlp.fem.assembly import element_geometry

    area, _ = element_geometry(M.vertices, M.simplices)
    C = M.vertices[M.simplices].mean(axis=1)
    C = C - area @ C / area.sum()
    lam, vec = np.linalg.eigh((C * area[:, None]).T @ C)  # (ascending; triangle centroids: O(h^2) of the moments)
    elongated = bool(lam[2] * lam[0] > lam[1] ** 2)  # (ratios: lam[2] / lam[1] > lam[1] / lam[0]; with differences
    # a 162-vertex discocyte whose disc was not round, thin along x3, was read along its long axis and named convex)
    axis = vec[:, 2] if elongated else vec[:, 0]
    return (axis if axis[2] >= 0 else -axis), elongated


def _along_x3(M: Mesh, axis: np.ndarray) -> Mesh:
    """M rotated (about its vertex mean) so that the unit vector ``axis`` becomes x3."""
    from scipy.spatial.transform import Rotation

    R, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [axis])
    return M.with_vertices(R.apply(M.vertices - M.vertices.mean(axis=0)))


HULL_CONVEX = 0.999
"""A closed surface whose enclosed volume is at least this share of its convex hull's is convex for
:func:`mesh_shape`. The axisymmetric prolate minimisers (revolved onto 642 vertices) give 0.99988 at v = 0.9, whose
contour is convex, and 0.9877 / 0.943 / 0.821 at v = 0.85 / 0.8 / 0.7, whose contours turn back at a waist (the
flow's meshes at those v: 0.987 / 0.943 / 0.819)."""


def hull_share(M: Mesh) -> float:
    """Enclosed volume of the closed surface ``M`` / the volume of its vertices' convex hull (1 for a convex
    polyhedron)."""
    from scipy.spatial import ConvexHull

    from willmore_nlp.geometry import enclosed_volume

    return float(enclosed_volume(M) / ConvexHull(np.asarray(M.vertices)).volume)


def mesh_shape(M: Mesh) -> str:
    """Shape name of a mesh: "stomatocyte" (an inner pocket, :func:`has_pocket`), "cup" (an open invagination
    on one side: :func:`axis_profile`'s offset >= 0.1 without a pocket), "discocyte" (dimples on both sides:
    axis thickness < 0.95), "convex" (:func:`hull_share` >= :data:`HULL_CONVEX`), "dumbbell" (elongated, with a
    waist: its volume below that share of its convex hull's) or "non-convex" (flattened, without those), read along
    the surface's :func:`symmetry_axis` (it was read along x3, and a flow may turn a shape: a new user's oblate v =
    0.9 start relaxed into a prolate lying in the x1-x2 plane, and c0 = 0.5 dumbbells along x1 were named
    discocytes, their waist read as a dimple; dumbbells were named "convex" until a new user's v = 0.7 one, its
    waist 0.74 of its bulbs' radius)."""
    axis, elongated = symmetry_axis(M)
    if axis[2] < 1 - 1e-9:
        M = _along_x3(M, axis)
    if has_pocket(M):
        return "stomatocyte"
    thick, offset = axis_profile(M)
    if abs(offset) >= 0.1:
        return "cup"
    if thick < 0.95:
        return "discocyte"
    if hull_share(M) >= HULL_CONVEX:
        return "convex"
    return "dumbbell" if elongated else "non-convex"
