"""The vesicle problem's ``tangential_weight`` 1, 10, 100 on its three 642-vertex starts (issue 16).

    OMP_NUM_THREADS=1 nice python reports/vesicle_weight_study.py [--jobs 3] [--cache DIR]
    # writes reports/vesicle_weight_study.md

Each run is the registered ``vesicle`` problem with its defaults (subdivisions 3 = 642 vertices) and only
``tangential_weight`` changed, stepped a fixed number of times :data:`STEPS` (the relaxation's stopping test
is ignored: every run takes the same number of steps): the prolate v = 0.85 start relaxed in 12 steps, the
oblate v = 0.65 start in 72 and the cup v = 0.55 (0.50) took 156 (154) steps to t = 0.3 with weight 1
(reports/vesicle_evolver.md). Per run: the final Willmore energy w / 8 pi, the energy the last step reached
before the light mesh repair (history ``willmore_before_remesh``) and the repair's lift, the relative change
of the recorded energy per step at the end, the constraint errors of V and A, retries, IPOPT iterations per
step, the smallest angle, the wall time and the gap to the axisymmetric reference (:data:`REFERENCE`).

``--cache DIR``: one pickle per run, read if present (reruns only what is missing).
"""

from __future__ import annotations

import argparse
import pickle
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.flow import FlowError
from willmore_nlp.geometry import enclosed_volume, measure, quality
from willmore_nlp.registry import build

OUT = Path(__file__).resolve().parent
WEIGHTS = (1.0, 10.0, 100.0)
CASES = (("prolate", 0.85), ("oblate", 0.65), ("cup", 0.55), ("oblate", 0.55), ("cup", 0.50))
"""(start, v); the oblate start at v = 0.55 (discocyte) and the cup at v = 0.50 are second checks."""
STEPS = {"prolate": 30, "oblate": 90, "cup": 160}
"""Fixed step counts (weight 1 came to rest in 12, 72 and 156 steps in reports/vesicle_evolver.md)."""
REFERENCE = {("prolate", 0.85): 1.285676, ("oblate", 0.65): 1.826233, ("cup", 0.55): 1.983834,
             ("oblate", 0.55): 2.087298, ("cup", 0.50): 1.988308}
"""Extrapolated axisymmetric reference w / 8 pi (reports/vesicle_evolver.md, n = 200 and 400 contour
segments; :mod:`willmore_nlp.vesicle_reference`): prolate v = 0.85, discocyte v = 0.65 and 0.55, stomatocyte
v = 0.55 and 0.50."""
TAIL = 5
"""Steps at the end over which the lift and the per-step change are summarised."""


def run(start: str, v: float, weight: float) -> dict[str, Any]:
    """Step the vesicle problem ``STEPS[start]`` times with ``tangential_weight = weight``."""
    pb, _ = build("vesicle", reduced_volume=v, start=start, subdivisions=3, tangential_weight=weight)
    V0, A0 = enclosed_volume(pb.mesh), measure(pb.mesh)
    flow = pb.make_flow(relax_newton=False)  # (time steps, as the cached table ran: STEPS of them per start)
    t0 = time.time()
    res, error = [], ""
    try:
        for _ in range(STEPS[start]):
            res.append(flow.step())
    except FlowError as exc:  # recorded in the table, the other runs go on
        error = str(exc).split(";")[0]
    wall = time.time() - t0
    after = np.array([r.willmore for r in res]) / (8 * np.pi)
    before = np.array([r.stats.get("willmore_before_remesh", r.willmore) for r in res]) / (8 * np.pi)
    M = flow.mesh.with_vertices(flow.X)
    return {"start": start, "v": v, "weight": weight, "steps": len(res), "t": flow.t, "error": error, "wall": wall,
            "after": after, "before": before, "n": M.n_vertices,
            "retries": sum(r.retries for r in res),
            "iterations": sum(r.iterations for r in res),
            "rejected_iterations": sum(r.stats.get("rejected_iterations", 0) for r in res),
            "dV": max((abs(r.volume / V0 - 1) for r in res), default=0.0),
            "dA": max((abs(r.measure / A0 - 1) for r in res), default=0.0),
            "min_angle": min((r.quality["min_angle"] for r in res), default=float("nan")),
            "final_angle": quality(M)["min_angle"],
            "taus": np.array([r.tau for r in res])}


def _run(args: tuple[str, float, float, Path | None]) -> dict[str, Any]:
    start, v, weight, cache = args
    path = None if cache is None else cache / f"{start}_{v}_{weight:g}.pkl"
    if path is not None and path.exists():
        return pickle.loads(path.read_bytes())
    out = run(start, v, weight)
    print(f"{start} v={v} weight {weight:g}: {out['steps']} steps, {out['wall']:.0f} s {out['error']}", flush=True)
    if path is not None:
        path.write_bytes(pickle.dumps(out))
    return out


def summary(r: dict[str, Any]) -> dict[str, float]:
    """Tail figures of one run: lift (after / before repair - 1), per-step relative change of the recorded
    and of the before-repair energy (largest over the last :data:`TAIL` steps)."""
    a, b = r["after"], r["before"]
    lift = a[-TAIL:] / b[-TAIL:] - 1
    change = (np.abs(np.diff(a)) / a[1:])[-TAIL:]
    change_b = (np.abs(np.diff(b)) / b[1:])[-TAIL:]
    return {"lift_last": lift[-1], "lift_max": lift.max(), "change_last": change[-1], "change_max": change.max(),
            "change_b_max": change_b.max(), "gap": a[-1] / REFERENCE[r["start"], r["v"]] - 1,
            "gap_before": b[-1] / REFERENCE[r["start"], r["v"]] - 1}


def markdown(runs: list[dict[str, Any]], wall: float) -> str:
    lines = [
        "# The vesicle problem's tangential_weight: 1, 10, 100 at 642 vertices", "",
        f"Generated by `OMP_NUM_THREADS=1 nice python reports/vesicle_weight_study.py --jobs 3` ({platform.node()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; the runs' own wall times add up to "
        f"{sum(r['wall'] for r in runs):.0f} s, this invocation {wall:.0f} s). The `vesicle` problem with its "
        "defaults and only `tangential_weight` changed, a fixed number of steps per start (the relaxation's "
        "stopping test ignored). Energies w / 8 pi. `before` = the energy the last step reached before the "
        "light mesh repair (history `willmore_before_remesh`), `lift` = recorded / before - 1 (last step; "
        f"largest of the last {TAIL} in brackets), `change` = |w_k - w_(k-1)| / w_k of the recorded energy "
        f"(last step; largest of the last {TAIL}), `change before` = the same of the before-repair energy "
        f"(largest of the last {TAIL}), dV, dA = largest relative constraint errors over the run, `it/step` = "
        "IPOPT iterations of the accepted attempts per step (with the rejected attempts' in brackets), "
        "`min angle` = smallest angle after the repair over the run (final state's in brackets), `gap` = "
        "w / reference - 1 with the extrapolated axisymmetric reference of reports/vesicle_evolver.md "
        f"({', '.join(f'{s} v = {v}: {e}' for (s, v), e in REFERENCE.items())}), `gap before` the same of the "
        "before-repair energy.", "",
        "| start | v | weight | steps | t | w final | before | lift | change | change before | dV | dA | retries "
        "| it/step | min angle | wall s | gap | gap before |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        if r["steps"] < 2:
            lines.append(f"| {r['start']} | {r['v']} | {r['weight']:g} | {r['steps']} FAILED: {r['error']} |"
                         + " |" * 14)
            continue
        s = summary(r)
        n = r["steps"]
        failed = f" FAILED: {r['error']}" if r["error"] else ""
        lines.append(
            f"| {r['start']} | {r['v']} | {r['weight']:g} | {r['steps']}{failed}"
            f" | {r['t']:.3g} | **{r['after'][-1]:.5f}** | {r['before'][-1]:.5f} | {100 * s['lift_last']:+.3f} % "
            f"({100 * s['lift_max']:+.3f} %) | {s['change_last']:.1e} ({s['change_max']:.1e}) "
            f"| {s['change_b_max']:.1e} | {r['dV']:.0e} | {r['dA']:.0e} | {r['retries']} | {r['iterations'] / n:.2f} "
            f"({(r['iterations'] + r['rejected_iterations']) / n:.2f}) | {r['min_angle']:.1f} ({r['final_angle']:.1f}) "
            f"| {r['wall']:.0f} | {100 * s['gap']:+.2f} % | {100 * s['gap_before']:+.2f} % |")
    lines += ["", "Recorded w / 8 pi every 10 steps:", ""]
    for r in runs:
        a = r["after"]
        lines.append(f"- {r['start']} v = {r['v']}, weight {r['weight']:g}: "
                     + ", ".join(f"{k + 1}: {a[k]:.5f}" for k in range(9, len(a), 10)))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", type=int, default=1, help="runs in parallel (processes)")
    ap.add_argument("--cache", type=Path, default=None, help="directory of per-run pickles")
    a = ap.parse_args()
    if a.cache is not None:
        a.cache.mkdir(parents=True, exist_ok=True)
    jobs = [(s, v, w, a.cache) for s, v in CASES for w in WEIGHTS]
    # longest first, so that the pool's last runs are short ones
    order = sorted(range(len(jobs)), key=lambda i: -STEPS[jobs[i][0]])
    t = time.time()
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        done = dict(zip(order, ex.map(_run, [jobs[i] for i in order]), strict=True))
    (OUT / "vesicle_weight_study.md").write_text(markdown([done[i] for i in range(len(jobs))], time.time() - t))


if __name__ == "__main__":
    main()
