"""Changes a vehicle meets in flight, injected into a simulation from a given time.

A health monitor has to be judged against known truth, so the simulator can change the bench
mid-recording: ``simulate(..., faults=[Fault("propeller_damage", 0.1, 20.0)])`` or
``bldc-propulsion simulate --fault propeller_damage=0.1@20``. The names are the contract's
(interfaces.md, "Changes a vehicle meets in flight"). A fault changes the bench's constants from
its onset on (:func:`apply_fault`); ``motor_heating`` also makes the winding temperature jump
at the onset (:func:`temperature_jump_k`). The simulator splits its integration at the onsets
and carries the state (speed, temperature, charge, polarisation) across, so a faulted run equals
the healthy one up to the first onset. A recording keeps its faults in its rosbag2 metadata
(``custom_data`` key :data:`FAULTS_KEY`, :func:`format_faults`), where ``Recording.faults``
reads them back.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass

from ..errors import BadInputError
from ..physics.params import BenchParams

#: What SIZE means for each fault, with its unit and range (printed by ``simulate --help``).
FAULT_DOCS: dict[str, str] = {
    "propeller_damage": "SIZE in (0, 0.9] is the fractional loss of the propeller's thrust AND "
    "power coefficients (CT and CP): 0.1 = 10 % less of each (a chipped, bent or wrong propeller); "
    "truth/thrust follows the damaged coefficient.",
    "pack_resistance": "SIZE in (1, 20] multiplies the pack's series resistance "
    "(battery_series_resistance_ohm): 2 = twice the instantaneous sag per ampere (ageing, a cold "
    "or damaged cell); the slow polarisation branches are unchanged.",
    "bearing_friction": "SIZE in (1, 50] multiplies the motor's friction torque: the bench's only "
    "friction is a constant (Coulomb) torque Kt * I0 from the no-load current "
    "motor_no_load_current_a, so that current is multiplied (a bearing going, debris).",
    "motor_heating": "SIZE in (0, 150] kelvin the winding runs hotter than the thermal model "
    "expects from the onset on: its temperature jumps by SIZE and the ambient it relaxes toward "
    "rises by SIZE, so it stays about SIZE K hotter (its resistance rises by copper's coefficient, "
    "times the motor_heating effect's strength).",
}

#: SIZE ranges: (lowest, excluded; highest, included), as FAULT_DOCS states them.
FAULT_RANGES: dict[str, tuple[float, float]] = {
    "propeller_damage": (0.0, 0.9),
    "pack_resistance": (1.0, 20.0),
    "bearing_friction": (1.0, 50.0),
    "motor_heating": (0.0, 150.0),
}

#: What SIZE is, in a few words, for error messages.
_SIZE_IS = {
    "propeller_damage": "the fractional loss of CT and CP",
    "pack_resistance": "a factor on the pack's series resistance",
    "bearing_friction": "a factor on the motor's friction torque",
    "motor_heating": "kelvin above the thermal model",
}

#: The rosbag2 ``custom_data`` key a simulated recording keeps its faults under.
FAULTS_KEY = "faults"

_FORM = "expected NAME=SIZE@TIME, e.g. propeller_damage=0.1@20"


def _number(x: object) -> float | None:
    """``x`` as a finite float, or None (bools are not numbers here)."""
    if isinstance(x, bool):
        return None
    try:
        v = float(x)  # type: ignore[arg-type]  # any user value: float() sorts it out, below
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def fault_problem(name: object, size: object, onset_s: object) -> str | None:
    """Why (name, size, onset) is not a fault, or None (numbers may be given as text)."""
    if not isinstance(name, str) or name not in FAULT_RANGES:
        return f"unknown fault {name!r} (known: {', '.join(FAULT_RANGES)})"
    lo, hi = FAULT_RANGES[name]
    s = _number(size)
    if s is None:
        return f"SIZE {size} is not a finite number"
    if not lo < s <= hi:
        return f"SIZE {size} is outside ({lo:g}, {hi:g}], the range of {name} ({_SIZE_IS[name]})"
    t = _number(onset_s)
    if t is None:
        return f"TIME {onset_s} is not a finite number of seconds"
    if t < 0.0:
        return f"TIME {onset_s} is negative (seconds from the start of the recording)"
    return None


@dataclass(frozen=True)
class Fault:
    """A change of the bench from ``onset_s`` (seconds from the recording's start) on; what
    ``size`` means for each ``name``: FAULT_DOCS. Checked when made (BadInputError)."""

    name: str
    size: float
    onset_s: float

    def __post_init__(self) -> None:
        why = fault_problem(self.name, self.size, self.onset_s)
        if why:
            raise BadInputError(f"fault {self.name}={self.size}@{self.onset_s}: {why}")
        # plain floats: equal faults compare, print and store alike however they were made
        object.__setattr__(self, "size", float(self.size))
        object.__setattr__(self, "onset_s", float(self.onset_s))

    @property
    def spec(self) -> str:
        """``NAME=SIZE@TIME``, what :func:`parse_fault` reads back to an equal Fault."""
        return f"{self.name}={_short(self.size)}@{_short(self.onset_s)}"


def _short(x: float) -> str:
    """The shortest text that reads back to the same float (20.0 -> '20', 0.1 -> '0.1')."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def parse_fault(text: str, option: str = "--fault") -> Fault:
    """``NAME=SIZE@TIME`` -> Fault; BadInputError naming ``option``, the text and what is wrong."""
    name, eq, rest = str(text).partition("=")
    size_text, at, time_text = rest.partition("@")
    name, size_text, time_text = name.strip(), size_text.strip(), time_text.strip()
    if not (eq and at and name and size_text and time_text):
        raise BadInputError(f"{option} {text}: {_FORM}")
    why = fault_problem(name, size_text, time_text)
    if why:
        raise BadInputError(f"{option} {text}: {why}")
    return Fault(name, float(size_text), float(time_text))


def format_faults(faults: Iterable[Fault]) -> str:
    """Faults as the recording's metadata keeps them: comma-separated specs ('' for none)."""
    return ",".join(f.spec for f in faults)


def parse_faults(text: str, option: str) -> list[Fault]:
    """:func:`format_faults`'s text back to faults ([] for ''); errors name ``option``."""
    return [parse_fault(part, option) for part in str(text).split(",") if part.strip()]


def apply_fault(p: BenchParams, fault: Fault) -> BenchParams:
    """``p`` with the constants ``fault`` changes (the step's temperature jump aside: see
    :func:`temperature_jump_k`)."""
    s = fault.size
    if fault.name == "propeller_damage":
        return dataclasses.replace(p, propeller_ct=p.propeller_ct * (1.0 - s),
                                   propeller_cp=p.propeller_cp * (1.0 - s))
    if fault.name == "pack_resistance":
        return dataclasses.replace(p, battery_series_resistance_ohm=p.battery_series_resistance_ohm * s)
    if fault.name == "bearing_friction":
        return dataclasses.replace(p, motor_no_load_current_a=p.motor_no_load_current_a * s)
    if fault.name == "motor_heating":
        return dataclasses.replace(p, ambient_temperature_c=p.ambient_temperature_c + s)
    raise AssertionError(f"fault {fault.name!r} has no physics")  # Fault checked the name


def temperature_jump_k(fault: Fault) -> float:
    """How far the winding's temperature jumps at ``fault``'s onset (K): SIZE for motor_heating
    (so it runs SIZE hotter at once, not only after a thermal time constant), else 0."""
    return fault.size if fault.name == "motor_heating" else 0.0
