"""The subcommands of `bldc-propulsion`, one module each.

Every module has ``NAME``, ``HELP``, ``DESCRIPTION``, ``add_arguments(parser)`` and
``run(args) -> CommandResult``; shared helpers live in the leaf module ``common``. ``cli``
builds the parser from ``MODULES`` (in this order) and is otherwise only ``main``.
"""

from __future__ import annotations

from types import ModuleType

from . import discrepancy, evaluate, health, import_csv, import_log, info, replay, simulate, train

#: In the order ``bldc-propulsion --help`` lists them: look, make, learn, check, explain, monitor, convert.
MODULES: tuple[ModuleType, ...] = (info, simulate, train, evaluate, replay, discrepancy, health, import_csv,
                                   import_log)
