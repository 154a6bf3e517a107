"""willmore_nlp: Willmore flow of curves and surfaces by a nested variational time discretization.

Each time step is a CasADi NLP in the new positions X and the implicit mean-curvature step Y,
solved by IPOPT with exact element-assembled Hessians.
"""

from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import FlowError, StepInterrupted, StepResult, WillmoreFlow
from willmore_nlp.geometry import willmore_energy
from willmore_nlp.mesh import Mesh, MeshError
from willmore_nlp.rundir import Run, load_run

__all__ = [
    "FlowError",
    "Mesh",
    "MeshError",
    "Run",
    "StepInterrupted",
    "StepResult",
    "UserInputError",
    "WillmoreFlow",
    "load_run",
    "willmore_energy",
]
__version__ = "0.1.0"
