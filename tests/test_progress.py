"""The one progress report (trustnav.progress): a bar on a terminal, a log line every few seconds
elsewhere, never 100 % for a run that stopped early."""

from __future__ import annotations

import io
import re

import pytest

from trustnav.progress import Progress, labelled_reporter, step_reporter


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_off_a_terminal_a_line_every_few_seconds_while_it_runs():
    out, clock = io.StringIO(), Clock()
    bar = Progress(100, "sweep", "ep", stream=out, every=5.0, clock=clock)
    for k in range(1, 101):
        clock.t = 0.5 * k  # 50 s in all
        bar.update()
        bar.note(failed=k // 40)
        if k == 30:  # a log read while the run goes on shows how far it got
            assert "trustnav: sweep: 30/100 ep (30 %), 0:15 elapsed, failed=0" in out.getvalue().splitlines()
    bar.close()
    lines = out.getvalue().splitlines()
    assert 9 <= len(lines) <= 11  # one per 5 s and the last one, not one per episode
    assert lines[-1] == "trustnav: sweep: done: 100/100 ep (100 %), 0:50 elapsed, failed=2"
    assert "\r" not in out.getvalue()  # plain lines for a file


def test_an_interrupted_run_never_reads_100_percent():
    out, clock = io.StringIO(), Clock()
    bar = Progress(40.0, "case-1", "s sim", decimals=1, stream=out, clock=clock)
    with pytest.raises(KeyboardInterrupt), bar:
        clock.t = 6.0
        bar.set(39.9)  # 99.75 %: rounded down
        raise KeyboardInterrupt
    last = out.getvalue().splitlines()[-1]
    assert last == "trustnav: case-1: interrupted: 39.9/40.0 s sim (99 %), 0:06 elapsed"
    assert "100 %" not in out.getvalue()


def test_on_a_terminal_an_interrupted_bar_stays_where_it_stopped():
    out = Terminal()
    with pytest.raises(KeyboardInterrupt), step_reporter("case-1 (render)", 25.0, stream=out) as progress:
        for k in range(50):
            progress(0.1 * k, 25.0)
        raise KeyboardInterrupt
    final = out.getvalue().split("\r")[-1]
    assert "case-1 (render) (interrupted)" in final
    assert "4.9/25 s sim" in final
    assert "100%" not in out.getvalue()


def test_a_drive_that_reaches_its_goal_early_is_shown_complete():
    out = Terminal()
    with step_reporter("case-1 (render)", 25.0, stream=out) as progress:
        for k in range(95):
            progress(0.1 * k, 25.0)  # the goal at 9.4 s of 25
    final = out.getvalue().split("\r")[-1]
    assert re.search(r"100%.*9\.4/9 s sim", final), final
    log, clock = io.StringIO(), Clock()
    with step_reporter("case-1", 25.0, stream=log, clock=clock) as progress:
        clock.t = 3.0  # the bar opens at the first report (once the world has opened)
        progress(1.0, 25.0)
        clock.t = 6.0
        progress(9.4, 25.0)
    assert log.getvalue().splitlines()[-1] == "trustnav: case-1: done: 9.4/9.4 s sim (100 %), 0:03 elapsed"


def test_a_comparison_gets_one_report_per_run_each_closed():
    out = io.StringIO()
    with labelled_reporter("case-1", stream=out) as progress:
        for label in ("trust-aware", "trust 0", "trust 1"):
            for k in range(11):
                progress(label, float(k), 10.0)
    lines = out.getvalue().splitlines()
    assert [ln.split(":")[1].strip() for ln in lines] == ["case-1 trust-aware", "case-1 trust 0", "case-1 trust 1"]
    assert all(": done: 10.0/10.0 s sim (100 %)" in ln for ln in lines)


def test_messages_and_quiet():
    out = io.StringIO()
    bar = Progress(3, "estimate", "frame", stream=out)
    bar.write("trustnav: skipped frame b.png: not an image")
    bar.close()
    assert out.getvalue().splitlines()[0] == "trustnav: skipped frame b.png: not an image"
    quiet = io.StringIO()
    with Progress(3, "x", enabled=False, stream=quiet) as bar:
        bar.update(3)
    assert quiet.getvalue() == ""
    with pytest.raises(ValueError, match="progress total must be >= 0"):
        Progress(-1)


def test_the_clis_and_campaigns_have_no_progress_code_of_their_own():
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "src" / "trustnav"
    commands = sorted((src / "cli").glob("*.py"))
    assert len(commands) >= 8  # the cli package: one module per command, common, __init__, __main__
    for path in [*commands, src / "campaigns" / "runner.py"]:
        assert "tqdm" not in path.read_text(), f"{path.name} draws its own bar: use trustnav.progress"
    # the commands with a long loop report through trustnav.progress
    for path in [src / "cli" / f"{name}.py" for name in ("estimate", "drive", "compare", "demo")] + [
        src / "campaigns" / "runner.py"
    ]:
        assert "trustnav.progress import" in path.read_text(), path.name
