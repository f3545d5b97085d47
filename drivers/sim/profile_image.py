"""The simulated servo table's registers laid out by a servo profile (`drivers.servo_profile`).

`TableModel` speaks the station controller's own map (`drivers.rate_table_map`). A drive with
a user-defined map (another address block, low word first, other scales and bit numbers) is
served by translating: a read is the model's state at the request time encoded in the
profile's layout; a write is decoded to engineering values and applied to the model as one
write of its own registers, so a command group written in one request plans one motion.
Feedback that overflows its register wraps, as a drive's does. Register gaps inside the
command group accept writes and ignore them.
"""

from __future__ import annotations

from pymodbus.constants import ExcCodes

from drivers.rate_table_map import Control, Fault, Mode, Reg, Status
from drivers.servo_profile import COMMAND_FIELDS, Register, ServoProfile, Text
from drivers.sim.table import CommandRefusedError, TableModel, string_registers

_FAULT_KINDS = {
    Fault.OVERSPEED: "overspeed",
    Fault.FOLLOWING_ERROR: "following_error",
    Fault.ENCODER_LOSS: "encoder_loss",
    Fault.ESTOP: "estop",
}
_STATUS = {
    "ready": Status.READY, "enabled": Status.ENABLED, "fault": Status.FAULT,
    "in_position": Status.IN_POSITION, "at_rate": Status.AT_RATE, "moving": Status.MOVING,
    "interlock_open": Status.INTERLOCK_OPEN,
}
_CONTROL = {
    "enable": Control.ENABLE, "halt": Control.HALT, "fault_reset": Control.FAULT_RESET,
    "zero_encoder": Control.ZERO_ENCODER,
}
# profile command field -> the model's register (millidegree / millisecond units)
_NATIVE_CMD = {
    "position_command": Reg.POS_CMD, "rate_command": Reg.RATE_CMD,
    "accel_limit": Reg.ACCEL_LIMIT, "move_time": Reg.MOVE_TIME,
}


def _i32(hi: int, lo: int) -> int:
    v = (hi << 16) | lo
    return v - (1 << 32) if v & 0x80000000 else v


class ProfileImage:
    """Reads and writes of one `TableModel` in the layout of `profile`."""

    def __init__(self, profile: ServoProfile, table: TableModel) -> None:
        if profile.counts_per_rev != table.cpr:
            raise ValueError(
                f"servo profile {profile.name!r} declares {profile.counts_per_rev} counts per "
                f"revolution but the simulated table's encoder has {table.cpr}: set "
                "table.counts_per_rev in the sim config to the profile's"
            )
        kinds: dict[str, int] = {f.kind: f.code for f in profile.faults}
        missing = [k for k in _FAULT_KINDS.values() if k not in kinds]
        if missing:
            raise ValueError(
                f"servo profile {profile.name!r} has no fault code of kind {', '.join(missing)}: "
                "the simulated table could not report that fault"
            )
        self.profile = profile
        self.table = table
        self._fault_codes = {f: kinds[k] for f, k in _FAULT_KINDS.items()}
        regs = profile.registers
        self.fields: dict[str, Register | Text] = {
            n: getattr(regs, n) for n in type(regs).model_fields
        }
        self.first = min(f.address for f in self.fields.values())
        self.end = max(f.address + self._size(f) for f in self.fields.values())
        cmd_first, cmd_end = regs.span(COMMAND_FIELDS)
        self.writable = {regs.control.address, *range(cmd_first, cmd_end)}
        self._pairs = [
            regs_.address for n in ("control", *COMMAND_FIELDS)
            if (regs_ := getattr(regs, n)).words == 2
        ]

    @staticmethod
    def _size(field: Register | Text) -> int:
        return field.count if isinstance(field, Text) else field.words

    @property
    def count(self) -> int:
        return self.end - self.first

    # ------------------------------------------------------------ reads

    def _put(self, image: list[int], reg: Register, value: float) -> None:
        raw = int(round(value / reg.scale)) & ((1 << reg.bits) - 1)  # wraps like a drive's
        words = [raw] if reg.words == 1 else [raw >> 16, raw & 0xFFFF]
        if reg.words == 2 and self.profile.word_order == "low_first":
            words.reverse()
        at = reg.address - self.first
        image[at : at + reg.words] = words

    def image(self, t_s: float) -> list[int]:
        """Every register first..end-1 at world time `t_s` (one consistent snapshot)."""
        p, table = self.profile, self.table
        native = table.registers(t_s)
        image = [0] * self.count
        put = self._put
        regs = p.registers
        control = Control(native[Reg.CONTROL])
        put(image, regs.control, sum(
            1 << getattr(p.control_bits, n) for n, bit in _CONTROL.items() if bit in control
        ))
        mode = Mode(native[Reg.MODE])
        put(image, regs.mode, getattr(p.modes, mode.name.lower()))
        for name, reg in _NATIVE_CMD.items():
            put(image, getattr(regs, name), _i32(native[reg], native[reg + 1]) / 1000.0)
        status = Status(native[Reg.STATUS])
        put(image, regs.status, sum(
            1 << getattr(p.status_bits, n) for n, bit in _STATUS.items() if bit in status
        ))
        put(image, regs.fault_code, self._fault_codes.get(table.fault, 0))
        counts = table.counts_since_zero(t_s)
        put(image, regs.encoder_counts, counts)
        put(image, regs.position, counts * 360.0 / table.cpr)
        put(image, regs.rate, float(table.rate_dps(t_s)[0]))
        put(image, regs.time, t_s)
        cfg = table.cfg
        for name, text in (("model", cfg.model), ("serial", cfg.serial),
                           ("firmware", cfg.firmware)):
            field = self.fields[name]
            assert isinstance(field, Text)
            at = field.address - self.first
            image[at : at + field.count] = string_registers(text, field.count)
        return image

    # ------------------------------------------------------------ writes

    def write(self, t_s: float, address: int, values: list[int]) -> ExcCodes | None:
        """Apply one write request; None, or the Modbus exception the drive answers."""
        span = set(range(address, address + len(values)))
        if not span <= self.writable:
            return ExcCodes.ILLEGAL_ADDRESS
        if any((a in span) != (a + 1 in span) for a in self._pairs):
            return ExcCodes.ILLEGAL_ADDRESS  # one word of a 32-bit pair: a torn value
        image = self.image(t_s)
        image[address - self.first : address - self.first + len(values)] = values
        p = self.profile
        native = self.table.registers(t_s)
        new: dict[int, int] = {}
        for name in ("control", *COMMAND_FIELDS):
            reg = getattr(p.registers, name)
            if reg.address not in span:
                continue
            if name == "control":
                word = int(p.decode(reg, image, self.first, raw=True))
                new[Reg.CONTROL] = int(sum(
                    (bit for n, bit in _CONTROL.items() if word >> getattr(p.control_bits, n) & 1),
                    Control(0),
                ))
            elif name == "mode":
                value = int(p.decode(reg, image, self.first, raw=True))
                modes = {getattr(p.modes, m.name.lower()): m for m in Mode}
                if value not in modes:
                    return ExcCodes.ILLEGAL_VALUE
                new[Reg.MODE] = int(modes[value])
            else:
                mvalue = int(round(p.decode(reg, image, self.first) * 1000.0))
                if not -(1 << 31) <= mvalue < 1 << 31:
                    return ExcCodes.ILLEGAL_VALUE
                native_reg = _NATIVE_CMD[name]
                new[native_reg] = (mvalue >> 16) & 0xFFFF
                new[native_reg + 1] = mvalue & 0xFFFF
        if not new:
            return None  # only gap registers
        first, last = min(new), max(new)
        block = [new.get(a, native[a]) for a in range(first, last + 1)]
        try:
            self.table.write(t_s, first, block, native)
        except CommandRefusedError:
            return ExcCodes.ILLEGAL_VALUE
        return None
