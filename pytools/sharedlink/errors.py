"""The package's one error hierarchy: what the library raises and ``cli.main`` reports.

Modelled on kbandla/dpkt ``dpkt/dpkt.py`` (one base, unpack errors below it) and pypa/twine
``twine/exceptions.py`` (one base the command line catches once)::

    Error
    +-- DecodeError(offset, reason)        bytes that are not a message of the protocol
    |   +-- codec.SharedLinkError, p2os.P2osError, blackboard.BlackboardError
    +-- InputError(path, record, reason)   a file that cannot be read (further)
    |   +-- pcapio.CaptureError, serial_import.SerialImportError
    +-- OutputError                        a file that cannot be written
    |   +-- transform.TransformError
    +-- UsageError                         a bad option or argument
        +-- replay.ReplayError

``cli.main`` catches :class:`Error` once, prints ``sharedlink: error: <message>`` (for an input
error ``FILE: record N: reason``) and exits with 2. Decode errors are also ``ValueError`` (as they
always were); codecs raise nothing else, whatever the input.
"""

from __future__ import annotations

__all__ = ["DecodeError", "Error", "InputError", "OutputError", "UsageError"]


class Error(Exception):
    """Base of every error the package raises on purpose."""


class DecodeError(Error, ValueError):
    """Bytes that are not a message of the protocol. ``offset`` is relative to the input the
    codec was given; ``reason`` says what is wrong there."""

    def __init__(self, offset: int, reason: str) -> None:
        super().__init__(f"offset {offset}: {reason}")
        self.offset = offset
        self.reason = reason


class InputError(Error):
    """A file that cannot be read (further): ``path``, the ``record`` (counting from 1, as
    Wireshark counts frames) where reading stopped, or ``None`` for the file as a whole, and the
    ``reason``. The message is ``PATH: <unit> N: reason``."""

    #: what one record of this kind of input is called in the message
    unit = "record"
    #: what the message names when ``record`` is None ("" names nothing)
    whole = ""

    def __init__(self, path: str, record: int | None, reason: str) -> None:
        where = f"{self.unit} {record}" if record is not None else self.whole
        super().__init__(f"{path}: {where}: {reason}" if where else f"{path}: {reason}")
        self.path, self.record, self.reason = path, record, reason


class OutputError(Error):
    """A file that cannot be written (or a capture that cannot be rewritten as asked)."""


class UsageError(Error):
    """Bad input or usage: the CLI prints ``sharedlink: error: ...`` and exits with 2."""
