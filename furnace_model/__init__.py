"""The science half: the paper's three-zone furnace model, its exact simulator, the plant
simulator with switchable unmodelled effects, identification and diagnosis.

Pure computation on numpy/scipy/pandas; it reads files into an `Experiment` but never talks
to a PLC, a bus or a socket.
"""

from . import oldpaths

oldpaths.install()
