"""The README says what the add-on does: its hotkey table lists exactly the registered hotkeys, and its
examples of files from elsewhere run as written."""

import re
from pathlib import Path

from contact_edit_addon import keymaps

README = (Path(__file__).resolve().parent.parent / "README.md").read_text(encoding="utf-8")
#: The README's tool names for the operators that have hotkeys.
TOOLS = {
    "Paint": "contact_edit.paint", "Axis": "contact_edit.axis", "Transfer": "contact_edit.transfer",
    "Translate": "contact_edit.translate", "Rotate": "contact_edit.rotate", "Bend": "contact_edit.bend",
    "Solve": "contact_edit.solve", "Flex to contact": "contact_edit.flex_to_contact",
    "Key device pose": "contact_edit.device_key",
}  # fmt: skip


def test_the_hotkey_table_lists_the_registered_hotkeys():
    rows = dict(re.findall(r"^\| ([A-Z][a-z ]+) \| ((?:Ctrl|Shift|Alt)\+[^|]+?) \|", README, re.MULTILINE))
    assert set(rows) == set(TOOLS)
    assert {TOOLS[tool]: key for tool, key in rows.items()} == {
        idname: keymaps.shortcut(idname) for idname, *_ in keymaps.HOTKEYS
    }


def _section(title: str) -> str:
    start = README.index(f"## {title}")
    end = README.find("\n## ", start + 1)
    return README[start : end if end != -1 else None]


def test_files_from_elsewhere_python_runs_as_written(tmp_path, monkeypatch, capsys):
    (code,) = re.findall(r"```python\n(.*?)```", _section("Files from elsewhere"), re.DOTALL)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("['f 12 0.2 0.3 0.5', 'e ") and lines[0].endswith(" 0.5']")
    assert lines[1] == "[2 0]"
    assert lines[-1] == "(3, 54)"
    assert {"hand.obj", "contacts.json", "hand.virtualmarkers", "motion.kmexp"} <= {
        p.name for p in tmp_path.iterdir()
    }


def test_files_from_elsewhere_import_grab_line_runs_as_written(tmp_path, monkeypatch, capsys):
    """The README's import-grab line, on files laid out as the authors' exporter names them (made here
    from a short synthetic motion)."""
    import shlex

    from contact_edit_addon.cli import main
    from geodesics import save_mesh
    from solver.retarget import Motion, save_grab, synthetic

    (line,) = re.findall(r"```sh\n(.*?)\n```", _section("Files from elsewhere"), re.DOTALL)
    command, *args = shlex.split(line)
    assert command == ".venv/bin/contact-edit"
    motion = synthetic.generate("sphere", frames=44, seed=0, density=2)
    files = dict(zip(args[2::2], args[3::2], strict=True))
    monkeypatch.chdir(tmp_path)
    Path(args[1]).parent.mkdir(parents=True)
    save_grab(motion, args[1])
    save_mesh(motion.hand_mesh, files["--hand-mesh"])
    save_mesh(motion.object_mesh, files["--object-mesh"])
    assert main(args) == 0
    imported = Motion.load(files["-o"])
    assert imported.n_frames == 44 and imported.hand_contacts is not None
    assert "contact-edit import-grab: Motion(" in capsys.readouterr().out
