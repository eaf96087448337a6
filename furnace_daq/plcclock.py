"""The PLC's clock as the log's publish time: epoch + PLC seconds.

The PLC's seconds are the data clock refits cut windows on; the host clock may step, the
PLC's only runs. The epoch is the config's when it gives one, or anchored at the first
reading, and re-anchored (with a /daq/events message) when the PLC clock jumps back, which is
what a restarted PLC does.
"""

from __future__ import annotations

from furnace_model.log.messages import DaqEvent, DaqEventKind


class PlcClock:
    def __init__(self, epoch_ns: int | None = None):
        self._fixed = epoch_ns is not None
        """An epoch from the config is never re-anchored."""
        self._epoch_ns = epoch_ns
        self._last_s: float | None = None

    @property
    def seen(self) -> bool:
        """Whether a reading carried the PLC's clock: the data clock is then the PLC's."""
        return self._last_s is not None

    def publish_ns(self, plc_seconds: float | None, log_ns: int) -> tuple[int, DaqEvent | None]:
        """The publish time of a reading logged at `log_ns` (the log time when it carries no
        PLC clock), and the event to log first when the PLC clock went back."""
        s = plc_seconds
        if s is None:
            return log_ns, None
        reset = None
        if self._last_s is not None and s < self._last_s and not self._fixed:
            reset = DaqEvent(DaqEventKind.PLC_CLOCK_RESET,
                             f"PLC clock went back from {self._last_s:g} s "
                             f"to {s:g} s; publish time re-anchored")
            self._epoch_ns = None
        self._last_s = s
        if self._epoch_ns is None:
            self._epoch_ns = log_ns - int(round(s * 1e9))
        return self._epoch_ns + int(round(s * 1e9)), reset
