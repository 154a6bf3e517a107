"""Applications built on the library core: the paper's reproduction (:mod:`~willmore_nlp.apps.reproduce`),
solver studies (:mod:`~willmore_nlp.apps.study`), run reports (:mod:`~willmore_nlp.apps.report`) and the
benchmarks (:mod:`~willmore_nlp.apps.bench`, ``python -m willmore_nlp.bench``). The core never imports them."""
