"""Anisotropic Willmore flow (paper Sec. 5.3, Fig. 11) and a surface example beyond the paper."""

from __future__ import annotations

import numpy as np

from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.registry import Problem, register

BUNNY_H = 0.00865
"""Initial mean edge length of the paper's Fig. 11 bunny (436 nodes)."""

HELD = {"anisotropy": "gamma"}
"""The flow option these problems set from their parameter ``gamma`` (:attr:`~willmore_nlp.registry.Problem.held`:
``bunny --set gamma=gamma0 --set anisotropy=gamma2`` ran gamma2 with the weight 1 and no redistribution that the
bunny gives gamma0, failed its first step, and its config.json recorded gamma0: a new-user check)."""


def bunny_curve(n: int = 436, h: float = BUNNY_H) -> Mesh:
    """A bunny-shaped closed curve in R^2 (own silhouette): body, head, two ears, tail and feet.

    The outline is star-shaped, r(theta) = ellipse body + Gaussian bumps, counter-clockwise,
    resampled to ``n`` nodes equally spaced in arc length and scaled to mean edge ``h`` (the
    paper's 436 nodes with h = 0.00865 give a perimeter of 3.77).

    Returns
    -------
    Mesh with n vertices, (n, 2) positions.
    """
    shapes.vertex_count("bunny_curve", n=n)
    th = np.linspace(0.0, 2 * np.pi, 4000, endpoint=False)
    r = 1.0 / np.sqrt((np.cos(th) / 0.55) ** 2 + (np.sin(th) / 0.38) ** 2)

    def bump(center_deg: float, width: float, amp: float) -> np.ndarray:
        d = np.angle(np.exp(1j * (th - np.radians(center_deg))))
        return amp * np.exp(-0.5 * (d / width) ** 2)

    r = (r + bump(35, 0.35, 0.20)  # head
         + bump(58, 0.11, 0.30) + bump(82, 0.11, 0.28)  # ears
         + bump(180, 0.25, 0.08)  # tail
         + bump(245, 0.18, 0.04) + bump(300, 0.18, 0.04))  # feet
    P = np.column_stack([r * np.cos(th), r * np.sin(th)])
    Q = shapes.resample_closed_polyline(P, n)
    Q -= Q.mean(axis=0)
    Q *= n * h / np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).sum()  # the dense outline's length
    return shapes.closed_curve(Q, "bunny")


@register("bunny")
def bunny(gamma: str = "gamma1", n: int = 436, h: float = 0.05, tau: float | None = None,
          tau_tilde: float | None = None, lam: float = 0.025, steps: int = 600,
          tangential_weight: float | None = None, redistribute: bool | None = None) -> Problem:
    """Bunny-shaped curve under anisotropic Willmore flow (Fig. 11).

    ``gamma``: gamma0 (isotropic, tends to a circle), gamma1 (sqrt(z1^2 + 4 z2^2): an ellipse-like
    shape elongated along x2; Wulff shape x1^2 + x2^2/4 <= 1) or gamma2:EPS (regularised l1 norm:
    a square with rounded corners). Defaults: 436 nodes, tau = h, lam = 0.025 as in the paper, but
    the curve is scaled to h = 0.05 (about 6.6 wide) and tau_tilde = h^2 / 10, which runs at tau = h
    from the first step. At the paper's scale (``h=0.00865 tau_tilde=7.5e-5``) the first steps need
    tau far below h; run it with the flow options ``adaptive=true max_retries=16``
    (docs/guide/anisotropy.md). Fig. 11's third row runs as
    ``gamma=gamma2:1e-2`` (with redistribution) or ``gamma=gamma2:0.1`` (without): the paper's
    eps = 1e-7 (``gamma2``) clusters the nodes within the first step. For gamma2 the defaults are
    ``tangential_weight`` (beta of the distance term) = 1000, since nodes otherwise slide into
    clusters, and ``redistribute`` (equal arc-length spacing after every step) = True; for the other
    anisotropies 1 and False, the paper's scheme. The anisotropy is ``gamma``'s: the flow option ``anisotropy`` is
    refused (``gamma=gamma0 anisotropy=gamma2`` ran gamma2 without its tangential weight and redistribution).
    """
    mesh = bunny_curve(n, h)
    h_ = mesh.h
    crystal = gamma.startswith("gamma2")
    if tangential_weight is None:
        tangential_weight = 1000.0 if crystal else 1.0
    if redistribute is None:
        redistribute = crystal
    return Problem(mesh, h_ if tau is None else float(tau), 0.1 * h_ * h_ if tau_tilde is None else float(tau_tilde),
                   lam, steps=steps, flow_options={"anisotropy": gamma, "tangential_weight": float(tangential_weight),
                                                   "redistribute": bool(redistribute)},
                   description="bunny curve under anisotropic Willmore flow (Fig. 11)", held=HELD)


@register("anisotropic_sphere")
def anisotropic_sphere(gamma: str = "gamma1", subdivisions: int = 2, radius: float = 3.0, tau: float | None = None,
                       tau_tilde: float | None = None, lam: float = 0.0, steps: int = 12) -> Problem:
    """Icosphere under anisotropic Willmore flow (beyond the paper: a closed surface in R^3).

    With gamma1 = sqrt(z1^2 + 4 z2^2 + z3^2) the Wulff shape is the ellipsoid
    x1^2 + x2^2/4 + x3^2 <= 1 and the sphere stretches along x2 towards that axis ratio 2.
    Defaults: 162 vertices, radius 3, tau = h, tau_tilde = h^2 / 100, lam = 0, and the flow's mesh control. At
    rest (t = 67) x2/x1 is 2.21 / 2.004 / 1.999 and w_gamma 4.98 / 1.23 / 0.33 % below the Wulff shapes' 42.96 on
    162 / 642 / 2,562 vertices (order 1.96), every angle >= 42 deg (reports/wulff_study.md); without the mesh
    control the 162-vertex mesh collapses (0.5 deg) and its step fails at t = 56. The anisotropy is ``gamma``'s (the
    flow option ``anisotropy`` is refused).
    """
    mesh = shapes.icosphere(subdivisions, radius)
    h = mesh.h
    return Problem(mesh, h if tau is None else float(tau), 0.01 * h * h if tau_tilde is None else float(tau_tilde),
                   lam, steps=steps, flow_options={"anisotropy": gamma},
                   description="sphere under anisotropic Willmore flow (surface, beyond the paper)", held=HELD)
