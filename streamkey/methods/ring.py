"""A bounded window of the newest frames of a stream, for the online keyframers.

`RingWindow` holds the rows (one vector per frame, e.g. positions) and times of the last
`capacity` consecutive frames, oldest first, with an amortised O(1) append: rows are written
into a buffer of up to twice the capacity and copied down only when it is full, so the held
rows are always one contiguous view (no wrap-around for the numerical code that reads them).
Frames are numbered by their stream sequence number; `first_seq` is the oldest one held.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["RingWindow"]


class RingWindow:
    """Rows and times of the last `capacity` consecutive frames, oldest first.

    Attributes: `capacity` (most frames held), `width` (values per row), `first_seq`
    (sequence number of the oldest held frame), `dropped_since` (frames dropped off the old
    end since the owner last set it to 0: lets the owner shift indices it keeps into the
    window). Pickled with the held rows only, not the spare buffer.
    """

    capacity: int  # most frames held
    width: int  # values per row
    first_seq: int  # oldest held frame's sequence number
    dropped_since: int  # frames dropped since the owner's last reset of it
    _rows: np.ndarray  # buffer; held rows at [_start, _end)
    _times: np.ndarray  # buffer of times, aligned with _rows
    _start: int  # buffer index of the oldest held row
    _end: int  # buffer index one past the newest held row

    def __init__(self, capacity: int, width: int) -> None:
        self.capacity = capacity
        self.width = width
        self.clear()

    def clear(self) -> None:
        """Forget every row."""
        self._rows = np.empty((0, self.width))
        self._times = np.empty(0)
        self._start = self._end = 0
        self.first_seq = 0
        self.dropped_since = 0

    def __len__(self) -> int:
        return self._end - self._start

    def __getstate__(self) -> dict[str, Any]:
        """The held rows only, not the spare buffer (snapshots stay small)."""
        state = dict(self.__dict__)
        state["_rows"] = self._rows[self._start : self._end].copy()
        state["_times"] = self._times[self._start : self._end].copy()
        state["_start"], state["_end"] = 0, len(self)
        return state

    def extend(self, first_seq: int, rows: np.ndarray, times: np.ndarray) -> None:
        """Append consecutive frames starting at `first_seq`; drop the oldest beyond capacity."""
        k, start, end = len(rows), self._start, self._end
        held = end - start
        if held == 0:
            self.first_seq = first_seq
        if end + k > len(self._rows):
            need = held + k
            size = max(16, min(2 * self.capacity, 2 * need))
            rows_new = np.empty((max(size, need), self.width))
            times_new = np.empty(len(rows_new))
            rows_new[:held] = self._rows[start:end]
            times_new[:held] = self._times[start:end]
            self._rows, self._times = rows_new, times_new
            start, end = 0, held
        self._rows[end : end + k] = rows
        self._times[end : end + k] = times
        self._end = end + k
        drop = held + k - self.capacity
        if drop > 0:
            start += drop
            self.first_seq += drop
            self.dropped_since += drop
        self._start = start

    def rows(self) -> np.ndarray:
        """The held rows, oldest first (a view: valid until the next `extend`)."""
        return self._rows[self._start : self._end]

    def times(self) -> np.ndarray:
        """The held frames' times, oldest first (a view: valid until the next `extend`)."""
        return self._times[self._start : self._end]

    def time(self, seq: int) -> float:
        """Time of held frame `seq`."""
        return float(self._times[self._start + seq - self.first_seq])
