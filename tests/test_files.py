"""Files written whole or not at all, with the permissions any new file of the user gets; JSON read with
errors naming the file."""

import os
import stat

import pytest

from geodesics import ContactError
from geodesics.files import atomic_file, read_json, write_atomically


def test_outputs_get_the_umasks_permissions_not_private_ones(tmp_path):
    old = os.umask(0o022)
    try:
        write_atomically(tmp_path / "a.json", "{}")
        write_atomically(tmp_path / "b.bin", b"\x00\x01")
    finally:
        os.umask(old)
    for name in ("a.json", "b.bin"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644


def test_text_is_utf8_and_bytes_are_kept(tmp_path):
    write_atomically(tmp_path / "t.txt", "λ θ\n")
    write_atomically(tmp_path / "b.bin", bytes(range(256)))
    assert (tmp_path / "t.txt").read_bytes() == "λ θ\n".encode()
    assert (tmp_path / "b.bin").read_bytes() == bytes(range(256))


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "kept.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(target) as f:
        f.write(b"half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.json"]


def test_json_errors_name_the_file(tmp_path):
    with pytest.raises(ContactError, match=r"cannot read the contact file .*missing\.json: there is no"):
        read_json(tmp_path / "missing.json", "contact file", ContactError)
    (tmp_path / "bad.json").write_bytes(b"\xff{")
    with pytest.raises(ContactError, match=r"bad\.json: not valid JSON"):
        read_json(tmp_path / "bad.json", "contact file", ContactError)
    with pytest.raises(ContactError, match="cannot read the contact file"):
        read_json(tmp_path, "contact file", ContactError)  # a directory
    (tmp_path / "ok.json").write_text('{"a": [1, 2]}')
    assert read_json(tmp_path / "ok.json", "contact file", ContactError) == {"a": [1, 2]}
