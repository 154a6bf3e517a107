"""The one exception class for bad input, and the exit codes of the command line.

Every error the user can fix (a bad file, option, parameter, run directory, environment setting)
is a :class:`UserInputError`: the CLI prints its message as one line and exits with
:data:`EXIT_USAGE`. Anything else is a bug and shows its traceback.
"""

from __future__ import annotations

import errno
import sys

EXIT_OK = 0
EXIT_FAILED = 1
"""A run stopped because a step failed after every retry (the run directory is kept)."""
EXIT_USAGE = 2
"""Bad input: file, option, parameter, run directory or environment setting (one-line message)."""
EXIT_BUG = 70
"""An internal error (sysexits' EX_SOFTWARE): a bug, with its traceback; never the user's input."""
EXIT_IO = 74
"""The output could not be written (disk full, read-only or no permission; sysexits' EX_IOERR)."""
IO_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG})
"""OSErrors of the environment, reported in one line with :data:`EXIT_IO` (any other OSError is a bug)."""
PATH_ERRNOS = frozenset({errno.ENOTDIR, errno.EEXIST, errno.ENAMETOOLONG, errno.ELOOP, errno.EISDIR})
"""OSErrors of a path the user gave that cannot be made (a file where a folder must go, a name too long, a symlink
loop): one line with :data:`EXIT_USAGE`."""
EXIT_INTERRUPTED = 130
"""Ctrl-C (SIGINT, 128 + 2) outside a run's steps: while the library loads, in a study, a report (runs that catch the
signal end with 128 + its number after their last finished step, :mod:`willmore_nlp.runner`)."""


def interrupted() -> int:
    """Say "interrupted" on stderr (one line, no traceback: the user's Ctrl-C is not a bug) and return
    :data:`EXIT_INTERRUPTED`."""
    print("willmore-nlp: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


class UserInputError(ValueError):
    """Bad input from the user; the message names the file, vertex, option or setting and the fix.

    Subclasses: ConfigError, MeshError, ProblemError, RunError, StudyError, AnisotropyError,
    CodegenError (a subclass of ValueError so that older ``except ValueError`` code still works).
    """
