"""Real Blender windows for the tests: a Blender with its window under Xvfb, in a Debian chroot built by
``chroot.sh`` (Debian 12 has no Blender new enough), running a scripted session (see ``driver.py``).

A session installs the built extension zip the way a user does (``blender --command extension
install-file``) into a fresh user folder, starts Xvfb and Blender, runs the session module's steps with
real input events, and comes back with Blender's console output, what the session recorded, and its
screenshots. Nothing stays mounted or running afterwards.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import textwrap
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHROOT = HERE / "chroot.sh"
SESSIONS = HERE / "sessions"
#: The Debian suites whose Blender the tests run: suite -> what it gives.
SUITES = {
    "trixie": "Debian 13, Blender 4.3 (Python 3.13)",
    "sid": "Debian unstable, Blender 5.2 (Python 3.14)",
}
#: The screen (and the Blender window on it).
SCREEN = (1600, 1000)


@dataclass
class SessionRun:
    """What one session left: Blender's console output, the recorded results, the screenshots."""

    log: str
    results: dict
    shots: dict[str, Path]
    returncode: int
    seconds: float
    folder: Path

    def tracebacks(self) -> list[str]:
        """Python tracebacks Blender printed (a draw handler or an operator that failed)."""
        blocks, lines = [], self.log.splitlines()
        for i, line in enumerate(lines):
            if line.startswith("Traceback (most recent call last)"):
                end = i + 1
                while end < len(lines) and (lines[end].startswith((" ", "\t")) or not lines[end].strip()):
                    end += 1
                blocks.append("\n".join(lines[i : end + 1]))
        return blocks


@dataclass
class WindowBlender:
    """A Blender with a window, in one chroot."""

    suite: str
    root: Path
    version: str
    _installed: dict = field(default_factory=dict)

    @classmethod
    def find(cls, suite: str = "trixie") -> WindowBlender:
        """The chroot's Blender, or RuntimeError saying why it cannot run here."""
        if os.geteuid() != 0:
            raise RuntimeError(
                "a real Blender window needs root (chroot, mounts); these tests run as root in CI"
            )
        done = subprocess.run([str(CHROOT), "path", suite], capture_output=True, text=True)
        root = Path(done.stdout.strip())
        stamp = root / ".contact-edit-ready"
        if not stamp.exists():
            raise RuntimeError(
                f"no Blender window chroot for Debian {suite} at {root}: build it with "
                f"'{CHROOT.relative_to(HERE.parent.parent)} setup {suite}' (about 1.5 GB, a few minutes)"
            )
        return cls(suite, root, stamp.read_text().strip())

    def run(self, *command: str, timeout: float = 120) -> subprocess.CompletedProcess:
        """A command inside the chroot."""
        return subprocess.run(
            [str(CHROOT), "run", self.suite, *command], capture_output=True, text=True, timeout=timeout
        )

    def _user_folder(self, extension: Path) -> Path:
        """A Blender user folder (in the chroot) with the extension installed and the splash screen off,
        made once per zip; sessions get copies."""
        key = (extension.resolve(), extension.stat().st_mtime_ns)
        if key in self._installed:
            return self._installed[key]
        folder = self.root / "tmp" / f"contact-edit-user-{uuid.uuid4().hex[:8]}"
        folder.mkdir(parents=True)
        shutil.copy(extension, folder / "extension.zip")
        inside = "/" + folder.relative_to(self.root).as_posix()
        env = f"BLENDER_USER_RESOURCES={inside}/user"
        done = self.run(
            "env", env, "blender", "--command", "extension", "install-file", "-r", "user_default", "-e",
            f"{inside}/extension.zip",
        )  # fmt: skip
        if done.returncode != 0 or "Installed" not in done.stdout:
            raise RuntimeError(f"installing the extension failed:\n{done.stdout}\n{done.stderr}")
        splash = "import bpy; bpy.context.preferences.view.show_splash = False; bpy.ops.wm.save_userpref()"
        done = self.run("env", env, "blender", "--background", "--python-expr", splash)
        if done.returncode != 0:
            raise RuntimeError(f"saving the preferences failed:\n{done.stdout}\n{done.stderr}")
        self._installed[key] = folder
        return folder

    def session(self, name: str, extension: Path, out: Path, timeout: float = 300) -> SessionRun:
        """Run ``sessions/<name>.py`` in a fresh Blender window with the extension installed; its
        console output, results and screenshots are copied into ``out``."""
        user = self._user_folder(extension)
        folder = self.root / "tmp" / f"contact-edit-session-{name}-{uuid.uuid4().hex[:8]}"
        shutil.copytree(user / "user", folder / "user", symlinks=True)
        for source in (HERE / "driver.py", *SESSIONS.glob("*.py")):
            shutil.copy(source, folder / source.name)
        inside = "/" + folder.relative_to(self.root).as_posix()
        expr = f"import sys; sys.path.insert(0, {inside!r}); import driver; driver.start({name!r})"
        width, height = SCREEN
        script = textwrap.dedent(
            f"""
            Xvfb -displayfd 3 -screen 0 {width}x{height}x24 -nolisten tcp \
                3>{inside}/display 2>{inside}/xvfb.log &
            xvfb=$!
            for i in $(seq 100); do [ -s {inside}/display ] && break; sleep 0.1; done
            export DISPLAY=:$(cat {inside}/display)
            export BLENDER_USER_RESOURCES={inside}/user CONTACT_EDIT_SESSION={inside}
            timeout -k 5 {int(timeout)} blender --window-geometry 0 0 {width} {height} --no-window-focus \\
                --python-expr {_quote(expr)} > {inside}/blender.log 2>&1
            code=$?
            kill $xvfb; wait $xvfb 2>/dev/null
            exit $code
            """
        )
        began = time.monotonic()
        done = self.run("bash", "-c", script, timeout=timeout + 60)
        seconds = time.monotonic() - began
        out.mkdir(parents=True, exist_ok=True)
        log = (
            (folder / "blender.log").read_text(errors="replace") if (folder / "blender.log").exists() else ""
        )
        (out / "blender.log").write_text(log)
        results_file = folder / "results.json"
        results = json.loads(results_file.read_text()) if results_file.exists() else {}
        (out / "results.json").write_text(json.dumps(results, indent=1))
        shots = {}
        for png in sorted((folder / "shots").glob("*.png")) if (folder / "shots").exists() else []:
            shots[png.stem] = out / png.name
            shutil.copy(png, shots[png.stem])
        shutil.rmtree(folder, ignore_errors=True)
        return SessionRun(log + done.stderr, results, shots, done.returncode, seconds, out)

    def cleanup(self) -> None:
        for folder in self._installed.values():
            shutil.rmtree(folder, ignore_errors=True)
        self._installed.clear()


def _quote(text: str) -> str:
    return "'" + text.replace("'", "'\\''") + "'"
