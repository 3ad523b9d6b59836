"""Python environments that hold only Blender as a module (and what it pulls in), as a Blender user's
Python does: there the built extension's bundled wheels are the only copy of our dependencies, where
the dev venv's own scipy, NLopt, potpourri3d and pyserial would shadow them.

    python -m tests.bpy_only      create the missing ones (about 1 GB each, cached outside the clone)

CONTACT_EDIT_BPY_CACHE overrides where they live (default: ~/.cache/contact-edit/bpy).
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys
from pathlib import Path

#: name -> (Python version, what to install): the oldest Blender the manifest claims, 4.2 LTS, with the
#: NumPy that Blender 4.2 ships; and the newest bpy for Python 3.13 with the NumPy pip gives it.
ENVIRONMENTS = {
    "4.2": ("3.11", ["bpy==4.2.23", "numpy==1.26.4"]),
    "5.3": ("3.13", ["bpy==5.3.0"]),
}


def folder(name: str) -> Path:
    cache = os.environ.get("CONTACT_EDIT_BPY_CACHE") or Path.home() / ".cache" / "contact-edit" / "bpy"
    return Path(cache) / f"bpy-{ENVIRONMENTS[name][1][0].split('==')[1]}"


def python(name: str) -> Path:
    """The environment's Python, or RuntimeError saying how to create it."""
    path = folder(name) / "bin" / "python"
    if not (folder(name) / ".ready").exists() or not path.exists():
        raise RuntimeError(
            f"no Python environment with only {' and '.join(ENVIRONMENTS[name][1])} at {folder(name)}: "
            "create it with 'python -m tests.bpy_only' (about 1 GB)"
        )
    return path


def interpreter(version: str) -> str | None:
    """A Python of this version on this machine that runs (on PATH, or installed by pyenv; pyenv's shim
    on PATH fails for a version that is not the selected one)."""
    candidates = [shutil.which(f"python{version}")]
    if shutil.which("pyenv"):
        root = subprocess.run(["pyenv", "root"], capture_output=True, text=True).stdout.strip()
        candidates += sorted(
            glob.glob(os.path.join(root, "versions", f"{version}.*", "bin", f"python{version}"))
        )
    for candidate in filter(None, candidates):
        if subprocess.run([candidate, "-c", "pass"], capture_output=True).returncode == 0:
            return candidate
    return None


def create(name: str) -> Path:
    """Create the environment unless it is ready; returns its Python."""
    try:
        return python(name)
    except RuntimeError:
        pass
    version, requirements = ENVIRONMENTS[name]
    base = interpreter(version)
    if base is None:
        raise RuntimeError(f"no Python {version} on this machine (install it, e.g. with pyenv)")
    target = folder(name)
    shutil.rmtree(target, ignore_errors=True)
    subprocess.run([base, "-m", "venv", str(target)], check=True)
    subprocess.run(
        [str(target / "bin" / "python"), "-m", "pip", "install", "--quiet", *requirements], check=True
    )
    (target / ".ready").write_text(" ".join(requirements) + "\n")
    return python(name)


if __name__ == "__main__":
    for environment in ENVIRONMENTS:
        print(f"bpy {environment}: {create(environment)}", file=sys.stderr)
