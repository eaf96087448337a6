"""The science half: the paper's three-zone furnace model, its exact simulator, the plant
simulator with switchable unmodelled effects, identification and diagnosis.

Pure computation on numpy/scipy/pandas; it reads files into an `Experiment` but never talks
to a PLC, a bus or a socket.
"""

from . import oldpaths

oldpaths.install()

ZONES: tuple[str, str, str] = ("soak", "heat", "preheat")
"""Zone names in the paper's numbering: zone 1 soaking, zone 2 heating, zone 3 preheating."""

BURNERS_PER_ZONE: tuple[int, int, int] = (10, 8, 8)
"""NXB-125 burners in the soaking zone, NXB-300 in the heating and preheating zones."""

SENSORS: tuple[str, ...] = tuple(f"{z}_{i}" for z in ZONES for i in (1, 2))
"""The six thermocouples, two per zone, in register-map order."""
