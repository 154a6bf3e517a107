"""willmore_nlp: Willmore flow of curves and surfaces by a nested variational time discretization.

Each time step is a CasADi NLP in the new positions X and the implicit mean-curvature step Y,
solved by IPOPT with exact element-assembled Hessians.

The names below load their modules on first use (PEP 562), so that ``willmore-nlp`` starts its
command line before CasADi and NumPy are loaded (a Ctrl-C while they load is then an ordinary
interrupt, :mod:`willmore_nlp.__main__`); ``from willmore_nlp import WillmoreFlow`` works as usual.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from willmore_nlp.errors import UserInputError
    from willmore_nlp.flow import FlowError, StepInterrupted, StepResult, WillmoreFlow
    from willmore_nlp.geometry import willmore_energy
    from willmore_nlp.mesh import Mesh, MeshError
    from willmore_nlp.rundir import Run, load_run

_HOME = {"FlowError": "flow", "Mesh": "mesh", "MeshError": "mesh", "Run": "rundir", "StepInterrupted": "flow",
         "StepResult": "flow", "UserInputError": "errors", "WillmoreFlow": "flow", "load_run": "rundir",
         "willmore_energy": "geometry"}
__all__ = ["FlowError", "Mesh", "MeshError", "Run", "StepInterrupted", "StepResult", "UserInputError", "WillmoreFlow",
           "load_run", "willmore_energy"]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module 'willmore_nlp' has no attribute {name!r}")
    value = getattr(import_module(f"willmore_nlp.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return [*__all__, "__version__"]
