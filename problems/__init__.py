"""Registered problem factories: the paper's scenarios and more.

Every module in this package registers its factories with
:func:`willmore_nlp.registry.register`; ``willmore-nlp problems`` lists them.
Problems use the public API of :mod:`willmore_nlp` only.
"""
