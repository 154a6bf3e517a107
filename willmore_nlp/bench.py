"""``python -m willmore_nlp.bench``: the benchmarks of :mod:`willmore_nlp.apps.bench`."""

import sys

from willmore_nlp.apps.bench import main

if __name__ == "__main__":
    sys.exit(main())
