"""The masses a robot's structure must have, checked alike for every robot, built in or plug-in.

The simulated structure divides by the mass that moves with the tool (``LumpedMasses.translating_kg``,
sim_backend/plant.py and mechanics.py) and takes the root of the one on each actuator: a Cheope
with all masses at 0 ended a simulated demo in a ZeroDivisionError (858246c refused it for Cheope
alone), and a plug-in robot's masses, read from keys of its own, were not checked at all (an
outside tester's finding). The keys are named by the project's convention that a mass key ends in
``_kg``; a section without such keys is named whole.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import msgspec

from controller.config_schema import ConfigError

if TYPE_CHECKING:
    from controller.core.ports import LumpedMasses


def check_masses(kind: str, section: Any, masses: LumpedMasses) -> None:
    """``robot.<kind>``'s ``masses`` (from its ``section``): more than 0 kg with the tool, at least 0
    on each actuator; a ``ConfigError`` naming the section's mass keys otherwise."""
    tool, actuator = masses.translating_kg, masses.per_actuator_kg
    if not tool > 0.0:  # NaN too
        what = (
            f"the mass that moves with the tool (translating_kg) is {tool:g} kg: it must be more than "
            "0 kg (the simulated structure divides by it)"
        )
    elif not actuator >= 0.0:
        what = (
            f"the mass that moves with each actuator (per_actuator_kg) is {actuator:g} kg: it must be "
            "at least 0 kg"
        )
    else:
        return
    raise ConfigError(f"{_mass_keys(f'robot.{kind}', section)}: {what}")


def _mass_keys(prefix: str, section: Any) -> str:
    """``robot.<kind>.….<name>_kg = value, …`` for every mass key of ``section``, or ``prefix``'s masses."""
    found: list[str] = []

    def walk(table: dict[str, Any], at: str) -> None:
        for name, value in table.items():
            if isinstance(value, dict):
                walk(value, f"{at}.{name}")
            elif name.endswith("_kg"):
                found.append(f"{at}.{name} = {value!r}")

    walk(msgspec.to_builtins(section), prefix)
    return ", ".join(found) or f"the masses of [{prefix}]"
