"""Files read with errors that name them, and written whole or not at all."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


def write_atomically(path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` so that the file is either complete or untouched: a
    temporary file next to it is renamed over it (``os.replace``), never half written."""
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as f:
            f.write(raw)
        os.replace(temp, path)
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise


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
