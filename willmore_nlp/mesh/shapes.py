"""Shape generators: the paper's initial curves and surfaces.

Every generator returns a validated :class:`~willmore_nlp.mesh.core.Mesh` with a
consistently oriented parametrisation (curves counter-clockwise, surfaces with outward
normals for the sphere and torus).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.validate import simplex_volumes


def closed_curve(points: np.ndarray, source: str = "<curve>") -> Mesh:
    """Closed polygon through ``points`` ((n, m) array), segments i -> i+1 (mod n)."""
    P = np.asarray(points, dtype=float)
    n = P.shape[0]
    if n < 3:
        raise MeshError(f"{source}: a closed polygon needs at least 3 vertices, got {n}")
    S = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    return Mesh(P, S, source)


def resample_closed_polyline(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced in arc length along the closed polyline through ``points``.

    Parameters
    ----------
    points : (k, m) vertices of the closed polyline (segment k-1 -> 0 closes it)
    n : number of points to return

    Returns
    -------
    (n, m) points on the polyline, the first one at ``points[0]``, in the polyline's order.
    """
    P = np.asarray(points, dtype=float)
    closed = np.vstack([P, P[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    if not s[-1] > 0:
        raise MeshError("cannot resample a closed polyline of zero length")
    t = np.linspace(0.0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(t, s, closed[:, c]) for c in range(P.shape[1])])


def open_curve(points: np.ndarray, source: str = "<curve>") -> Mesh:
    """Open polyline through ``points`` ((n, m) array), segments i -> i+1."""
    P = np.asarray(points, dtype=float)
    n = P.shape[0]
    if n < 2:
        raise MeshError(f"{source}: an open polyline needs at least 2 vertices, got {n}")
    S = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    return Mesh(P, S, source)


def _lengths(shape: str, **lengths: float) -> None:
    """MeshError unless every length is a finite number > 0 (``shape``: the generator's name, for the message)."""
    for name, v in lengths.items():
        if not 0 < v < np.inf:
            raise MeshError(f"{shape}: {name} must be a finite number > 0, got {v!r}")


MAX_VERTICES = 2_000_000
"""Generators refuse a size (a vertex count n, an edge length h to remesh a surface to) that would make more vertices
than this: a negative h hung ``genus2_blending``, a tiny one would fill the memory, and ``--set n=1e9`` on ``circle``
was killed by the kernel's out-of-memory killer (exit 137, the machine's 24 GB taken) before any step (new-user
checks)."""


def vertex_count(shape: str, least: int = 3, **counts: int) -> None:
    """MeshError unless every count (``name=value``) is at least ``least`` and their product at most
    :data:`MAX_VERTICES` (``shape``: the generator's name, for the message)."""
    for name, n in counts.items():
        if n < least:
            raise MeshError(f"{shape}: {name} must be >= {least}, got {n}")
    _at_most(shape, float(np.prod([float(n) for n in counts.values()])),
             " x ".join(f"{k} = {v:,}" for k, v in counts.items()))


def _at_most(shape: str, total: float, what: str) -> None:
    """MeshError when ``what`` (the parameters, for the message) would make ``total`` > :data:`MAX_VERTICES`."""
    if total > MAX_VERTICES:
        raise MeshError(f"{shape}: {what} would make {total:,.0f} vertices, more than {MAX_VERTICES:,}")


def _remesh_size(shape: str, area: float, h: float) -> None:
    """MeshError unless ``h`` is a finite number > 0 giving at most :data:`MAX_VERTICES` vertices on a
    surface of ``area`` (about 2 area / (sqrt(3) h^2) with equilateral triangles)."""
    _lengths(shape, h=h)
    estimate = 2 * area / (np.sqrt(3) * h * h)
    if estimate > MAX_VERTICES:
        least = np.sqrt(2 * area / (np.sqrt(3) * MAX_VERTICES))
        raise MeshError(f"{shape}: h = {h:g} would make about {estimate:,.0f} vertices, more than "
                        f"{MAX_VERTICES:,}; choose h >= {least:.3g}")


def regular_polygon(n: int, radius: float = 1.0, *, m: int = 2, phase: float = 0.0) -> Mesh:
    """Regular n-gon inscribed in the circle of ``radius`` in the plane x3 = 0 of R^m."""
    _lengths("regular_polygon", radius=radius)
    vertex_count("regular_polygon", n=n)
    t = phase + 2 * np.pi * np.arange(n) / n
    P = np.zeros((n, m))
    P[:, 0] = radius * np.cos(t)
    P[:, 1] = radius * np.sin(t)
    return closed_curve(P, f"regular_polygon(n={n})")


def ellipse(n: int, a: float = 2.0, b: float = 1.0, *, m: int = 2) -> Mesh:
    """Ellipse with semi-axes a (x1) and b (x2), n vertices equally spaced in the angle."""
    _lengths("ellipse", a=a, b=b)
    vertex_count("ellipse", n=n)
    t = 2 * np.pi * np.arange(n) / n
    P = np.zeros((n, m))
    P[:, 0] = a * np.cos(t)
    P[:, 1] = b * np.sin(t)
    return closed_curve(P, f"ellipse(n={n}, a={a}, b={b})")


def hypocycloid(n: int, delta: float = 0.0, *, m: int | None = None) -> Mesh:
    """The paper's hypocycloid X0(t) = (-5/2 cos t + 4 cos 5t, -5/2 sin t + 4 sin 5t, delta sin 3t).

    Parameters
    ----------
    n : int
        Number of vertices, equally spaced in t.
    delta : float
        Vertical perturbation; with ``delta == 0`` and ``m`` unset the curve is planar (m = 2).
    m : int, optional
        Ambient dimension; defaults to 3 when ``delta != 0`` and 2 otherwise.
    """
    vertex_count("hypocycloid", n=n)
    if m is None:
        m = 3 if delta != 0 else 2
    if m == 2 and delta != 0:
        raise MeshError("hypocycloid: delta != 0 needs m = 3")
    t = 2 * np.pi * np.arange(n) / n
    P = np.zeros((n, m))
    P[:, 0] = -2.5 * np.cos(t) + 4 * np.cos(5 * t)
    P[:, 1] = -2.5 * np.sin(t) + 4 * np.sin(5 * t)
    if m == 3:
        P[:, 2] = delta * np.sin(3 * t)
    return closed_curve(P, f"hypocycloid(n={n}, delta={delta})")


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Mesh:
    """Icosphere with 10 * 4**subdivisions + 2 vertices (642 for 3, 2562 for 4)."""
    _lengths("icosphere", radius=radius)
    if isinstance(subdivisions, bool) or not float(subdivisions).is_integer() or subdivisions < 0:
        raise MeshError(f"icosphere: subdivisions must be an integer >= 0 (10 * 4^s + 2 vertices), got "
                        f"{subdivisions!r}")  # (trimesh makes the icosahedron of -1: a new-user check)
    _at_most("icosphere", 10.0 * 4.0 ** min(float(subdivisions), 64.0) + 2, f"subdivisions = {subdivisions}")
    s = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=radius)
    return Mesh(np.asarray(s.vertices), np.asarray(s.faces), f"icosphere({subdivisions})")


def torus(R: float = 1.0, r: float = 0.5, n_major: int = 24, n_minor: int = 12) -> Mesh:
    """Torus of revolution about x3 with radii R (tube centre) and r (tube), outward normals.

    A regular (n_major x n_minor) grid in the two angles, each quad split into two triangles.
    """
    _lengths("torus", R=R, r=r)
    if r <= 0 or r >= R:
        raise MeshError(f"torus: need 0 < r < R, got R={R}, r={r}")
    vertex_count("torus", n_major=n_major, n_minor=n_minor)
    u = 2 * np.pi * np.arange(n_major) / n_major
    v = 2 * np.pi * np.arange(n_minor) / n_minor
    U, W = np.meshgrid(u, v, indexing="ij")
    P = np.stack(
        [(R + r * np.cos(W)) * np.cos(U), (R + r * np.cos(W)) * np.sin(U), r * np.sin(W)], axis=-1
    ).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    dd = i * n_minor + (j + 1) % n_minor
    T = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, dd], -1).reshape(-1, 3)])
    return Mesh(P, T, f"torus(R={R}, r={r}, {n_major}x{n_minor})")


def disk(rings: int = 6, radius: float = 1.0) -> Mesh:
    """Flat disk in the plane x3 = 0 of R^3, normal +x3: the centre and ``rings`` concentric
    rings with 6k vertices on ring k (k = 1..rings), Delaunay-triangulated (scipy).

    ``3 rings (rings + 1) + 1`` vertices; nearly equilateral triangles of edge ~ radius / rings.
    """
    from scipy.spatial import Delaunay

    _lengths("disk", radius=radius)
    if rings < 1:
        raise MeshError(f"disk: rings must be >= 1, got {rings}")
    _at_most("disk", 3.0 * rings * (rings + 1.0) + 1, f"rings = {rings:,}")
    pts = [np.zeros((1, 2))]
    for k in range(1, rings + 1):
        t = 2 * np.pi * np.arange(6 * k) / (6 * k)
        pts.append(radius * k / rings * np.stack([np.cos(t), np.sin(t)], axis=1))
    P2 = np.concatenate(pts)
    T = Delaunay(P2).simplices
    a, b, c = P2[T[:, 0]], P2[T[:, 1]], P2[T[:, 2]]
    cw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    T[cw] = T[cw][:, [0, 2, 1]]
    P = np.column_stack([P2, np.zeros(len(P2))])
    return Mesh(P, T, f"disk(rings={rings})")


def cylinder(radius: float = 1.0, length: float = 2.0, n_around: int = 24, n_along: int = 8,
             z0: float = 0.0) -> Mesh:
    """Open cylinder about the x3 axis from x3 = z0 to z0 + length, outward normals.

    A regular (n_along + 1) x n_around grid, each quad split into two triangles.
    """
    _lengths("cylinder", radius=radius, length=length)
    if n_around < 3 or n_along < 1:
        raise MeshError(f"cylinder: need n_around >= 3 and n_along >= 1, got {n_around}, {n_along}")
    _at_most("cylinder", float(n_around) * (n_along + 1.0), f"n_around = {n_around:,} x n_along + 1 = {n_along + 1:,}")
    u = 2 * np.pi * np.arange(n_around) / n_around
    z = z0 + length * np.arange(n_along + 1) / n_along
    Z, U = np.meshgrid(z, u, indexing="ij")
    P = np.stack([radius * np.cos(U), radius * np.sin(U), Z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_along), np.arange(n_around), indexing="ij")
    a = i * n_around + j
    b = i * n_around + (j + 1) % n_around
    c = (i + 1) * n_around + (j + 1) % n_around
    dd = (i + 1) * n_around + j
    T = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, dd], -1).reshape(-1, 3)])
    return Mesh(P, T, f"cylinder(r={radius}, {n_along}x{n_around})")


def spherical_cap(rings: int = 8, angle: float = 45.0, radius: float = 1.0) -> Mesh:
    """Cap of the sphere of ``radius`` around +x3 up to the polar ``angle`` (degrees).

    :func:`disk` mapped to the sphere: ring k of the disk lies on the latitude circle at polar
    angle ``angle * k / rings``, so the cap's boundary and every ring are latitude circles.
    """
    _lengths("spherical_cap", radius=radius)
    if not 0 < angle < 180:
        raise MeshError(f"spherical_cap: angle must be in (0, 180) degrees, got {angle}")
    D = disk(rings, 1.0)
    xy = D.vertices[:, :2]
    th = np.radians(angle) * np.linalg.norm(xy, axis=1)
    phi = np.arctan2(xy[:, 1], xy[:, 0])
    P = radius * np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], axis=1)
    return Mesh(P, D.simplices, f"spherical_cap(rings={rings}, angle={angle})")


@functools.lru_cache(maxsize=8)  # (seconds each; a Mesh is read-only: the same one is returned again)
def genus2(h: float = 0.1, c: float = 0.035, grid: int = 80) -> Mesh:
    """Closed genus-2 surface ("double torus") with mean edge about ``h``, outward normals.

    The level set ``(x^4 - x^2 + y^2)^2 + z^2 = c`` (a thickened lemniscate of Gerono, two holes
    around (+-0.7, 0)) by marching cubes on a ``grid^3`` grid, then isotropic remeshing to edge
    length ``h`` with projection onto it (both from gpytoolbox). The Euler characteristic is
    checked (-2).
    """
    ax = [np.linspace(-1.3, 1.3, grid), np.linspace(-0.8, 0.8, grid), np.linspace(-0.5, 0.5, grid)]

    def lemniscate(P: np.ndarray) -> np.ndarray:
        x, y, z = P.T
        return (x**4 - x**2 + y**2) ** 2 + z**2 - c

    return _genus2_level_set(lemniscate, ax, h, f"genus2(h={h})")


def _genus2_level_set(func: Callable[[np.ndarray], np.ndarray], ax: list[np.ndarray], h: float, name: str) -> Mesh:
    """Genus-2 mesh of the zero set of ``func`` ((n, 3) -> (n,)) sampled on the grid of the three axes ``ax``:
    marching cubes, isotropic remeshing to edge length ``h`` with projection (gpytoolbox), outward orientation,
    and the Euler characteristic checked (-2)."""
    import gpytoolbox

    from willmore_nlp.mesh.topology import euler_characteristic

    n = [len(a) for a in ax]
    G = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3, order="F")  # x fastest
    _lengths(name, h=h)
    V, F = gpytoolbox.marching_cubes(func(G), G, *n)
    V, F = np.asarray(V, float), np.asarray(F, np.int64)
    _remesh_size(name, float(simplex_volumes(V, F).sum()), h)
    V, F = gpytoolbox.remesh_botsch(V, F.astype(np.int32), 20, h, True)
    V, F = np.asarray(V, float), np.asarray(F, np.int64)
    if np.einsum("ij,ij->", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])) < 0:
        F = F[:, ::-1].copy()
    if euler_characteristic(F) != -2:
        raise MeshError(f"{name}: marching cubes gave Euler characteristic {euler_characteristic(F)}, "
                        "not -2 (refine the grid)")
    return Mesh(V, F, name)


def double_torus_function(P: np.ndarray, R: float = 1.0, r: float = 0.5, d: float = 1.25,
                          blend: float = 0.25) -> np.ndarray:
    """(n,) implicit function of :func:`double_torus` at the points ``P`` (n, 3): negative inside.

    The smooth minimum -blend log(exp(-s1/blend) + exp(-s2/blend)) of the signed distances
    s_i = sqrt((sqrt((x -+ d)^2 + y^2) - R)^2 + z^2) - r of the two tori centred at (+-d, 0, 0).
    """
    x, y, z = np.asarray(P, float).T
    s = [np.hypot(np.hypot(x - c, y) - R, z) - r for c in (d, -d)]
    m = np.minimum(*s)
    return m - blend * np.log(np.exp(-(s[0] - m) / blend) + np.exp(-(s[1] - m) / blend))


@functools.lru_cache(maxsize=8)  # (3 s at h = 0.2: a session trying the blending's fills meshes it once)
def double_torus(R: float = 1.0, r: float = 0.5, d: float = 1.25, h: float = 0.2, blend: float = 0.25,
                 grid: int = 96) -> Mesh:
    """Closed genus-2 surface: two tori (R, r) about x3 centred at (+-d, 0, 0), joined smoothly.

    The zero set of :func:`double_torus_function` (a C^infinity smooth minimum of the two tori's
    signed distances, so the junction has no crease), by marching cubes on a ``grid^3`` grid and
    isotropic remeshing to edge length ``h`` with projection onto it (gpytoolbox), as :func:`genus2`.
    Unlike :func:`genus2`, whose thin rims (|H| = |k1 + k2| up to 18.6 at the lemniscate's tips, h |H|
    = 1.9 at h = 0.1) are not resolved by its mesh, every tube here has radius ``r``, so the curvature
    is resolved once ``h`` is a fraction of ``r`` (h |H| <= 0.66 at h = 0.2). The Euler
    characteristic is checked (-2); needs d < R + r (the tubes overlap) and d > R - r (two holes).
    """
    if not (0 < r < R and R - r < d < R + r and blend > 0):
        raise MeshError(f"double_torus: need 0 < r < R, R - r < d < R + r, blend > 0; got R={R}, r={r}, d={d}, "
                        f"blend={blend}")
    e = d + R + r + 2 * blend + 2 * h
    f = r + 2 * blend + 2 * h
    ax = [np.linspace(-e, e, grid), np.linspace(-(R + f), R + f, grid), np.linspace(-f, f, grid)]
    return _genus2_level_set(lambda P: double_torus_function(P, R, r, d, blend), ax, h,
                             f"double_torus(R={R}, r={r}, d={d}, h={h})")


LAWSON_GENUS2_DATA = Path(__file__).parent / "data" / "lawson_genus2.npz"
"""Stored surface of :func:`lawson_genus2` (made by ``reports/mesh_quality_study.py --lawson-start``)."""


def lawson_genus2(h: float | None = None) -> Mesh:
    """Closed genus-2 surface near a Moebius image of Lawson's minimal surface xi_{2,1} (the conjectured
    minimiser of the Willmore energy among genus-2 surfaces), in an image whose curvature the mesh resolves.

    The stored surface (1,288 v, mean edge 0.20, |k1 + k2| h <= 0.53; :data:`LAWSON_GENUS2_DATA`) is returned
    as it is (``h`` None) or remeshed isotropically to edge length ``h`` with projection onto it
    (:func:`willmore_nlp.remesh.isotropic_remesh`). How it was made (``reports/mesh_quality_study.py
    --lawson-start``, docs/guide/mesh_quality_measurements.md "Genus 2"): the flow of :func:`double_torus` approaches
    a stereographic image of a minimal surface in S^3 (:func:`willmore_nlp.analysis.minimal_s3_fit`:
    residual 0.68 -> 0.11) whose bar across the hole is thinner than the mesh's edges; that state was lifted
    to S^3 with the fitted centre and radius and projected back from the point of S^3 farthest from it
    (:func:`willmore_nlp.geometry.stereographic_reprojection`; the Willmore energy is Moebius invariant),
    remeshed to h = 0.2 and flowed 5 steps with ``conformal_gauge``: W = 43.48 (Lawson: 43.8 in this
    library's normalisation), minimal-S^3 residual 0.039.
    """
    from willmore_nlp.remesh import isotropic_remesh

    with np.load(LAWSON_GENUS2_DATA) as z:
        V, F = np.asarray(z["vertices"], float), np.asarray(z["simplices"], np.int64)
    if h is None:
        return Mesh(V, F, "lawson_genus2()")
    _remesh_size("lawson_genus2", float(simplex_volumes(V, F).sum()), h)
    r = isotropic_remesh(V, F, float(h), smooth=False)  # on the stored polyhedron: the cached studies' starts
    return Mesh(r.vertices, r.simplices, f"lawson_genus2(h={h})")


def spheroid_area_volume(a: float, c: float) -> tuple[float, float]:
    """Area and volume of the smooth spheroid with equatorial semi-axis ``a`` and polar semi-axis ``c``.

    Closed forms: V = 4/3 pi a^2 c; A = 2 pi a^2 (1 + c/(a e) arcsin e), e^2 = 1 - a^2/c^2, for
    c > a (prolate) and A = 2 pi a^2 (1 + (1 - e^2)/e artanh e), e^2 = 1 - c^2/a^2, for c < a
    (oblate); 4 pi a^2 for the sphere.
    """
    if a <= 0 or c <= 0:
        raise MeshError(f"spheroid: semi-axes must be positive, got a={a}, c={c}")
    V = 4.0 / 3.0 * np.pi * a * a * c
    if np.isclose(a, c, rtol=1e-12, atol=0.0):
        return 4.0 * np.pi * a * a, V
    if c > a:
        e = np.sqrt(1.0 - (a / c) ** 2)
        return float(2 * np.pi * a * a * (1 + c / (a * e) * np.arcsin(e))), V
    e = np.sqrt(1.0 - (c / a) ** 2)
    return float(2 * np.pi * a * a * (1 + (1 - e * e) / e * np.arctanh(e))), V


def reduced_volume(area: float, volume: float) -> float:
    """v = 6 sqrt(pi) V / A^(3/2): 1 for a sphere, < 1 for every other closed surface."""
    return float(6.0 * np.sqrt(np.pi) * volume / area**1.5)


def _spheroid_ratio(v: float, kind: str) -> float:
    """Aspect ratio c/a of the smooth spheroid of reduced volume ``v`` (bisection on the log ratio)."""
    from scipy.optimize import brentq

    def f(t: float) -> float:
        return reduced_volume(*spheroid_area_volume(1.0, float(np.exp(t)))) - v

    t = brentq(f, 0.0, 12.0, xtol=1e-15) if kind == "prolate" else brentq(f, -12.0, 0.0, xtol=1e-15)
    return float(np.exp(t))


def ellipsoid_of_reduced_volume(v: float, kind: str = "prolate", subdivisions: int = 3, *,
                                area: float | None = None, volume: float | None = None,
                                exact: str = "smooth") -> Mesh:
    """Icosphere mapped onto a spheroid (semi-axes a = b, c about x3) of reduced volume ``v``.

    Parameters
    ----------
    v : float
        Reduced volume 6 sqrt(pi) V / A^(3/2), in (0, 1] (1 gives a sphere).
    kind : ``"prolate"`` (c > a) or ``"oblate"`` (c < a)
    subdivisions : icosphere level (642 vertices for 3, 2,562 for 4)
    area, volume : float, optional
        Normalisation, at most one: the surface's area or its enclosed volume (of the smooth spheroid
        with ``exact="smooth"``, of the polyhedron with ``exact="mesh"``). Default: area 4 pi.
    exact : ``"smooth"`` or ``"mesh"``
        ``"smooth"``: c/a from the closed-form area of the smooth spheroid, vertices on it; the
        inscribed polyhedron's own v is then smaller than ``v`` by O(h^2): measured 8.1e-4 to
        1.3e-3 at 642 vertices and 2.0e-4 to 3.2e-4 at 2,562 for v in [0.55, 0.85], both kinds.
        ``"mesh"``: c/a found by a 1-D root
        find so that the polyhedron's discrete V and A (those a constrained flow keeps) give ``v``
        to 1e-12.

    Returns
    -------
    Mesh with outward normals, vertices on the spheroid x^2/a^2 + y^2/a^2 + z^2/c^2 = 1 (times the
    normalisation factor).
    """
    from scipy.optimize import brentq

    if kind not in ("prolate", "oblate"):
        raise MeshError(f"ellipsoid_of_reduced_volume: kind must be 'prolate' or 'oblate', got {kind!r}")
    if not 0 < v <= 1:
        raise MeshError(f"ellipsoid_of_reduced_volume: reduced volume must be in (0, 1], got {v}")
    if area is not None and volume is not None:
        raise MeshError("ellipsoid_of_reduced_volume: give area or volume, not both")
    if exact not in ("smooth", "mesh"):
        raise MeshError(f"ellipsoid_of_reduced_volume: exact must be 'smooth' or 'mesh', got {exact!r}")
    U = icosphere(subdivisions).vertices

    def mesh_av(ratio: float) -> tuple[float, float]:
        from willmore_nlp.geometry import enclosed_volume, measure

        M = Mesh(U * [1.0, 1.0, ratio], icosphere(subdivisions).simplices, "spheroid")
        return measure(M), enclosed_volume(M)

    if v == 1:
        ratio = 1.0
    elif exact == "smooth":
        ratio = _spheroid_ratio(v, kind)
    else:
        v_max = reduced_volume(*mesh_av(1.0))
        if v >= v_max:
            raise MeshError(f"ellipsoid_of_reduced_volume: exact='mesh' needs v below the icosphere's own "
                            f"{v_max:.6f} at subdivisions={subdivisions}, got {v}")

        def g(t: float) -> float:
            return reduced_volume(*mesh_av(float(np.exp(t)))) - v

        try:  # (v = 0.01 prolate: c/a near 9,000, where the spheroid's closed form and the mesh's V and A fail)
            guess = np.log(_spheroid_ratio(v, kind))
            lo, hi = (0.0, 2 * guess) if kind == "prolate" else (2 * guess, 0.0)
            ratio = float(np.exp(brentq(g, lo, hi, xtol=1e-14)))
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            raise MeshError(f"ellipsoid_of_reduced_volume: no {kind} spheroid of reduced volume {v} found on this "
                            f"mesh (its axis ratio would be extreme; {exc})") from None
    A1, V1 = spheroid_area_volume(1.0, ratio) if exact == "smooth" else mesh_av(ratio)
    s = (volume / V1) ** (1.0 / 3.0) if volume is not None else np.sqrt((4 * np.pi if area is None else area) / A1)
    return Mesh(s * U * [1.0, 1.0, ratio], icosphere(subdivisions).simplices,
                f"{kind} spheroid(v={v}, c/a={ratio:.6g}, {exact}, {U.shape[0]} vertices)")


def _bent(ico: Mesh, ratio: float, bend: float) -> Mesh:
    """The unit icosphere ``ico``'s vertices (x, y, z) moved to (x, y, ratio z + bend (x^2 + y^2)): a cup."""
    U = ico.vertices
    return Mesh(np.column_stack([U[:, 0], U[:, 1], ratio * U[:, 2] + bend * (U[:, 0] ** 2 + U[:, 1] ** 2)]),
                ico.simplices, "cup")


def cup_max_reduced_volume(subdivisions: int = 3, bend: float = 0.6) -> float:
    """The supremum of the reduced volumes :func:`cup_of_reduced_volume` builds at ``subdivisions`` and ``bend``: that
    of the bent sphere (aspect ratio 1)."""
    from willmore_nlp.geometry import enclosed_volume, measure

    M = _bent(icosphere(subdivisions), 1.0, bend)
    return reduced_volume(measure(M), enclosed_volume(M))


def cup_of_reduced_volume(v: float, subdivisions: int = 3, bend: float = 0.6, *, area: float | None = None) -> Mesh:
    """An oblate spheroid bent into a cup, with the polyhedron's reduced volume exactly ``v``.

    The icosphere's unit vertices (x, y, z) go to (x, y, r z + bend (x^2 + y^2)): an oblate spheroid of
    aspect ratio r (equatorial radius 1) sheared along x3 into a bowl that opens towards +x3. The shear
    keeps the enclosed volume and adds area, so it breaks the up-down symmetry of the oblate start
    (which the flow keeps, and with it the discocyte branch) without leaving the family of
    surfaces of revolution. r is found by a 1-D root find so that the polyhedron's discrete V and A
    (those a constrained flow keeps) give ``v`` to 1e-12; the surface is then scaled to ``area``.

    Parameters
    ----------
    v : float
        Reduced volume 6 sqrt(pi) V / A^(3/2) in (0, 1); must lie below the v of the bent sphere (r = 1).
    subdivisions : icosphere level (642 vertices for 3, 2,562 for 4)
    bend : float
        Shear coefficient b >= 0 (0: the oblate spheroid of ``ellipsoid_of_reduced_volume(..., exact="mesh")``).
    area : float, optional
        Total area of the result (default 4 pi).

    Returns
    -------
    Mesh with outward normals and the icosphere's connectivity.
    """
    from scipy.optimize import brentq

    from willmore_nlp.geometry import enclosed_volume, measure

    if not bend >= 0:
        raise MeshError(f"cup_of_reduced_volume: bend must be >= 0, got {bend}")
    ico = icosphere(subdivisions)

    def v_of(t: float) -> float:
        M = _bent(ico, float(np.exp(t)), bend)
        return reduced_volume(measure(M), enclosed_volume(M))

    v_max = v_of(0.0)  # the bent sphere: cup_max_reduced_volume
    if not 0 < v < v_max:
        raise MeshError(f"cup_of_reduced_volume: v must be in (0, {v_max:.6f}) for bend={bend} at "
                        f"subdivisions={subdivisions}, got {v}")
    try:  # (v = 1e-9: below the bracket's flattest cup, r = e^-12; brentq's ValueError was a traceback)
        ratio = float(np.exp(brentq(lambda t: v_of(t) - v, -12.0, 0.0, xtol=1e-14)))
    except (ValueError, ArithmeticError) as exc:
        raise MeshError(f"cup_of_reduced_volume: no cup of reduced volume {v} found for bend={bend} at "
                        f"subdivisions={subdivisions} (its aspect ratio would be extreme; {exc})") from None
    M = _bent(ico, ratio, bend)
    s = np.sqrt((4 * np.pi if area is None else area) / measure(M))
    return Mesh(s * M.vertices, ico.simplices,
                f"cup(v={v}, c/a={ratio:.6g}, bend={bend}, {ico.n_vertices} vertices)")
