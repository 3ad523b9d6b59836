"""Build the Blender extension zips: the add-on, our libraries as a wheel, and every run-time dependency
as unmodified wheels for Python 3.11 (Blender 4.2–5.0) and 3.13 (Blender 5.1+), and on Linux 3.14 (the
distributions' own Blender builds), one zip per platform.

Blender provides numpy, so it is never bundled; the other dependencies are pinned per Python version to
releases that work with the numpy that those Blender versions ship (numpy 1.x up to Blender 5.0).
"""

from __future__ import annotations

import base64
import hashlib
import io
import subprocess
import sys
import tomllib
import zipfile
from collections.abc import Callable
from pathlib import Path

#: Wheel platform tags that serve each Blender platform, best first.
PLATFORM_TAGS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_14_0_arm64", "macosx_13_0_arm64", "macosx_12_0_arm64", "macosx_11_0_arm64"],
    "macos-x64": ["macosx_11_0_x86_64", "macosx_10_15_x86_64", "macosx_10_13_x86_64", "macosx_10_9_x86_64"],
}
DEFAULT_PLATFORMS = ("linux-x64",)

#: Pinned run-time dependencies per Python version (numpy comes with Blender). SciPy's range of NumPy must
#: hold the NumPy each Blender ships, or SciPy warns on import: 1.15.3 takes 1.23.5-2.4 (Blender 4.2-5.0
#: ship 1.26); 1.18.1 takes 2.0-2.7 (Blender 5.1+ ship NumPy 2, and bpy 5.3 from PyPI pulls in 2.5).
#: NLopt 2.9.1 is the newest release with wheels for all four platforms on both Pythons; its wheels declare
#: numpy>=2 because they were built against numpy 2, whose C API also serves numpy 1.x, so they run on
#: Blender 4.2-5.0's numpy 1.26 (Blender installs bundled wheels without resolving their requirements).
#: tests/test_wheels.py runs the extension on these wheels alone, in Pythons that hold only bpy.
#: Python 3.14 serves Linux distributions' own Blender builds (Debian unstable's Blender 5.2 runs on its
#: system Python 3.14); NLopt has cp314 wheels from 2.10 on, for every platform but Intel macOS, where
#: Blender comes only from blender.org with its own Python 3.11 or 3.13.
REQUIREMENTS = {
    "3.11": ["scipy==1.15.3", "potpourri3d==1.4.0", "pyserial==3.5", "nlopt==2.9.1"],  # Blender 4.2-5.0
    "3.13": ["scipy==1.18.1", "potpourri3d==1.4.0", "pyserial==3.5", "nlopt==2.9.1"],  # Blender 5.1+
    "3.14": [
        "scipy==1.18.1",
        "potpourri3d==1.4.0",
        "pyserial==3.5",
        "nlopt==2.11.0",
    ],  # distributions' Blender
}
#: The Pythons each platform's zip carries wheels for.
PYTHONS = {
    "linux-x64": ("3.11", "3.13", "3.14"),
    "windows-x64": ("3.11", "3.13"),
    "macos-arm64": ("3.11", "3.13"),
    "macos-x64": ("3.11", "3.13"),
}

#: Our libraries, bundled as one pure-Python wheel.
LIBRARIES = ("geodesics", "solver", "tangible")
#: Files of the add-on package (paths inside it) that belong to the command line, not inside Blender.
CONSOLE_ONLY = ("commands/cli.py", "commands/build.py", "commands/rig_benchmark.py")


class BuildError(RuntimeError):
    """The extension could not be built (a wheel could not be fetched, a file is missing)."""


def addon_root() -> Path:
    """The add-on package's folder, which the extension zip holds (its subpackages' folders included)."""
    return Path(__file__).resolve().parent.parent


def project_root() -> Path:
    return addon_root().parent


def manifest_template() -> dict:
    path = project_root() / "blender_manifest.toml"
    if not path.exists():
        raise BuildError(f"{path} is missing: build-extension runs from a source checkout")
    return tomllib.loads(path.read_text(encoding="utf-8"))


def library_wheel(version: str) -> tuple[str, bytes]:
    """A reproducible pure-Python wheel of the libraries: (file name, bytes)."""
    dist = f"contact_edit-{version}"
    files: dict[str, bytes] = {}
    for package in LIBRARIES:
        root = project_root() / package
        for path in sorted(root.rglob("*")):
            if path.is_file() and path.suffix in (".py", ".md") and "__pycache__" not in path.parts:
                files[path.relative_to(project_root()).as_posix()] = path.read_bytes()
    files[f"{dist}.dist-info/METADATA"] = (
        f"Metadata-Version: 2.1\nName: contact-edit\nVersion: {version}\n"
        "Summary: Contact Edit libraries (geodesics, solver, tangible), bundled with the Blender extension\n"
    ).encode()
    files[f"{dist}.dist-info/WHEEL"] = (
        b"Wheel-Version: 1.0\nGenerator: contact-edit build-extension\n"
        b"Root-Is-Purelib: true\nTag: py3-none-any\n"
    )
    record = []
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{name},sha256={digest},{len(data)}")
    record.append(f"{dist}.dist-info/RECORD,,")
    files[f"{dist}.dist-info/RECORD"] = ("\n".join(record) + "\n").encode()
    return f"{dist}-py3-none-any.whl", _zip(files)


def dependency_wheels(platform: str, python: str, cache: Path) -> list[Path]:
    """Download (or reuse from ``cache``) the pinned dependency wheels for one platform and Python."""
    target = cache / f"{python}-{platform}"
    target.mkdir(parents=True, exist_ok=True)
    tags = [arg for tag in PLATFORM_TAGS[platform] for arg in ("--platform", tag)]
    command = [
        sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
        "--only-binary=:all:", "--no-deps", "--python-version", python, *tags, "--dest", str(target),
        *REQUIREMENTS[python],
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise BuildError(f"could not fetch wheels for {platform}, Python {python}:\n{done.stderr.strip()}")
    found, missing = [], []
    wheels = sorted(target.glob("*.whl"))
    for requirement in REQUIREMENTS[python]:
        name, version = requirement.lower().replace("-", "_").split("==")
        # Exactly the pinned release: the cache may hold others from earlier pins.
        matches = [w for w in wheels if w.name.lower().split("-")[:2] == [name, version]]
        if matches:
            found.append(matches[0])
        else:
            missing.append(requirement)
    if missing:
        raise BuildError(f"no wheels for {', '.join(missing)} on {platform}, Python {python}")
    return found


def build_extension(
    output: Path,
    platforms=DEFAULT_PLATFORMS,
    pythons=None,
    cache: Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write one extension zip per platform into ``output``, with wheels for ``pythons`` (default: the
    platform's :data:`PYTHONS`); returns their paths."""
    say = progress or (lambda _msg: None)
    unknown = [p for p in platforms if p not in PLATFORM_TAGS]
    if unknown:
        raise BuildError(f"unknown platforms {unknown}; choose from {', '.join(PLATFORM_TAGS)}")
    manifest = manifest_template()
    version = manifest["version"]
    cache = cache or Path.home() / ".cache" / "contact-edit" / "wheels"
    output.mkdir(parents=True, exist_ok=True)
    root = addon_root()
    sources = list(root.glob("*.py"))
    for sub in sorted(root.iterdir()):
        if sub.is_dir() and (sub / "__init__.py").exists():
            sources += sub.rglob("*.py")
    addon = {
        name: path.read_bytes()
        for path in sorted(sources)
        if (name := path.relative_to(root).as_posix()) not in CONSOLE_ONLY
    }
    lib_name, lib_bytes = library_wheel(version)
    written = []
    for platform in platforms:
        files = dict(addon)
        files[f"wheels/{lib_name}"] = lib_bytes
        for python in pythons or PYTHONS[platform]:
            say(f"fetching wheels for {platform}, Python {python}")
            for wheel in dependency_wheels(platform, python, cache):
                files[f"wheels/{wheel.name}"] = wheel.read_bytes()
        wheels = sorted(name for name in files if name.startswith("wheels/"))
        files["blender_manifest.toml"] = _manifest_text(
            manifest, [platform], [f"./{w}" for w in wheels]
        ).encode()
        path = output / f"contact_edit-{version}-{platform}.zip"
        path.write_bytes(_zip(files))
        written.append(path)
        say(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MiB)")
    return written


def _manifest_text(manifest: dict, platforms: list[str], wheels: list[str]) -> str:
    """TOML for the manifest with the build's platforms and wheels (flat keys and one table)."""

    def value(v):
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise BuildError(f"unsupported manifest value {v!r}")

    generated = ("platforms", "wheels")
    lines = [
        f"{k} = {value(v)}" for k, v in manifest.items() if not isinstance(v, dict) and k not in generated
    ]
    lines += [f"platforms = {value(platforms)}", "wheels = ["] + [f"  {value(w)}," for w in wheels] + ["]"]
    for key, table in manifest.items():
        if isinstance(table, dict):
            lines += ["", f"[{key}]"] + [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def _zip(files: dict[str, bytes]) -> bytes:
    """A deterministic zip (sorted names, fixed timestamps)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, files[name])
    return buffer.getvalue()
