"""docs/fixture-protocol.md against the code: its worked examples are decoded by the station's
own parser and must say what the page says they say, so the specification cannot drift."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np
import pytest

from drivers import fixture_protocol as fp
from drivers.part_codes import ADIS16130

DOC = Path(__file__).resolve().parents[2] / "docs" / "fixture-protocol.md"


@pytest.fixture(scope="module")
def text() -> str:
    return DOC.read_text(encoding="utf-8")


def example(text: str, name: str) -> bytes:
    m = re.search(rf"<!-- example: {re.escape(name)} -->\s*```text\n(.*?)```", text, re.S)
    assert m is not None, f"worked example {name!r} not found in {DOC.name}"
    return bytes.fromhex(m.group(1))


def field_table(text: str) -> dict[str, tuple[int, bytes, int]]:
    """The worked sample's table: field -> (offset, bytes, first integer of its value)."""
    rows = re.findall(r"^\| (\d+) \| `([0-9A-F ]+)` \| (\w+) \| (\d+)[^|]*\|$", text, re.M)
    return {name: (int(off), bytes.fromhex(hexes), int(value))
            for off, hexes, name, value in rows}


def test_the_worked_sample_frame_decodes_to_what_the_page_says(text: str) -> None:
    frame = example(text, "sample")
    assert len(frame) == fp.SAMPLE_FRAME_SIZE
    table = field_table(text)
    assert b"".join(b for _, b, _ in sorted(table.values())) == frame  # the table is the frame
    for off, raw, _ in table.values():
        assert frame[off : off + len(raw)] == raw
    res = fp.FrameParser().feed(frame)
    assert (res.frames_corrupted, res.bytes_discarded, res.replies) == (0, 0, [])
    assert res.seq.tolist() == [table["seq"][2]]
    assert res.time_s[0] == pytest.approx(table["time"][2] * 1e-6, abs=1e-9)
    assert res.rate_code.tolist() == [table["rate"][2]]
    assert res.temp_code.tolist() == [table["temperature"][2]]
    assert res.status.tolist() == [table["status"][2]]
    assert res.status[0] & fp.SampleStatus.ENCODER_LATCHED
    assert res.encoder.tolist() == [table["encoder"][2]]
    assert zlib.crc32(frame[2:-4]) == table["CRC"][2] == int.from_bytes(frame[-4:], "big")
    assert (frame[2], frame[3]) == (table["type"][2], table["length"][2])
    # the units the page gives for the example (10 deg/s, 25 C for the shipped product)
    assert ADIS16130.rate_code_to_dps(res.rate_code)[0] == pytest.approx(10.0, abs=1e-12)
    assert ADIS16130.temp_code_to_c(res.temp_code)[0] == pytest.approx(25.0, abs=1e-12)
    # and the station's encoder writes exactly these bytes for these values
    again = fp.encode_samples(res.seq, np.array([table["time"][2]]), res.rate_code,
                              res.temp_code, res.status, np.array([-1000]))
    assert again == frame


def test_the_worked_legacy_frame_is_the_same_sample_without_its_encoder(text: str) -> None:
    frame = example(text, "legacy-sample")
    assert len(frame) == fp.LEGACY_SAMPLE_FRAME_SIZE and frame[3] == 13
    res = fp.FrameParser().feed(frame + example(text, "sample"))  # mixed in one stream
    assert res.frames_corrupted == 0 and res.bytes_discarded == 0
    assert res.seq.tolist() == [4660, 4660]
    assert res.rate_code[0] == res.rate_code[1] and res.temp_code[0] == res.temp_code[1]
    assert res.encoder[0] == 0 and res.status[0] == 0


def test_the_worked_reply_and_the_crc_check_value(text: str) -> None:
    res = fp.FrameParser().feed(example(text, "reply-ok"))
    assert res.replies == ["OK"] and res.frames_corrupted == 0
    check = re.search(r"`123456789` is `0x([0-9A-F]{8})`", text)
    assert check is not None and zlib.crc32(b"123456789") == int(check.group(1), 16)


def test_the_page_lists_every_command_status_bit_and_reply_code(text: str) -> None:
    for attr in vars(fp.Command):
        if attr.isupper():
            word = getattr(fp.Command, attr).split()[0]
            assert f"`{word}" in text, f"command {word} is not in {DOC.name}"
    for bit in fp.SampleStatus:
        assert re.search(rf"\| {bit.bit_length() - 1} \| `0x{int(bit):02X}` \| {bit.name} \|",
                         text), bit
    for code in fp.ReplyError:
        assert re.search(rf"^\| {int(code)} \| ", text, re.M), code
    assert f"0..{fp.MAX_REPLY_PAYLOAD}" in text
    for hz in fp.OUTPUT_RATES_HZ:
        assert str(hz) in text
