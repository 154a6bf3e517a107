"""Tutorial: Willmore flow of a closed curve, checked against the exact expanding circle.

A circle of radius R0 is not stationary for Willmore flow: it expands as R(t) = (R0^4 + 2 t)^(1/4).
Run with ``python docs/tutorials/closed_curve.py``.
"""

import numpy as np

from willmore_nlp import WillmoreFlow, willmore_energy
from willmore_nlp.mesh import shapes


def main(n: int = 128, t_end: float = 0.1, tau: float | None = None) -> dict[str, float]:
    mesh = shapes.regular_polygon(n, radius=1.0)       # a closed polygon in R^2
    h = mesh.h                                         # mean edge length
    tau = h / 10 if tau is None else tau                # the outer step; the error is O(h^2 + tau + tau_tilde)
    flow = WillmoreFlow(mesh, tau=tau, tau_tilde=h**2 / 10, lam=0.0)      # keep tau_tilde << h^2
    print(f"n = {n}, h = {h:.4f}, initial Willmore energy {willmore_energy(mesh):.5f} (pi = {np.pi:.5f})")
    energies = []
    for r in flow.run(t_end=t_end):                    # one StepResult per accepted step
        energies.append(r.energy)
    radius = float(np.linalg.norm(flow.X, axis=1).mean())
    exact = (1.0 + 2 * t_end) ** 0.25
    print(f"t = {t_end}: mean radius {radius:.6f}, exact {exact:.6f}, error {abs(radius - exact):.2e}")
    print(f"scheme energy after step 1 {energies[0]:.5f} -> after the last {energies[-1]:.5f}; "
          f"pi / R(t) = {np.pi / exact:.5f}")
    return {"h": h, "error": abs(radius - exact), "energy_drop": energies[0] - energies[-1],
            "monotone": bool(np.all(np.diff(energies) <= 0))}


if __name__ == "__main__":
    main()
