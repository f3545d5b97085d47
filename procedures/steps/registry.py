"""Step types: what a procedure's `steps:` list may name, and the interface each one has.

A step type is a class registered as an entry point in the group `gyrocal.steps`
(`<type name> = "module:Class"` in pyproject.toml), the convention the drivers use. It has

- `Settings`: its pydantic settings model (extra="forbid", numbers finite and bounded); the
  entry of the procedure file, less the keys every entry has (`step`, `timeout_s`,
  `retries`), is validated against it at load, with file:line on any mistake;
- `measurements(settings)`: the measurements it declares (OpenHTF's idea), each with its
  units and the product limit that judges it, or `informational=True` (no limit needed);
  a declared name the product has no limit for is refused at load, and a declared
  measurement a step never sets is NOT_MEASURED on the record;
- `estimate_s(ctx)`, `setup(ctx)`, `main(ctx)`, `cleanup(ctx)` (cleanup always runs).

An instance holds its typed settings as `self.settings` and where it runs as `self.place`
(its condition inside `for_each: condition`, the repeat index inside `repeat: N`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from functools import cache
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from procedures.runtime.conditions import Condition

if TYPE_CHECKING:
    from procedures.runtime.run_context import RunContext

STEP_GROUP = "gyrocal.steps"  # pinned: the entry-point group of step types


class StepSettings(BaseModel):
    """Base of every step type's `Settings` (strict, immutable, finite numbers)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class StepPolicy(BaseModel):
    """Keys every step entry may have besides its settings: how long, how often."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    timeout_s: float = Field(3600.0, gt=0, le=86_400.0,
                             description="station seconds before the step times out (ERROR)")
    retries: int = Field(0, ge=0, le=5, description="extra attempts after an instrument timeout")


# keys every entry may have besides its settings; `informational: [names]` records those of
# the step's declared measurements without needing a product limit for them
COMMON_KEYS = ("step", "informational", *StepPolicy.model_fields)


@dataclass(frozen=True)
class Declared:
    """One measurement a step type declares.

    `limit`: the product limit key that judges it (default: the name). `informational`: no
    limit is needed (recorded, not judged). `per_condition`: set once at each condition of
    the enclosing `for_each`. `optional`: set only when the data allow it (never NOT
    MEASURED, e.g. the stop/table consistency needs a rate-table fit at the same condition).
    """

    name: str
    units: str
    description: str = ""
    limit: str | None = None
    informational: bool = False
    per_condition: bool = False
    optional: bool = False

    @property
    def limit_key(self) -> str:
        return self.limit or self.name


@dataclass(frozen=True)
class Place:
    """Where a step instance runs in the plan."""

    condition: Condition | None = None  # inside for_each: condition
    condition_index: int = 0  # 0 at the first condition of the loop
    previous: Condition | None = None  # the condition before this one (None at the first)
    repeat: int = 0  # inside repeat: N, 0..N-1
    path: str = ""  # where the entry is in the file ("steps.2.steps.0")

    @property
    def condition_name(self) -> str:
        return self.condition.name if self.condition is not None else ""


S = TypeVar("S", bound=StepSettings)


class Provided(StrEnum):
    """What a step leaves for later steps (`StepType.provides`) and what a step needs from
    an earlier one (`StepType.requires`), checked when the procedure is loaded."""

    BIAS = "bias"  # each condition's bias (step bias)
    SCALE_TABLE = "scale_table"  # each condition's rate-table scale (step rate_table)
    SCALE_STOP = "scale_stop"  # each condition's stop-method scale (stop_method, manual_stop)
    FIT = "fit"  # PartRun.fit (step fit)
    PROGRAMMED = "programmed"  # the part compensates its output (program, program_three_axis)
    THREE_AXIS_WINDOWS = "three_axis_windows"  # PartRun.three_axis_windows (step cube_faces)
    FIT_THREE_AXIS = "fit_three_axis"  # PartRun.three_axis_fit (step fit_three_axis)


class StepType(Generic[S]):
    """Base of every step type; see the module docstring."""

    type_name: ClassVar[str] = ""  # set from the entry-point name when loaded
    Settings: ClassVar[type[StepSettings]] = StepSettings
    uses_table: ClassVar[bool] = False  # True: the station must have a rate table
    # what the step leaves for later steps; `requires(settings)` names what must come from
    # an earlier entry
    provides: ClassVar[frozenset[Provided]] = frozenset()
    # the model of what the step writes to record.analysis (or record.verification),
    # procedures/runtime/results.py; None for a step that records measurements only
    Results: ClassVar[type[BaseModel] | None] = None

    def __init__(self, settings: S, place: Place | None = None,
                 policy: StepPolicy | None = None) -> None:
        self.settings: S = settings
        self.place = place or Place()
        self.policy = policy or StepPolicy()
        # the sockets this instance measures (None: every part still running); a step run
        # again for some parts only (procedures.steps.thermal_after) names them
        self.sockets: frozenset[int] | None = None

    # the engine reads these three
    @property
    def name(self) -> str:
        return self.type_name

    @property
    def condition(self) -> str:
        return self.place.condition_name

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        """The measurements this step type declares with these settings."""
        return []

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        """What an earlier entry of the procedure must provide (checked at load)."""
        return set()

    def runs_here(self) -> bool:
        """Does this instance run at its place? (False: left out of the plan, e.g. a step
        set to run at the first condition only)"""
        return True

    def after_condition(self, body: list[StepType[Any]]) -> list[StepType[Any]]:
        """Steps the plan adds after this condition's `body` (the steps of one pass of
        `for_each: condition`, this one among them); none by default."""
        return []

    def follow_up(self) -> list[StepType[Any]]:
        """Steps the engine runs next, once this instance has run (e.g. a condition's
        measurement steps again for parts whose stability failed); none by default."""
        return []

    def expected(self) -> list[Declared]:
        """The declared measurements this instance must set (override to narrow, e.g. only
        at the first condition); what it does not set becomes NOT_MEASURED."""
        return [d for d in self.measurements(self.settings) if not d.optional]

    def estimate_s(self, ctx: RunContext) -> float:
        return 0.0

    def setup(self, ctx: RunContext) -> None:
        return None

    def main(self, ctx: RunContext) -> None:
        return None

    def cleanup(self, ctx: RunContext) -> None:
        return None


class UnknownStepType(LookupError):
    """A procedure names a step type nobody registered."""


@cache
def step_types() -> dict[str, type[StepType[Any]]]:
    """Every registered step type by its type name (entry points of `gyrocal.steps`)."""
    out: dict[str, type[StepType[Any]]] = {}
    for ep in entry_points(group=STEP_GROUP):
        cls = ep.load()
        if not (isinstance(cls, type) and issubclass(cls, StepType)):
            raise TypeError(f"entry point {ep.name} = {ep.value} is not a StepType subclass")
        cls.type_name = ep.name
        out[ep.name] = cls
    return dict(sorted(out.items()))


def step_type(name: str) -> type[StepType[Any]]:
    """The step type registered as `name`; UnknownStepType naming the known ones."""
    types = step_types()
    if name not in types:
        raise UnknownStepType(
            f"unknown step type {name!r}; known: {', '.join(types)} (a new type is "
            f"registered as an entry point in the group {STEP_GROUP})"
        )
    return types[name]


@dataclass
class DeclaredIn:
    """A declared measurement with the step entry that declares it (for load checks)."""

    declared: Declared
    step: str
    path: tuple[str | int, ...] = field(default_factory=tuple)
