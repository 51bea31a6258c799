"""The rotor's predicted wrench (``predicted/wrench``): the rule the node and ``replay`` share.

force.z is the predicted thrust b w^2 (N). torque.z is the reaction torque the rotor puts on the
body (N m), along the rotor frame's z axis (up, the thrust's direction): the propeller's drag
torque kQ w^2 turns the rotor against its spin, the motor holds it, and the motor's stator
takes the opposite, so a rotor turning counter-clockwise seen from above (``spin_direction``
+1, angular velocity along +z) pushes the body clockwise: torque.z = -spin_direction kQ w^2.
Only the propeller's steady drag: the inertial torque J dw/dt of a speed change and the motor's
friction are left out (a few percent at a steady speed; J dw/dt matters only in transients).

kQ is known where the model has the propeller's constants: a physics model (and the physics part
of a hybrid) has CP, rho and D (``physics.params.PlantParams.torque_coefficient``), the first-principles
fallback its nominal kQ. A network model maps commands to speed only: torque.z is then 0, and
a status says so rather than letting a consumer take the 0 for a measurement.
"""

from __future__ import annotations

import math

from ..errors import BadInputError
from .status import WARN, CoreStatus

#: Why torque.z is 0, on diagnostics (the node) and in replay's recording.
NO_TORQUE_MESSAGE = ("torque.z is 0 on predicted/wrench: this model does not know the "
                     "propeller's torque (a physics or hybrid model, or the fallback, does)")


def torque_coefficient(model: object) -> float | None:
    """kQ in propeller drag torque = kQ w^2 (N m s^2/rad^2) of a model of any kind, None when
    the model does not know it (a network)."""
    plant = getattr(model, "plant", None)  # a hybrid's physics part
    params = getattr(plant if plant is not None else model, "params", None)
    kq = getattr(params, "torque_coefficient", None) if params is not None else None
    if kq is None:  # the first-principles fallback states its kQ directly
        kq = getattr(model, "torque_coefficient", None)
    if kq is None or not (math.isfinite(float(kq)) and float(kq) >= 0.0):
        return None
    return float(kq)


def reaction_torque_nm(kq: float | None, speed_rad_s: float, spin_direction: int) -> float:
    """torque.z (N m) on the body for a rotor at ``speed_rad_s``; 0 when kQ is unknown."""
    if kq is None:
        return 0.0
    return -spin_direction * kq * speed_rad_s * speed_rad_s


def check_spin_direction(value: int, where: str) -> int:
    """``value`` if it is +1 or -1; else BadInputError naming ``where`` (node, option)."""
    if isinstance(value, bool) or value not in (1, -1):
        raise BadInputError(f"{where}: spin_direction must be 1 (counter-clockwise seen from "
                            f"above) or -1 (clockwise), got {value!r}")
    return int(value)


def check_rotor_name(value: str, where: str) -> str:
    """A joint name or frame id (``where``: node parameter or option) if it is not blank; else
    BadInputError: a consumer matches the rotor by it."""
    if not value.strip():
        raise BadInputError(f"{where}: must not be empty (the name consumers match the rotor by)")
    return value


def wrench_status(kq: float | None, advertised: bool) -> list[CoreStatus]:
    """A WARN while predicted/wrench is published with a torque.z of 0 for want of kQ; nothing
    otherwise (no wrench without a thrust coefficient: that has a status of its own)."""
    if kq is not None or not advertised:
        return []
    return [CoreStatus("wrench", WARN, NO_TORQUE_MESSAGE, {"torque_coefficient": "none"})]
