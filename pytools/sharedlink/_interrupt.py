"""Ctrl-C while the command is still loading its modules: exit 130 without a traceback.

The package's ``__init__`` and ``cli`` load their modules inside :class:`quiet_interrupt`. It
imports nothing but the C modules ``_signal`` and ``sys``, so it is in place a moment after the
package starts loading (``signal`` and ``contextlib`` would first import ``enum`` and more).
Ctrl-C before that moment, while Python itself starts, is out of our hands."""

import _signal
import sys

#: the exit code of an interrupted command (as ``commands.EXIT_INTERRUPTED``)
EXIT_INTERRUPTED = 130


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is so that it cleans up as on Ctrl-C (``cli.main``
    installs the handler; exit 143, not Ctrl-C's 130: code that catches KeyboardInterrupt to
    clean up tells the two apart by this class)."""


def _exit_interrupted(signum, frame):  # type: ignore[no-untyped-def]
    sys.stderr.write("sharedlink: interrupted\n")
    raise SystemExit(EXIT_INTERRUPTED)


class quiet_interrupt:  # noqa: N801 - used like a function: ``with quiet_interrupt():``
    """Within the block, Ctrl-C exits with 130 quietly (``SystemExit``, which an import passes
    on and Python ends without a traceback) instead of raising ``KeyboardInterrupt``. Only
    when nobody set a SIGINT handler of their own, and only in the main thread; the default
    handler is back after the block."""

    def __enter__(self) -> None:
        self.installed = False
        if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
            try:
                _signal.signal(_signal.SIGINT, _exit_interrupted)
                self.installed = True
            except ValueError:  # not the main thread
                pass

    def __exit__(self, *exc: object) -> None:
        if self.installed:
            _signal.signal(_signal.SIGINT, _signal.default_int_handler)
