"""The README says what the add-on does: its hotkey table lists exactly the registered hotkeys."""

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
