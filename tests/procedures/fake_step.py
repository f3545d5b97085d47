"""What the engine reads of a step's declarations (procedures.engine.engine.Step), for the tests'
hand-made steps that declare no measurement."""

from __future__ import annotations

from procedures.steps.registry import Declared, StepSettings


class DeclaresNothing:
    settings = StepSettings()

    @classmethod
    def measurements(cls, settings: StepSettings) -> list[Declared]:
        return []

    def expected(self) -> list[Declared]:
        return []
