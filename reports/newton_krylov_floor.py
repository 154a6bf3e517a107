"""Where a newton-krylov step's time goes, and its floor against IPOPT (issue 15).

    OMP_NUM_THREADS=1 nice python reports/newton_krylov_floor.py 5 6   # icosphere subdivisions

One process per sphere of the scale benchmark (``willmore_nlp.bench``'s sphere case: icosphere scaled
1:1:1.3, tau = 0.2 h, tt = h^2 / 100), back to back so that both solvers see the same machine load: IPOPT's
two steps, newton-krylov's two steps, then the unit costs of newton-krylov's operations at its last point
(best of 2-5 repetitions): a feasible point (Y[X] with one factorisation of M + tt L, W^, the adjoint
gradient: what a line-search trial costs), the distance Hessian D, the Lagrangian Hessian, one build of the
preconditioner B (assembly + CHOLMOD factorisation), one solve with B and one reduced Hessian-vector
product. The floor of a step is its cost with IPOPT's own iteration count: n Hessians, n + 1 feasible
points, D, 5 CG iterations per Newton iteration and one build of B. Prints one markdown row per sphere.
"""

from __future__ import annotations

import argparse
import gc
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from willmore_nlp import WillmoreFlow
from willmore_nlp.apps.bench import _mesh

CG_PER_NEWTON = 5
"""CG iterations per Newton iteration assumed by the floor (step 2 of the benchmark spheres: 5-6)."""


def _best(fn: Callable[[], Any], n: int) -> tuple[float, Any]:
    """Smallest wall time of ``n`` calls of ``fn`` and its last result."""
    times, out = [], None
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def measure(sub: int) -> dict[str, float]:
    """IPOPT's and newton-krylov's two steps and newton-krylov's unit costs on ``icosphere(sub)``."""
    mesh = _mesh(f"sphere:{sub}")
    args = (mesh, 0.2 * mesh.h, mesh.h**2 / 100)
    row: dict[str, float] = {"N": mesh.n_vertices, "load": os.getloadavg()[0]}
    ipopt = WillmoreFlow(*args, mesh_control="off")
    for k in (1, 2):
        r = ipopt.step()
        row[f"ip{k}"], row[f"ip_it{k}"] = r.wall_time, r.iterations
    del ipopt
    gc.collect()
    nk = WillmoreFlow(*args, solver="newton-krylov", mesh_control="off")
    for k in (1, 2):
        r = nk.step()
        row[f"nk{k}"], row[f"nk_it{k}"] = r.wall_time, r.iterations
        row[f"cg{k}"], row[f"B{k}"] = r.stats["n_cg"], r.stats["n_precond_builds"]
    s = nk.solver
    P = s.P
    p = nk.params(nk.X, nk.tau)
    z0 = P.pack_z(nk.X, nk.Y)
    row["point"], pt = _best(lambda: s._feasible(np.asarray(z0[: s.nxm], float), p, nk.Y), 3)
    row["D"], D = _best(lambda: s._distance_hessian(pt.z, p), 3)
    row["hess"], pt.H = _best(lambda: s.ev.hess_lag_operator(pt.z, p, 1.0, pt.lam), 3)
    row["B"], _ = _best(lambda: s._build_preconditioner(pt, p, D), 2)
    v = np.random.default_rng(0).standard_normal(s.nxm)
    row["Bsolve"], _ = _best(lambda: s._pre.solve(v), 5)
    row["hessp"], _ = _best(lambda: s._hessp(pt, p, v), 5)
    row["load_end"] = os.getloadavg()[0]
    for k in (1, 2):
        n = row[f"ip_it{k}"]
        row[f"floor{k}"] = (n * row["hess"] + (n + 1) * row["point"] + row["D"] + row["B"]
                            + CG_PER_NEWTON * n * (row["Bsolve"] + row["hessp"]))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("subdivisions", type=int, nargs="+")
    a = ap.parse_args()
    print("| N | load | IPOPT step 1 / 2 [s] (it) | newton-krylov step 1 / 2 [s] | speed-up 1 / 2 | Newton it | CG it "
          "| B builds | point [s] | D [s] | Hessian [s] | B build [s] | B solve [ms] | Hv [ms] | floor 1 / 2 [s] "
          "| speed-up at the floor 1 / 2 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for sub in a.subdivisions:
        r = measure(sub)
        print(f"| {r['N']:,} | {r['load']:.1f}-{r['load_end']:.1f} | {r['ip1']:.3g} / {r['ip2']:.3g} "
              f"({r['ip_it1']} / {r['ip_it2']}) | {r['nk1']:.3g} / {r['nk2']:.3g} "
              f"| {r['ip1'] / r['nk1']:.2f}x / {r['ip2'] / r['nk2']:.2f}x | {r['nk_it1']} / {r['nk_it2']} "
              f"| {r['cg1']} / {r['cg2']} | {r['B1']} / {r['B2']} | {r['point']:.3g} | {r['D']:.3g} "
              f"| {r['hess']:.3g} | {r['B']:.3g} | {r['Bsolve'] * 1e3:.3g} | {r['hessp'] * 1e3:.3g} "
              f"| {r['floor1']:.3g} / {r['floor2']:.3g} "
              f"| {r['ip1'] / r['floor1']:.1f}x / {r['ip2'] / r['floor2']:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
