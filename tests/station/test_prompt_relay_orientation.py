"""The prompt relay forwards a reorientation prompt's face, and only then (a single-axis
prompt's line keeps exactly the keys it had)."""

from __future__ import annotations

import json
import socket

from procedures.runtime.progress import ProgressEvent
from station.prompt_relay import PromptRelay


def _lines(events: list[ProgressEvent]) -> list[dict]:
    server = socket.create_server(("127.0.0.1", 0))
    relay = PromptRelay(f"127.0.0.1:{server.getsockname()[1]}")
    try:
        for event in events:
            relay(event)
        conn, _ = server.accept()
        conn.settimeout(2.0)
        data = b""
        while data.count(b"\n") < relay.sent:
            data += conn.recv(4096)
        conn.close()
    finally:
        relay.close()
        server.close()
    return [json.loads(line) for line in data.splitlines()]


def test_orientation_is_forwarded_only_on_prompts_that_carry_it() -> None:
    turn = ProgressEvent(kind="prompt", step="orient", condition="bias",
                         message="Turn socket 1's cube so that face +Y points up",
                         sockets={1: "PROMPT"}, orientation="+y")
    stop = ProgressEvent(kind="prompt", step="manual_stop",
                         message="Turn socket 2's fixture by hand to the other stop",
                         sockets={2: "PROMPT"})
    first, second = _lines([turn, stop])
    assert first["orientation"] == "+y" and first["sockets"] == {"1": "PROMPT"}
    assert first["message"] == "Turn socket 1's cube so that face +Y points up"
    assert set(second) == {"kind", "message", "sockets", "step", "condition", "monotonic_s"}


def test_progress_event_orientation_defaults_to_none() -> None:
    event = ProgressEvent(kind="prompt")
    assert event.orientation is None and event.to_dict()["orientation"] is None


def test_link_speed_counts_three_axis_frames() -> None:
    from station.link_speed import link_speed_problem

    assert link_speed_problem(200, 115_200) is None
    assert link_speed_problem(200, 115_200, axes=3) is None  # 80,000 baud
    problem = link_speed_problem(200, 57_600, axes=3)  # 80,000 > 90 % of 57,600
    assert problem is not None and "40-byte" in problem and "115,200" in problem
    assert link_speed_problem(200, 57_600) is None  # 50,000 baud of 25-byte frames
