"""The command line's progress output: bars on a terminal, plain periodic lines anywhere else."""

import io
import re

from contact_edit_addon.commands.cli import _StageBars, main


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_without_a_terminal_progress_is_plain_lines_at_tenths():
    stream, clock = io.StringIO(), Clock()
    with _StageBars(stream=stream, clock=clock, tty=False) as bars:
        for done in range(1001):
            clock.now = 100.0 + 0.01 * done  # 10 s for the stage: never 5 s between tenths
            bars("full", done, 1000)
        clock.now = 111.0
        bars("refine", 0, 30)
        clock.now = 112.0
        bars("refine", 1, 30)
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    full = [line for line in lines if line.startswith("  full")]
    # When the stage starts, after each tenth, and when it ends: 11 lines, not 1001.
    assert [int(re.search(r"(\d+)/1000", line).group(1)) for line in full] == list(range(0, 1001, 100))
    assert full[0] == "  full      0/1000 (0%), 0:00 elapsed"
    assert full[5] == "  full      500/1000 (50%), 0:05 elapsed, ~0:05 left"  # from the stage's rate so far
    assert full[-1] == "  full      1000/1000 (100%), 0:10 elapsed"
    # A stage that ends before its total (closed) still gets its last state, without an estimate.
    assert lines[-2:] == ["  refine    0/30 (0%), 0:00 elapsed", "  refine    1/30 (3%), 0:01 elapsed"]


def test_without_a_terminal_a_slow_stage_reports_every_few_seconds():
    stream, clock = io.StringIO(), Clock()
    with _StageBars(stream=stream, clock=clock, tty=False, every=5.0) as bars:
        for done in range(21):  # 2 s a step, 1/200 of the stage a step: the time makes the lines
            clock.now = 100.0 + 2.0 * done
            bars("full", done, 4000)
    counts = [int(re.search(r"(\d+)/4000", line).group(1)) for line in stream.getvalue().splitlines()]
    assert counts == [0, 3, 6, 9, 12, 15, 18, 20]  # 6 s apart (the first step past 5 s), then the last


def test_on_a_terminal_the_bar_is_redrawn_in_place_with_elapsed_and_remaining_time():
    stream, clock = io.StringIO(), Clock()
    bars = _StageBars(stream=stream, clock=clock, tty=True)
    bars("root", 0, 40)
    clock.now += 30.0
    bars("root", 10, 40)
    clock.now += 0.01  # too soon to redraw
    bars("root", 11, 40)
    draws = stream.getvalue().split("\r")[1:]
    assert len(draws) == 2 and "\n" not in stream.getvalue()
    assert draws[1].startswith("  root      [#######.......................] 10/40 (25%)")
    assert draws[1].endswith("0:30 elapsed, ~1:30 left")
    clock.now += 1.0
    bars("full", 0, 5)  # the next stage: the last one's bar is finished on its own line
    bars.close()
    finished, rest = stream.getvalue().split("\n", 1)
    assert (
        finished.split("\r")[-1].rstrip()
        == "  root      [########......................] 11/40 (27%), 0:31 elapsed"
    )
    assert rest.startswith("\r  full      [") and rest.endswith("\n")


def test_a_bar_whose_total_is_a_budget_says_at_most():
    stream, clock = io.StringIO(), Clock()
    with _StageBars(stream=stream, clock=clock, tty=False, capped=True) as bars:
        bars("solving", 1, 2000, "energy 438.7")
        clock.now += 1.0
        bars("solving", 201, 2000, "energy 12.5")
        clock.now += 0.5
        bars("solving", 251, 2000, "energy 11")
    assert stream.getvalue().splitlines() == [
        "  solving   1/2000 energy 438.7, 0:00 elapsed",
        "  solving   201/2000 energy 12.5, 0:01 elapsed, at most ~0:08 left",
        "  solving   251/2000 energy 11, 0:01 elapsed",  # converged: the last state, no estimate
    ]


def test_a_bar_interrupted_mid_stage_ends_its_line():
    stream = io.StringIO()
    try:
        with _StageBars(stream=stream, clock=Clock(), tty=True) as bars:
            bars("full", 3, 10)
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    assert stream.getvalue().endswith("\n")  # the message after it starts on a line of its own


def test_synthesize_logs_plain_lines_to_a_pipe(tmp_path, capsys):
    """capsys's stderr is not a terminal, as in a CI log: no carriage returns, a handful of lines."""
    path = tmp_path / "m.npz"
    assert main(["synthesize", str(path), "--object", "sphere", "--frames", "44", "--density", "2"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and err
    assert len(err.splitlines()) <= 40
    assert all(re.fullmatch(r"  \S+ +\d+/\d+ \(\d+%\), \d+:\d\d elapsed(, ~\d+:\d\d left)?", line)
               for line in err.splitlines())  # fmt: skip
