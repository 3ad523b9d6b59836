"""Where a command may write: never over one of its inputs, over an existing file only when told to.

Every ``contact-edit`` subcommand that writes files checks them all here, before any work: each file it
writes, including those it writes inside an output folder, is compared with each of its input files
(by resolved path, and by :func:`os.path.samefile`, which also sees hard links and the other spellings a
case-insensitive file system accepts). An output that is an input is refused even with ``--overwrite``:
the command would destroy what it reads, and with a format the input's readers do not expect (a motion
zip over a hand's OBJ). An existing output that is not an input is replaced only with ``--overwrite``.
A command whose output has one format (``pose`` writes a .blend, ``synthesize`` and ``import-grab`` a
motion .npz) refuses an output named with another extension, which would hide what the file holds.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path

#: The option that allows replacing an existing output (never an input).
OVERWRITE = "--overwrite"


def check_outputs(
    outputs: Iterable,
    inputs: Mapping,
    *,
    overwrite: bool = False,
    error: type[Exception] = FileExistsError,
    folders: Iterable = (),
    instead: str = "choose another output",
    suffix: str | None = None,
) -> None:
    """Refuse outputs that are inputs, existing outputs unless ``overwrite``, and outputs whose extension
    is not the format written; raise ``error``.

    Parameters
    ----------
    outputs : iterable of path-like
        Every file the command will write, as the user named it or inside the folder they named.
    inputs : mapping of path-like (or None, skipped) to str
        The command's input files and what each is, for the message (``"the input scene"``).
    overwrite : bool
        Allow replacing an existing output that is not an input.
    error : exception class
        Raised with a one-line message naming the file and what to do (the caller's family of errors).
    folders : iterable of path-like
        Folders the command fills with files named as it works (a retarget's per-frame results): an input
        anywhere inside one is refused.
    instead : str
        What to do about an output that is an input (``"choose another output folder (-o)"``).
    suffix : str, optional
        The extension of the one format the command writes (``".blend"``): an output named otherwise (a
        .blend written as ``o11.txt``) is refused, saying which extension is expected. Any case.
    """
    named = {Path(path): what for path, what in inputs.items() if path is not None}
    for output in map(Path, outputs):
        for path, what in named.items():
            if _same(output, path):
                raise error(f"{output} is {what}: an input, never written, even with {OVERWRITE}; {instead}")
        if suffix is not None and output.suffix.lower() != suffix.lower():
            stem = Path(output.stem)  # "o11.txt" -> "o11.blend"; "o11.blend.tmp" -> "o11.blend"
            named_so = stem.name if stem.suffix.lower() == suffix.lower() else f"{stem.name}{suffix}"
            raise error(
                f"{output}: the output is written as a {suffix} file, so its name must end in {suffix} "
                f"(e.g. {named_so})"
            )
        if not overwrite and os.path.lexists(output):
            raise error(f"{output} exists; {instead}, or pass {OVERWRITE} to replace it")
    for folder in map(Path, folders):
        for path, what in named.items():
            if any(_same(parent, folder) for parent in Path(os.path.realpath(path)).parents):
                raise error(
                    f"{path} is {what}: an input, inside {folder}, which this command fills with its work; "
                    f"move the input or {instead}"
                )


def _same(a: Path, b: Path) -> bool:
    """The same file or folder: by resolved path, or (both existing) by device and inode."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # either does not exist (yet)
        return False
