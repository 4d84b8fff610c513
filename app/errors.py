"""The one exceptions module of the application.

Every error a user can cause by bad input is a :class:`ConfigError` that names the
file and the field, so the command line can print it as one line and exit 2.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path


class FrhcError(Exception):
    """Base class of every error the application raises on purpose."""


class ConfigError(FrhcError):
    """A scene, session, device or gain file (or dict) is malformed.

    Attributes:
        source: The file (or a description such as ``"<gains>"``) the value came from.
        field: Dotted path of the offending field, e.g. ``"motors.torque_limit[2]"``.
        reason: What is wrong with it.
    """

    def __init__(self, source: str | Path, field: str, reason: str) -> None:
        self.source = str(source)
        self.field = field
        self.reason = reason
        super().__init__(f"{self.source}: field '{field}': {reason}")


class InvalidField(ValueError):
    """Raised by a configuration dataclass's ``__post_init__`` for one bad field.

    :func:`app.config.from_dict` turns it into a :class:`ConfigError` carrying the
    file name and the full dotted path of the field.
    """

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


class InputError(FrhcError, ValueError):
    """An argument of a public API call has the wrong type, dtype or shape (a programming error;
    non-finite *values* are faults the controller handles, not errors)."""


class ContactQueryError(FrhcError):
    """A collision query failed or returned a non-finite result."""


class ContactInputError(ContactQueryError):
    """The contact API was called with an unusable pose or twist (wrong shape or type, or a pose
    that is not a rigid transform): a programming error, raised rather than returned."""


class EngineError(FrhcError):
    """The point engine could not start or reach its workers (a Ray instance or cluster)."""


class OutputError(FrhcError):
    """An output folder (``--out``) could not be created or written: a read-only or full file
    system, a regular file in the way, a name longer than the file system allows.

    The message names the file that failed (or the folder, when the library that wrote did not
    say which file) and the operating system's reason.
    """

    def __init__(self, folder: str | Path, exc: OSError) -> None:
        self.folder = str(folder)
        where = exc.filename if exc.filename is not None else folder
        # pyarrow's OSError carries the errno but a long "Detail: ..." text as its strerror.
        reason = os.strerror(exc.errno) if exc.errno else str(exc)
        if isinstance(exc, FileExistsError | NotADirectoryError):
            reason = "a file is in the way of the folder"
        super().__init__(f"{where}: field '--out': cannot write the output: {reason}")


class ListenError(FrhcError):
    """A server (``frhc web``, ``frhc device serve``) cannot listen on the address it was given:
    the port is busy, the host is not this machine's, or the port needs privileges.

    A busy port is refused, not swapped for another: whoever connects (a browser tab, a ``frhc
    run --device ws://...``) was told that port and would find something else there, or nothing.
    Port 0 asks for any free one.
    """

    def __init__(self, host: str, port: int, exc: OSError) -> None:
        self.host, self.port = host, port
        # A name that does not resolve has a negative errno (getaddrinfo's own) and its text.
        reason = os.strerror(exc.errno) if exc.errno and exc.errno > 0 else exc.strerror or str(exc)
        hint = ""
        if exc.errno == errno.EADDRINUSE:
            hint = " (another server holds it: choose another --port, or --port 0 for any free one)"
        super().__init__(f"cannot listen on {host}:{port}: {reason}{hint}")


class Interrupted(KeyboardInterrupt):
    """A command stopped by SIGINT (Ctrl-C) or SIGTERM while it worked.

    A ``KeyboardInterrupt``, so it unwinds every ``with`` block on the way out (the point engine
    ends its Ray instance there) and is not caught as an ``Exception``.

    Attributes:
        signum: The signal (``signal.SIGINT`` or ``signal.SIGTERM``); the exit code is 128 + it.
        kept: What the command kept of its work and where (one line), or empty.
    """

    def __init__(self, signum: int, kept: str = "") -> None:
        self.signum = signum
        self.kept = kept
        super().__init__(kept)
