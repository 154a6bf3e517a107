"""Energy terms of the step problem, one module per term (docs/guide/terms.md).

The step problem (:class:`willmore_nlp.model.step.StepProblem`) is the sum of its terms;
:func:`willmore_nlp.model.build.build_step` picks them from the flow's options.
"""

from willmore_nlp.model.terms.anisotropic_inner import AnisotropicInner
from willmore_nlp.model.terms.area import AreaEnergy
from willmore_nlp.model.terms.base import CAPABILITIES, Element, Term
from willmore_nlp.model.terms.conormal import Conormal
from willmore_nlp.model.terms.constraints import AreaConstraint, VolumeConstraint
from willmore_nlp.model.terms.distance import Distance
from willmore_nlp.model.terms.helfrich import Helfrich
from willmore_nlp.model.terms.isotropic_inner import IsotropicInner
from willmore_nlp.model.terms.tangential_control import TangentialControlTerm
from willmore_nlp.model.terms.willmore import Willmore

__all__ = ["CAPABILITIES", "AnisotropicInner", "AreaConstraint", "AreaEnergy", "Conormal", "Distance", "Element",
           "Helfrich", "IsotropicInner", "TangentialControlTerm", "Term", "VolumeConstraint", "Willmore"]
