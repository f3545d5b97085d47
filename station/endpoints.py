"""Where the instruments are when they are not where station.yaml says: the simulated
bench's endpoints (its state file) as the station's."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from drivers.sim.launcher import BenchEndpoints


@dataclass(frozen=True)
class Endpoints:
    """Where the instruments are, when they are not where station.yaml says (the sim bench)."""

    speed: float
    rate_table: str
    chamber: str
    supply: str
    duts: dict[int, str]
    # role -> the family its twin serves (the station picks `<role>.<family>`)
    families: dict[str, str] = field(default_factory=dict)
    # where the simulated operator reads the station's prompts ('' = nobody simulated)
    operator: str = ""
    # socket -> the inclinometer twin on that socket's fixture (none when the bench has none)
    inclinometers: dict[int, str] = field(default_factory=dict)
    lockstep: bool = False  # the bench's world moves only when the station's clock asks
    control: str = ""  # the bench's control channel (host:port)
    # socket -> the effects the simulated part there carries, when the caller declares them
    # (a model's twin: station/discrepancy_simulate.py); recorded and on the certificate
    part_effects: dict[int, tuple[str, ...]] = field(default_factory=dict)

    @classmethod
    def of_bench(cls, e: BenchEndpoints) -> Endpoints:
        """The simulated bench's endpoints (its state file) as the station's."""
        return cls(
            speed=e.speed, rate_table=e.rate_table, chamber=e.chamber, supply=e.supply,
            duts=dict(e.duts), families=dict(e.families),
            operator=str(e.raw.get("operator", "") or ""),
            inclinometers={int(k): str(v) for k, v in (e.raw.get("inclinometers") or {}).items()},
            lockstep=e.lockstep, control=e.control,
        )

    def address(self, role: str) -> str:
        """The twin's address of a station role in its driver's form ('' if none)."""
        return str(getattr(self, role, "") or "") if role in (
            "rate_table", "chamber", "supply") else ""

    def serves(self, role: str) -> bool:
        """Whether the bench has a twin for a station role (the inclinometer: one on a
        fixture); a role it does not serve must never be reached at station.yaml's address."""
        if role == "inclinometer":
            return bool(self.inclinometers)
        return bool(self.address(role))
