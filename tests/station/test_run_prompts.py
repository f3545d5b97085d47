"""`station run` prints each operator prompt on its own line (BRIEF contract 2)."""

from __future__ import annotations

import io

from procedures.progress import ProgressEvent
from station.cli_run import ProgressDisplay


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
