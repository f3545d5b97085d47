"""TableTwin serving a servo profile: the default profile's layout gives the registers the
controller's own map gives; a profile the world's table cannot back is refused."""

from __future__ import annotations

import pytest

from drivers.servo_profile import STATUS_FIELDS, load_profile
from drivers.sim.config import SimConfig
from drivers.sim.profile_image import ProfileImage
from drivers.sim.world import World


def test_default_profile_image_matches_the_native_registers():
    world = World(SimConfig(), speed=100.0)
    table = world.table
    t = world.advance()
    regs = table.registers(t)
    table.write(t, 0, [1], regs)  # enable
    table.write(t, 1, [2, 0, 0, 0, 20_000, 0, 50_000, 0, 0], table.registers(t))  # 20 deg/s
    t += 3.7
    image = ProfileImage(load_profile("servo-default"), table)
    native = table.registers(t)
    ours = image.image(t)
    assert image.first == 0
    declared = {
        a for f in image.fields.values()
        for a in range(f.address, f.address + (getattr(f, "count", 0) or f.words))
    }
    assert declared >= set(range(0, 10)) | set(range(20, 30)) | set(range(40, 60))
    for address in sorted(declared):
        if address in (28, 29):  # the snapshot clock: native truncates, the image rounds
            continue
        assert ours[address] == native[address], address
    first, end = load_profile().registers.span(STATUS_FIELDS)
    assert ours[first:end] != [0] * (end - first)


def test_profile_write_plans_once_and_reads_back_in_its_layout():
    world = World(SimConfig.model_validate({"table": {"counts_per_rev": 1 << 22}}), speed=1.0)
    profile = load_profile("servo-lowword-example")
    image = ProfileImage(profile, world.table)
    t = world.advance()
    assert image.write(t, 1000, [1 << 8]) is None  # enable bit 8
    assert world.table.enabled
    block = image.image(t)[1100 - image.first : 1109 - image.first]
    block[0] = 3  # rate mode
    block[2:4] = [2000, 0]  # 20.00 deg/s, low word first
    assert image.write(t, 1100, block) is None
    assert world.table.mode.name == "RATE" and world.table.rate_cmd_mdps == 20_000
    assert image.write(t, 1103, [0]) is not None  # one word of a pair: refused
    assert image.write(t, 1200, [0]) is not None  # status: not writable


def test_profile_whose_encoder_differs_from_the_simulated_table_is_refused():
    world = World(SimConfig(), speed=1.0)
    with pytest.raises(ValueError, match="counts_per_rev"):
        ProfileImage(load_profile("servo-lowword-example"), world.table)
