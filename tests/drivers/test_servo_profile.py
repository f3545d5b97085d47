"""Servo profiles: the default ships today's register map; a broken profile is refused with
file:line:field; the codec handles both word orders, signs and scales; Settings validate."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from common.yaml_input import ConfigError
from drivers import rate_table_map as rm
from drivers.rate_table import Settings
from drivers.servo_profile import Register, builtin_profiles, load_profile

EXAMPLE = "servo-lowword-example"


def test_builtin_profiles_are_listed_and_load():
    assert {"servo-default", EXAMPLE} <= set(builtin_profiles())
    for name in builtin_profiles():
        assert load_profile(name).name == name


def test_default_profile_is_the_controllers_own_map():
    p = load_profile()
    regs = p.registers
    assert p.counts_per_rev == rm.COUNTS_PER_REV
    assert p.limits.max_rate_dps == rm.MAX_RATE_DPS
    assert p.word_order == "high_first"
    pairs = {
        "control": rm.Reg.CONTROL, "mode": rm.Reg.MODE, "position_command": rm.Reg.POS_CMD,
        "rate_command": rm.Reg.RATE_CMD, "accel_limit": rm.Reg.ACCEL_LIMIT,
        "move_time": rm.Reg.MOVE_TIME, "status": rm.Reg.STATUS, "fault_code": rm.Reg.FAULT_CODE,
        "encoder_counts": rm.Reg.ENCODER_COUNTS, "position": rm.Reg.POS_FB,
        "rate": rm.Reg.RATE_FB, "time": rm.Reg.SNAPSHOT_TIME, "model": rm.Reg.MODEL,
        "serial": rm.Reg.SERIAL, "firmware": rm.Reg.FIRMWARE,
    }
    for name, reg in pairs.items():
        assert getattr(regs, name).address == reg, name
    for reg, count in rm.STRING_REGS.items():
        assert {r.address: r.count for r in (regs.model, regs.serial, regs.firmware)}[reg] == count
    for name in ("enable", "halt", "fault_reset", "zero_encoder"):
        assert 1 << getattr(p.control_bits, name) == rm.Control[name.upper()]
    for name in ("ready", "enabled", "fault", "in_position", "at_rate", "moving",
                 "interlock_open"):
        assert 1 << getattr(p.status_bits, name) == rm.Status[name.upper()]
    assert (p.modes.idle, p.modes.position, p.modes.rate) == (
        rm.Mode.IDLE, rm.Mode.POSITION, rm.Mode.RATE
    )
    for fault, text in rm.FAULT_TEXT.items():
        if fault != rm.Fault.NONE:
            assert p.fault_text(int(fault)) == text


@pytest.mark.parametrize(
    ("type_", "scale", "value", "low_first", "words"),
    [
        ("i32", 0.001, -12.345, False, [0xFFFF, 0xCFC7]),
        ("i32", 0.001, -12.345, True, [0xCFC7, 0xFFFF]),
        ("u32", 1e-6, 4294.967295, True, [0xFFFF, 0xFFFF]),
        ("i16", 0.01, -3.0, False, [0xFED4]),
        ("u16", 0.5, 100.0, False, [200]),
    ],
)
def test_codec_round_trips_with_word_order_sign_and_scale(type_, scale, value, low_first, words):
    p = load_profile(EXAMPLE if low_first else "servo-default")
    reg = Register(address=10, type=type_, scale=scale)
    assert p.encode(reg, value) == words
    assert p.decode(reg, [0] * 10 + words, 0) == pytest.approx(value)


def test_encode_refuses_a_value_that_does_not_fit():
    p = load_profile()
    with pytest.raises(ValueError, match="does not fit"):
        p.encode(Register(address=0, type="u16", scale=1.0), -1)


def _write_variant(tmp_path: Path, old: str, new: str) -> tuple[Path, int]:
    src = (Path(load_profile.__code__.co_filename).parent / "profiles" / f"{EXAMPLE}.yaml")
    text = src.read_text()
    assert old in text
    text = text.replace(old, new)
    path = tmp_path / "drive.yaml"
    path.write_text(text)
    line = next(i for i, s in enumerate(text.splitlines(), 1) if new.split("\n")[-1] in s)
    return path, line


@pytest.mark.parametrize(
    ("old", "new", "field", "what"),
    [
        ("status:           {address: 1200, type: u16}",
         "status:           {address: 1200, type: i32}", "registers", "status must be of type u16"),
        ("rate:             {address: 1206, type: i32, scale: 0.01}",
         "rate:             {address: 1205, type: i32, scale: 0.01}", "registers", "overlaps"),
        ("counts_per_rev: 4194304", "counts_per_rev: 0", "counts_per_rev", "greater than"),
        ("word_order: low_first", "word_order: middle", "word_order", "high_first"),
        ("control_bits: {enable: 8", "control_bits: {enable: 9", "control_bits", "both 9"),
        ("  max_rate_dps: 600.0", "  max_rate_dps: 600.0\n  max_jerk: 5", "limits.max_jerk",
         "unknown field"),
        ("time:             {address: 1202, type: u32, scale: 0.001}",
         "time:             {address: 1402, type: u32, scale: 0.001}", "registers",
         "at most 125"),
    ],
)
def test_a_broken_profile_is_refused_naming_file_line_and_field(
    tmp_path, old, new, field, what
):
    path, line = _write_variant(tmp_path, old, new)
    with pytest.raises(ConfigError) as info:
        load_profile(path)
    msg = str(info.value)
    assert f"field {field}" in msg and what in msg
    assert msg.startswith(f"{path}:")
    if field != "registers":  # a model-level check points at the mapping's first line
        assert f"{path}:{line}:" in msg


def test_settings_refuse_an_unknown_profile_listing_the_built_in_ones():
    with pytest.raises(ValidationError, match="servo-default"):
        Settings.model_validate({"address": "10.0.0.2:502", "profile": "akd-typo"})


def test_settings_carry_a_broken_profile_files_lines(tmp_path):
    path, line = _write_variant(tmp_path, "counts_per_rev: 4194304", "counts_per_rev: -4")
    with pytest.raises(ValidationError) as info:
        Settings.model_validate({"address": "10.0.0.2:502", "profile": str(path)})
    assert f"{path}:{line}: field counts_per_rev" in str(info.value)


def test_settings_defaults_and_address_form():
    s = Settings.model_validate({"address": "192.168.1.20:502"})
    assert (s.profile, s.device_id, s.timeout_s) == ("servo-default", 1, 1.0)
    for bad in ("192.168.1.20", "host:port", ":502", "h:70000"):
        with pytest.raises(ValidationError, match="host:port"):
            Settings.model_validate({"address": bad})
    with pytest.raises(ValidationError):
        Settings.model_validate({"address": "h:502", "unit": 3})


@given(
    type_=st.sampled_from(["u16", "i16", "u32", "i32"]),
    low_first=st.booleans(),
    fraction=st.floats(min_value=0.0, max_value=1.0),
)
def test_codec_round_trips_every_raw_value_in_range(type_, low_first, fraction):
    p = load_profile(EXAMPLE if low_first else "servo-default")
    reg = Register(address=3, type=type_, scale=0.001)
    lo = -(1 << (reg.bits - 1)) if reg.signed else 0
    raw = lo + int(fraction * ((1 << reg.bits) - 1))
    words = p.encode(reg, raw / 1000)
    assert len(words) == reg.words and all(0 <= w <= 0xFFFF for w in words)
    assert p.decode(reg, [7, 7, 7, *words], 0) == pytest.approx(raw / 1000, abs=1e-9)
    assert p.decode(reg, [7, 7, 7, *words], 0, raw=True) == raw & ((1 << reg.bits) - 1)
