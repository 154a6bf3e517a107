"""Tutorial: anisotropic Willmore flow of a curve toward its Wulff shape.

With gamma1(z) = sqrt(z1^2 + 4 z2^2) the Wulff shape is an ellipse twice as wide along x2 as along x1.
A circle flowed with this anisotropy (and a small length energy lam) stretches toward that ratio.
Run with ``python docs/tutorials/anisotropy.py``.
"""

from willmore_nlp import WillmoreFlow
from willmore_nlp.analysis import axis_widths, wulff_widths
from willmore_nlp.mesh import shapes


def main(n: int = 64, steps: int = 60) -> dict[str, float]:
    mesh = shapes.regular_polygon(n, radius=1.5)
    flow = WillmoreFlow(mesh, mesh.h, mesh.h**2 / 10, lam=0.05, anisotropy="gamma1")
    results = flow.run(steps=steps)
    w = axis_widths(flow.X)              # widths along x1, x2, and the two diagonals
    wulff = wulff_widths("gamma1")       # the Wulff shape's widths 2 gamma(n)
    ratio, target = w[1] / w[0], wulff[1] / wulff[0]
    print(f"after {steps} steps (t = {results[-1].t:.3g}): width ratio x2/x1 = {ratio:.3f}, "
          f"Wulff shape {target:.3f}; anisotropic Willmore energy {results[-1].willmore_gamma:.4f}; "
          f"edge ratio {results[-1].quality['edge_ratio']:.2f}")
    return {"ratio": ratio, "target": target,
            "energies": [r.energy for r in results]}


if __name__ == "__main__":
    main()
