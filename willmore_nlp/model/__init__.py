"""Step problems: energies, element kernels, assembled NLP functions."""

from willmore_nlp.model.step import StepProblem

__all__ = ["StepProblem"]
