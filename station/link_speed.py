"""The fixture link's baud arithmetic: whether a fixture at a given baud carries a
procedure's output rate in the product's sample frames, and what to change when not."""

from __future__ import annotations

from drivers.fixture_protocol import (
    OUTPUT_RATES_HZ,
    SAMPLE3_FRAME_SIZE,
    SAMPLE_FRAME_SIZE,
    sample_stream_baud,
)

# share of the fixture link's baud the sample stream may take; the rest carries replies
LINK_BAUD_SHARE = 0.9
_STANDARD_BAUDS = (19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600)


def link_speed_problem(output_rate_hz: int, baud: int, axes: int = 1) -> str | None:
    """Why a fixture link at `baud` cannot carry samples at `output_rate_hz`, or None
    (`axes=3`: a three-axis part's longer frames)."""
    needed = sample_stream_baud(output_rate_hz, axes)
    if needed <= LINK_BAUD_SHARE * baud:
        return None
    enough = [b for b in _STANDARD_BAUDS if needed <= LINK_BAUD_SHARE * b]
    raise_to = f"to {enough[0]:,}" if enough else f"above {needed / LINK_BAUD_SHARE:,.0f}"
    fits = [r for r in OUTPUT_RATES_HZ if sample_stream_baud(r, axes) <= LINK_BAUD_SHARE * baud]
    lower_to = f" to {fits[-1]} Hz or less" if fits else ""
    frame_size = SAMPLE3_FRAME_SIZE if axes == 3 else SAMPLE_FRAME_SIZE
    return (
        f"an output rate of {output_rate_hz} Hz needs {needed:,} baud for its "
        f"{frame_size}-byte sample frames, more than {LINK_BAUD_SHARE:.0%} of the "
        f"fixture's {baud:,} baud (the rest is kept for replies): raise instruments.fixture.baud "
        f"in station.yaml {raise_to} (the fixtures must be set to the same rate) or lower "
        f"power.output_rate_hz in the procedure{lower_to}"
    )
