"""Files read with errors that name them, and written whole or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO


@contextlib.contextmanager
def atomic_file(path) -> Iterator[BinaryIO]:
    """Open a binary file to write that appears at ``path`` only once complete: it is written next to
    ``path`` under a temporary name, flushed to disk and renamed over it (``os.replace``); on an error
    it is removed and ``path`` is untouched.

    Not ``tempfile.mkstemp``: its files are private (0600), where an output should get the permissions the
    user's umask gives any new file.
    """
    path = Path(path)
    temp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
    handle = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        with os.fdopen(handle, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def write_atomically(path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` whole or not at all (:func:`atomic_file`)."""
    with atomic_file(path) as f:
        f.write(data.encode("utf-8") if isinstance(data, str) else bytes(data))


def read_json(path, what: str, error: type[Exception]) -> object:
    """The JSON value in ``path``; a missing, unreadable or malformed file raises ``error`` naming it and
    ``what`` it should be (``"contact file"``)."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"cannot read the {what} {path}: there is no {what} at that path") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise error(f"cannot read the {what} {path}: not valid JSON ({e})") from None
    except OSError as e:  # a directory, no permission, ...
        raise error(f"cannot read the {what} {path}: {e}") from None
