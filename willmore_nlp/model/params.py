"""The parameter vector of a step problem, packed and unpacked by name in one place."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

BASE_SCALARS = ("tau", "tt", "lam")
"""Scalar parameters of every step problem: step size tau, inner step tt, length/area energy lam."""


@dataclass(frozen=True)
class StepParams:
    """Layout of ``p = [Xk (N m), scalars, nodal blocks (N w each, node-major), nodal vectors (N m each)]``.

    Works on numpy arrays and on CasADi MX vectors alike (slicing only).

    Parameters
    ----------
    n_vertices, m : int
    scalars : names of the scalar parameters, :data:`BASE_SCALARS` first
    nodal : (name, width) of per-node data gathered into every element with its nodes
    vectors : names of (N, m) nodal vectors used outside the elements (the co-normal term)
    """

    n_vertices: int
    m: int
    scalars: tuple[str, ...] = BASE_SCALARS
    nodal: tuple[tuple[str, int], ...] = ()
    vectors: tuple[str, ...] = ()

    @property
    def n_nodal(self) -> int:
        """Per-node data width, all blocks together."""
        return sum(w for _, w in self.nodal)

    @property
    def nodal_start(self) -> int:
        """Offset of the per-node block (node-major, ``n_nodal`` per node)."""
        return self.n_vertices * self.m + len(self.scalars)

    @property
    def size(self) -> int:
        """Length of p."""
        return self.nodal_start + self.n_vertices * (self.n_nodal + self.m * len(self.vectors))

    def index(self, name: str) -> int:
        """Position of the scalar ``name`` in p."""
        return self.n_vertices * self.m + self.scalars.index(name)

    def xk(self, p: Any) -> Any:
        """(N, m) Xk of a numpy p (the (N m,) slice of an MX p)."""
        x = p[: self.n_vertices * self.m]
        return x.reshape(-1, self.m) if isinstance(x, np.ndarray) else x

    def scalar(self, p: Any, name: str) -> Any:
        """The scalar ``name`` (float for numpy p, MX entry otherwise)."""
        v = p[self.index(name)]
        return float(v) if isinstance(p, np.ndarray) else v

    def scalar_block(self, p: Any) -> Any:
        """All scalars (the element kernels' ``par``)."""
        i = self.n_vertices * self.m
        return p[i : i + len(self.scalars)]

    def vector(self, p: Any, name: str) -> Any:
        """The (N m,) nodal vector ``name``."""
        n = self.n_vertices * self.m
        i = self.nodal_start + self.n_vertices * self.n_nodal + self.vectors.index(name) * n
        return p[i : i + n]

    def replace(self, p: np.ndarray, **scalars: float) -> np.ndarray:
        """A copy of p with some scalars changed."""
        q = np.array(p, float, copy=True)
        for k, v in scalars.items():
            q[self.index(k)] = v
        return q

    def pack(self, Xk: np.ndarray, values: dict[str, Any]) -> np.ndarray:
        """(size,) p from Xk and the values of every scalar, nodal block and vector by name."""
        missing = [k for k in (*self.scalars, *(n for n, _ in self.nodal), *self.vectors) if k not in values]
        if missing:
            raise ValueError(f"step parameters: no value for {', '.join(missing)}")
        N, m = self.n_vertices, self.m
        parts = [np.asarray(Xk, float).reshape(N * m), np.array([float(values[k]) for k in self.scalars])]
        if self.nodal:
            parts.append(np.hstack([np.asarray(values[n], float).reshape(N, w) for n, w in self.nodal]).ravel())
        parts += [np.asarray(values[k], float).reshape(N * m) for k in self.vectors]
        return np.concatenate(parts)
