"""`progress.py`: the progress bar names its pass and reads the time left from the work's own pace."""

import io
import pickle

from smorphi_rl import progress


def test_a_progress_line_of_two_passes_names_each(capsys):
    """A count that goes back down starts the next pass under its own label, with its own clock."""
    show = progress.progress_line(("x: keyed", "x: settled"))
    show(10, 10)
    show(3, 10)
    show(10, 10)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("x: keyed [") and lines[0].count("#") == 30
    assert all(line.startswith("x: settled [") for line in lines[1:]) and len(lines) == 3


def test_a_pass_reported_ended_twice_writes_its_full_bar_once(capsys):
    """`search exhaustive` reports the end of its pass twice: off a terminal the full bar was written twice."""
    show = progress.progress_line(("x: keyed", "x: settled"))
    for done in (4, 8, 8, 2, 8, 8):
        show(done, 8)
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" [")[0] for line in lines] == ["x: keyed", "x: keyed", "x: settled", "x: settled"]


def test_the_time_left_leaves_out_the_wait_for_the_first_count(capsys, monkeypatch):
    """The first count of `search optimum` comes after the planner compiles (about 35 s): at the rate from the
    start it read "about 34 min more" for a search that had seconds left."""
    clock = iter([0.0, 35.0, 41.0])
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    show = progress.progress_line("x")
    show(100_000, 6_000_000)  # 35 s to the first count: compiling
    show(3_100_000, 6_000_000)  # 3,000,000 in 6 s: 2,900,000 left in about 6 s
    err = capsys.readouterr().err
    assert "min more" not in err
    assert err.splitlines()[-1].endswith(" 500,000/s, 6s left")  # the rate the time left is read from


def test_a_long_time_left_is_said_once_with_the_hint(capsys, monkeypatch):
    clock = iter([0.0, 1.0, 5.0, 9.0])
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    show = progress.progress_line("x", hint="a coarser --step")
    for done in (10, 20, 30):  # 10 shapes in 4 s: a million takes days
        show(done, 1_000_000)
    warned = [line for line in capsys.readouterr().err.splitlines() if "min more" in line]
    assert warned == ["x: about 6667 min more at this rate; a coarser --step"]


def test_an_exhaustive_search_shows_both_passes_when_its_plans_fit_one_chunk(capsys, tmp_path):
    """Its settling pass reported only its end, which the bar took for the first pass's end reported again."""
    from pathlib import Path

    from smorphi_rl.cli import main

    map_1 = str(Path(__file__).resolve().parents[1] / "maps" / "map-1.yaml")
    assert main(["search", "exhaustive", "--map", map_1, "--step", "30", "--log-dir", str(tmp_path)]) == 0
    labels = [line.split(" [")[0] for line in capsys.readouterr().err.splitlines() if " [" in line]
    assert labels[0] == "exhaustive: shapes keyed by footprint" and labels[-1] == "exhaustive: shapes settled"


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_status_line_off_a_terminal_writes_every_so_often_and_when_forced(monkeypatch):
    clock = iter([0.0, 4.0, 6.0, 11.0])
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    out = io.StringIO()
    status = progress.StatusLine(out, every_s=10)
    for when, force in ((0, False), (4, False), (6, True), (11, False)):
        if status.due(force):
            status.write(f"at {when}")
    assert out.getvalue() == "at 0\nat 6\n"  # 11 s is 5 s after the forced line


def test_a_status_line_on_a_terminal_is_rewritten_in_place_and_cleared(monkeypatch):
    monkeypatch.setenv("COLUMNS", "500")  # a wide terminal: the cap holds
    out = _Terminal()
    status = progress.StatusLine(out)
    status.write("x" * 100)
    status.write("short", end=True)
    status.finish()  # the line was ended: nothing more
    assert out.getvalue() == "\r" + "x" * 100 + " " * 60 + "\r" + "short".ljust(progress.STATUS_WIDTH) + "\n"


def test_a_pickled_status_line_leaves_its_stream_behind(capsys):
    """Tune pickles its callbacks with the experiment's state; a stream does not pickle, and the loader's stderr
    (here not a terminal) is asked again whether it is one."""
    again = pickle.loads(pickle.dumps(progress.StatusLine(_Terminal())))
    again.write("restored")
    assert capsys.readouterr().err == "restored\n"


def test_a_bar_is_clamped_to_its_width():
    assert progress.bar(0.5, 10) == "[#####-----]" and progress.bar(1.7, 4) == "[####]"
    assert progress.bar(-1, 2) == "[--]"


def test_a_status_line_wider_than_the_terminal_is_written_whole_on_its_own(monkeypatch):
    """Padded to 160 characters, every rewrite on an 80-column terminal wrapped and left a row behind; cut to the
    width, the line lost its end (`train`'s greedy gap). Now a wide line is a line of its own, as in a log file."""
    clock = iter([0.0, 1.0, 2.0, 12.0])
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    monkeypatch.setenv("COLUMNS", "80")
    out = _Terminal()
    status = progress.StatusLine(out, every_s=10)
    assert status.due()
    status.write("short")
    assert status.due()  # in place: every line is due
    status.write("x" * 100)
    assert not status.due()  # a wide line is not rewritten in place: at most every 10 s, as off a terminal
    assert status.due()
    status.write("y" * 100)
    assert out.getvalue() == "\r" + "short".ljust(79) + "\r" + " " * 79 + "\r" + "x" * 100 + "\n" + "y" * 100 + "\n"


def test_a_terminal_that_does_not_know_its_width_gets_the_widest_line(monkeypatch):
    """A pty whose size was never set says 0 columns: the line was cut to 20 characters."""
    import os
    import pty

    monkeypatch.setenv("COLUMNS", "500")  # what the fallback reads first
    leader, follower = pty.openpty()
    try:
        with os.fdopen(follower, "w", closefd=False) as stream:
            assert os.get_terminal_size(follower).columns == 0
            assert progress.StatusLine(stream).width() == progress.STATUS_WIDTH
    finally:
        os.close(leader)
        os.close(follower)


def test_durations_read_in_the_units_a_person_uses():
    """A search's time left read "1,902 s left": long ones are minutes and hours."""
    from smorphi_rl.progress import fmt_duration

    assert [fmt_duration(s) for s in (6, 59.6, 61, 1902, 3600, 5830)] == ["6s", "1m 00s", "1m 01s", "31m 42s",
                                                                         "1h 00m", "1h 37m"]  # fmt: skip
