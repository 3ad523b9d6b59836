"""The ``contact-edit`` command."""

import pytest

from contact_edit_addon.cli import main


def test_bench_geodesics_prints_the_table(capsys):
    assert main(["bench", "geodesics", "--repeat", "1", "--rays", "20"]) == 0
    out = capsys.readouterr().out
    assert "exp_map: 20 rays" in out
    assert "log_map (exact)" in out
    assert "1M faces" in out and "GiB" in out
    assert "potpourri3d" in out and "pygeodesic" in out


def test_bad_arguments_are_refused(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "nothing"])
    with pytest.raises(SystemExit):
        main(["bench", "geodesics", "--repeat", "0"])
    assert "--repeat must be at least 1" in capsys.readouterr().err
