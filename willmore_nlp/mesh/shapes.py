"""Shape generators: the paper's initial curves and surfaces.

Every generator returns a validated :class:`~willmore_nlp.mesh.core.Mesh` with a
consistently oriented parametrisation (curves counter-clockwise, surfaces with outward
normals for the sphere and torus).
"""

from __future__ import annotations

import numpy as np
import trimesh

from willmore_nlp.mesh.core import Mesh, MeshError


def closed_curve(points: np.ndarray, source: str = "<curve>") -> Mesh:
    """Closed polygon through ``points`` ((n, m) array), segments i -> i+1 (mod n)."""
    P = np.asarray(points, dtype=float)
    n = P.shape[0]
    if n < 3:
        raise MeshError(f"{source}: a closed polygon needs at least 3 vertices, got {n}")
    S = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    return Mesh(P, S, source)


def open_curve(points: np.ndarray, source: str = "<curve>") -> Mesh:
    """Open polyline through ``points`` ((n, m) array), segments i -> i+1."""
    P = np.asarray(points, dtype=float)
    n = P.shape[0]
    if n < 2:
        raise MeshError(f"{source}: an open polyline needs at least 2 vertices, got {n}")
    S = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    return Mesh(P, S, source)


def regular_polygon(n: int, radius: float = 1.0, *, m: int = 2, phase: float = 0.0) -> Mesh:
    """Regular n-gon inscribed in the circle of ``radius`` in the plane x3 = 0 of R^m."""
    if n < 3:
        raise MeshError(f"regular_polygon: n must be >= 3, got {n}")
    t = phase + 2 * np.pi * np.arange(n) / n
    P = np.zeros((n, m))
    P[:, 0] = radius * np.cos(t)
    P[:, 1] = radius * np.sin(t)
    return closed_curve(P, f"regular_polygon(n={n})")


def ellipse(n: int, a: float = 2.0, b: float = 1.0, *, m: int = 2) -> Mesh:
    """Ellipse with semi-axes a (x1) and b (x2), n vertices equally spaced in the angle."""
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
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(np.asarray(s.vertices), np.asarray(s.faces), f"icosphere({subdivisions})")


def torus(R: float = 1.0, r: float = 0.5, n_major: int = 24, n_minor: int = 12) -> Mesh:
    """Torus of revolution about x3 with radii R (tube centre) and r (tube), outward normals.

    A regular (n_major x n_minor) grid in the two angles, each quad split into two triangles.
    """
    if r <= 0 or r >= R:
        raise MeshError(f"torus: need 0 < r < R, got R={R}, r={r}")
    if n_major < 3 or n_minor < 3:
        raise MeshError(f"torus: n_major and n_minor must be >= 3, got {n_major}, {n_minor}")
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
