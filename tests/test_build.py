"""The extension build: our library wheel and the manifest (Blender's own validation of whole zips,
and installing them, is tested with the bpy module in test_extension.py)."""

import hashlib
import io
import tomllib
import zipfile
from base64 import urlsafe_b64encode

from contact_edit_addon.commands import build


def test_manifest_template_follows_blenders_rules():
    manifest = build.manifest_template()
    assert manifest["schema_version"] == "1.0.0"
    assert manifest["id"].isidentifier()
    assert len(manifest["tagline"]) <= 64 and not manifest["tagline"].endswith(".")
    for reason in manifest["permissions"].values():
        assert len(reason) <= 64 and not reason.endswith(".")
    parts = manifest["version"].split(".")
    assert len(parts) == 3 and all(part.isdigit() for part in parts)  # semantic version
    pyproject = tomllib.loads((build.project_root() / "pyproject.toml").read_text())
    assert manifest["version"] == pyproject["project"]["version"]
    assert "platforms" not in manifest and "wheels" not in manifest  # the build adds them


def test_manifest_text_adds_platforms_and_wheels():
    manifest = build.manifest_template()
    text = build._manifest_text(manifest, ["linux-x64"], ["./wheels/a-1.0-py3-none-any.whl"])
    parsed = tomllib.loads(text)
    assert parsed["platforms"] == ["linux-x64"]
    assert parsed["wheels"] == ["./wheels/a-1.0-py3-none-any.whl"]
    assert parsed["permissions"] == manifest["permissions"]
    assert {k: v for k, v in parsed.items() if k not in ("platforms", "wheels")} == manifest


def test_library_wheel_is_complete_reproducible_and_recorded():
    name, data = build.library_wheel("0.1.0")
    assert name == "contact_edit-0.1.0-py3-none-any.whl"
    assert build.library_wheel("0.1.0")[1] == data  # byte for byte
    archive = zipfile.ZipFile(io.BytesIO(data))
    names = set(archive.namelist())
    for package in build.LIBRARIES:
        assert f"{package}/__init__.py" in names
    assert "geodesics/exact.py" in names and not any("contact_edit_addon" in n for n in names)
    record = archive.read("contact_edit-0.1.0.dist-info/RECORD").decode().splitlines()
    for line in record:
        path, digest, size = line.split(",")
        if digest:
            content = archive.read(path)
            expected = urlsafe_b64encode(hashlib.sha256(content).digest()).rstrip(b"=").decode()
            assert digest == f"sha256={expected}"
            assert int(size) == len(content)
    assert {line.split(",")[0] for line in record} == names


def test_only_the_pinned_releases_are_bundled_whatever_else_the_cache_holds(tmp_path):
    """A wheel cache that also holds another release of a dependency (from an earlier pin) must not put
    both into the extension: which one Blender would install is then anyone's guess."""
    cache = tmp_path / "wheels"
    folder = cache / "3.13-linux-x64"
    folder.mkdir(parents=True)
    stale = folder / "scipy-1.15.3-cp313-cp313-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
    stale.write_bytes(b"stale")
    wheels = build.dependency_wheels("linux-x64", "3.13", cache)
    names = sorted(w.name.split("-")[0] + "==" + w.name.split("-")[1] for w in wheels)
    assert names == sorted(build.REQUIREMENTS["3.13"])
    assert stale not in wheels


def test_every_platform_names_pinned_pythons():
    assert set(build.PYTHONS) == set(build.PLATFORM_TAGS)
    for pythons in build.PYTHONS.values():
        assert {"3.11", "3.13"} <= set(pythons) <= set(build.REQUIREMENTS)
    assert "3.14" in build.PYTHONS["linux-x64"]  # distributions' Blender (Debian unstable: 5.2 on 3.14)
