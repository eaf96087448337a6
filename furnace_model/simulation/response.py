"""What a simulation returns: sample times, states, the sensed zone temperatures and what
each thermocouple of the model reads, batched over parameter sets (leading axis P).

Callers ask for what they mean (`zones`, `states`, `sensors`, `readings`, `final_state`)
instead of knowing which axis of which matrix holds it. The zone outputs are computed by the
simulation itself; the states, when not asked for up front, and the per-thermocouple
readings are computed on first use, so the identification's batched criterion pays for
nothing it does not read.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Protocol

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from .furnace import Furnace


class Simulated(Protocol):
    """What a response asks of the structure that made it (`ModelStructure`), named here so
    that the result does not depend on its producer."""

    @property
    def label(self) -> str: ...

    @property
    def furnace(self) -> Furnace: ...

    @property
    def has_sensor_offsets(self) -> bool: ...

    def sensor_offsets(self, values: Mapping[str, np.ndarray], t: np.ndarray
                       ) -> np.ndarray: ...


class Response:
    """A simulated run of one structure for P parameter sets at N sample times.

    `zones` (P, N, zones) are the sensed zone temperatures (C x: a lagged sensor's state
    where the structure has one); `sensors` (P, N, thermocouples) add the structure's
    per-thermocouple errors (a drifting thermocouple) to its zone's value, in the furnace's
    thermocouple order (`furnace.sensors`); `readings` are the zone
    temperatures as the mean of a record's good thermocouples reads them, which is what a
    fit compares with the data. No bias or noise: those belong to a plant's thermocouples.
    """

    def __init__(self, t: np.ndarray, zones: np.ndarray, structure: Simulated,
                 values: Mapping[str, np.ndarray], states: np.ndarray | None = None,
                 recompute_states: Callable[[], np.ndarray] | None = None):
        self.t = np.asarray(t, dtype=float)
        self.zones = zones
        self.structure = structure
        self.values = values
        self._states = states
        self._recompute = recompute_states
        self._sensor_offsets: np.ndarray | None = None

    def __len__(self) -> int:
        return self.zones.shape[0]

    def __repr__(self) -> str:
        return (f"Response({self.structure.label}, {len(self)} parameter set(s), "
                f"{self.t.size} samples)")

    @property
    def states(self) -> np.ndarray:
        """All states (P, N, n): the zone temperatures first, then the effects' own."""
        if self._states is None:
            if self._recompute is None:
                raise ValueError("this response was made without its states")
            self._states = self._recompute()
        return self._states

    @property
    def final_state(self) -> np.ndarray:
        """States (P, n) at the last sample time: where a stepped simulation goes on from."""
        return self.states[:, -1]

    def state_at(self, t: float) -> np.ndarray:
        """States (P, n) at the first sample at or after t."""
        return self.states[:, int(np.searchsorted(self.t, t))]

    def zone(self, name: str) -> np.ndarray:
        """One zone's sensed temperature (P, N)."""
        return self.zones[:, :, self.structure.furnace.zones.index(name)]

    @property
    def sensor_offsets(self) -> np.ndarray:
        """The structure's additive errors per thermocouple (P, N, 6); zeros without."""
        if self._sensor_offsets is None:
            self._sensor_offsets = self.structure.sensor_offsets(self.values, self.t)
        return self._sensor_offsets

    @property
    def sensors(self) -> np.ndarray:
        """What each thermocouple of the model reads (P, N, thermocouples), in order."""
        return self.zones[:, :, self.structure.furnace.sensor_zone] + self.sensor_offsets

    def sensor(self, name: str) -> np.ndarray:
        """One thermocouple's reading (P, N), by its name in `furnace.sensors` (`heat_2`)."""
        return self.sensors[:, :, self.structure.furnace.sensors.index(name)]

    def readings(self, good: np.ndarray | None = None, *,
                 weight: np.ndarray | None = None) -> np.ndarray:
        """Zone temperatures (P, N, 3) as the mean of the good thermocouples reads them.

        `good` (N, 6) says which thermocouples gave a reading at each sample (all if None):
        with a drifting one, a zone's reading depends on whether its partner was there. A
        zone with no good thermocouple at a sample gets the zone's value. `weight`:
        `furnace.weights(good)` computed once, for a record read many times (a fit's criterion).
        Without sensor effects this is `zones` itself."""
        if not self.structure.has_sensor_offsets:
            return self.zones
        furnace = self.structure.furnace
        if weight is None:
            weight = furnace.weights(np.ones((self.t.size, len(furnace.sensors)), dtype=bool)
                                     if good is None else good)
        # not kept: a fit's criterion reads each response once, and a kept (P, N, 6) array
        # costs it the memory it would reuse
        off = (self._sensor_offsets if self._sensor_offsets is not None
               else self.structure.sensor_offsets(self.values, self.t)) * weight
        if furnace.thermocouples == (2,) * furnace.n_zones:
            pair = off.reshape(off.shape[0], -1, furnace.n_zones, 2)
            return self.zones + (pair[..., 0] + pair[..., 1])  # a pair's sum, no slow reduce
        return self.zones + furnace.zone_sums(off)

    def __getitem__(self, p: int | slice | np.ndarray) -> Response:
        """The response of some parameter sets only (a P axis kept)."""
        idx = np.atleast_1d(np.arange(len(self))[p])
        vals = {k: np.broadcast_to(v, (len(self),))[idx] for k, v in self.values.items()}
        states = None
        if self._states is not None or self._recompute is not None:
            states = self.states[idx]
        return Response(self.t, self.zones[idx], self.structure, vals, states)

    def to_pandas(self, p: int = 0) -> pd.DataFrame:
        """One parameter set's run as a table: t_min, the zones, then the thermocouples
        (`tc_<sensor>`), as the tabular data contract names them."""
        frame = {"t_min": self.t}
        furnace = self.structure.furnace
        frame.update({z: self.zones[p, :, w] for w, z in enumerate(furnace.zones)})
        frame.update({f"tc_{s}": self.sensors[p, :, i] for i, s in enumerate(furnace.sensors)})
        return pd.DataFrame(frame)
