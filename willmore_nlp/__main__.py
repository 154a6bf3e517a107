"""``willmore-nlp`` and ``python -m willmore_nlp``: the command line (:mod:`willmore_nlp.cli`).

Loading the library takes about a second (CasADi, NumPy, SciPy, trimesh). The launcher loads it with Ctrl-C
(SIGINT) held back and answers a Ctrl-C that came meanwhile as the commands do: one line, exit 130. Not with a
traceback of the import, and not as a bug: trimesh turns an interrupt inside its own import into a broken module
whose next use raises TypeError.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Sequence

from willmore_nlp.errors import interrupted


def _load() -> bool:
    """Import the command line and trimesh; False when Ctrl-C came meanwhile (it is taken, not delivered)."""
    masks = hasattr(signal, "pthread_sigmask")  # (Windows has none: an interrupt raises as it comes)
    held = {signal.SIGINT}
    if masks:
        signal.pthread_sigmask(signal.SIG_BLOCK, held)
    came = False
    try:
        import trimesh  # noqa: F401

        import willmore_nlp.cli  # noqa: F401
    except KeyboardInterrupt:
        came = True
    finally:
        if masks:
            came = signal.SIGINT in signal.sigpending()
            if came:
                signal.sigwait(held)
            signal.pthread_sigmask(signal.SIG_UNBLOCK, held)
    return not came


def main(argv: Sequence[str] | None = None) -> int:
    """Load the library and run the command line; see :func:`willmore_nlp.cli.main`."""
    if not _load():
        return interrupted()
    from willmore_nlp.cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main())
