"""`station run` prints each operator prompt on its own line (BRIEF contract 2)."""

from __future__ import annotations

import io

from procedures.runtime.progress import ProgressEvent
from station.cli.run import ProgressDisplay


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _prompt(**kw: object) -> ProgressEvent:
    return ProgressEvent(
        kind="prompt", step="manual_stop", condition="T25_V5",
        message="Turn socket 1's fixture by hand to the other stop", sockets={1: "PROMPT"},
        **kw,  # type: ignore[arg-type]
    )


def test_a_prompt_is_its_own_line_naming_the_sockets() -> None:
    out = io.StringIO()
    display = ProgressDisplay(out)
    display(ProgressEvent(kind="step", step="manual_stop", condition="T25_V5"))
    display(_prompt())
    display(ProgressEvent(kind="prompt_done", step="manual_stop", sockets={1: "RUNNING"}))
    lines = out.getvalue().splitlines()
    assert lines[1] == ">>> OPERATOR (socket 1): Turn socket 1's fixture by hand to the other stop"
    assert lines[2] == "    done (socket 1)"


def test_on_a_terminal_the_prompt_breaks_the_progress_line_and_rings() -> None:
    out = _Tty()
    display = ProgressDisplay(out)
    display(ProgressEvent(kind="progress", step="manual_stop", fraction=0.5))
    display(
        ProgressEvent(kind="prompt", message="Turn the fixtures", sockets={2: "P", 1: "P"})
    )
    text = out.getvalue()
    assert "\n\a>>> OPERATOR (sockets 1, 2): Turn the fixtures\n" in text


def _states(n: int) -> dict[int, str]:
    states = {s: "RUNNING" for s in range(1, n + 1)}
    states.update({3: "FAIL", 17: "FAIL", 9: "ERROR"})
    return states


def test_progress_lines_of_32_sockets_stay_within_the_width() -> None:
    # issue 26 (14): 32 sockets made 405-character lines in a log
    out = io.StringIO()
    display = ProgressDisplay(out)
    display(ProgressEvent(kind="step", step="thermal", condition="T45_V5.25", fraction=0.4,
                          remaining_s=900, station_time_s=1200, sockets=_states(32)))
    (line,) = out.getvalue().splitlines()
    assert len(line) <= 100, (len(line), line)
    assert line.endswith("29 RUNNING; FAIL: 3,17; ERROR: 9"), line  # every socket accounted


def test_on_a_terminal_the_line_fits_its_width_and_few_sockets_are_named() -> None:
    out = _Tty()
    display = ProgressDisplay(out, width=79)
    display(ProgressEvent(kind="progress", step="thermal", condition="T45_V5.25",
                          sockets=_states(32)))
    assert max(len(part) for part in out.getvalue().split("\r")) <= 79
    out = io.StringIO()
    display = ProgressDisplay(out)
    display(ProgressEvent(kind="step", step="bias", sockets={1: "RUNNING", 2: "FAIL"}))
    assert out.getvalue().rstrip().endswith("1:RUNNING 2:FAIL")


def test_without_a_terminal_each_phase_of_a_long_step_is_a_line() -> None:
    # the ramp's 20 minutes printed one line, then jumped to the next step at 95 %
    out = io.StringIO()
    display = ProgressDisplay(out)
    for phase, fraction in (("", 0.02), ("heating", 0.03), ("heating", 0.2), ("cooling", 0.5)):
        display(ProgressEvent(kind="step", step="ramp_calibration", phase=phase,
                              fraction=fraction, sockets={1: "RUNNING"}))
    lines = out.getvalue().splitlines()
    assert [line.split("]")[0] for line in lines] == ["[  2%", "[  3%", "[ 50%"]
    assert "ramp_calibration heating" in lines[1] and "ramp_calibration cooling" in lines[2]
