"""The sensor-noise front end: every frame's joint angles and root position, low-passed before
any feature is computed, the same way offline and online.

Capture noise is white-ish: its power spreads evenly up to the Nyquist frequency, while the
energy of human movement lies almost all below 6-10 Hz (Winter, "Biomechanics and Motor
Control of Human Movement", 2009: residual analysis puts the cut-off of gait marker data at
about 6 Hz). Curvature and speed features differentiate the signal, which multiplies each
frequency's noise by its frequency (once per derivative), so even 0.3 degrees of noise
swamps the second derivative at 120 Hz. A low-pass at a cut-off in Hz removes that noise and
leaves the movement.

The filter is the discrete analogue of the Gaussian (Lindeberg, "Scale-space for discrete
signals", 1990): taps ``e^-t I_n(t)`` with ``t = sigma^2`` frames^2, whose frequency
response is exactly ``exp(t (cos w - 1))`` (w in radians per frame) before truncation:
real, positive and monotone (zero phase, no ringing, no overshoot at a sharp turn, which a
windowed sinc or a Butterworth filter would add), and it keeps its shape at small sigma,
where a sampled continuous Gaussian does not. `sigma` is chosen so that the gain is 50 % at
`cutoff_hz` (the same convention as the Hodrick-Prescott cut-off of `signal.hp_lambda`), so
the filter follows the stream's rate; the taps are truncated at `TRUNCATE` sigma, which makes
the half-width `h` (frames) the filter's delay: the filtered frame f needs frame f + h.

At the ends of a window (a clip, a stream, the stretch between two long gaps) the first and
last frames are repeated h times (edge replication), offline and online alike, so a
filtered clip and a filtered stream are the same numbers, bit for bit: `FrontEnd` is one
streaming object, and the offline path runs the whole clip through it as one block
(`FrontEnd.run`). The one Euro filter (Casiez, Roussel & Vogel, "1 Euro filter", CHI 2012)
needs no lookahead but lags by a speed-dependent amount, which moves keys in time; a
zero-phase filter does not.

`FrontEnd` is the per-stream stage before the features: it unwraps the rotation channels,
low-passes them and the root position, and holds each frame for `delay` frames. A later
session-state stage (calibration holds, still stretches, reported as segments) plugs in
here, seeing the same rows with the same delay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import UsageError
from .jit import kernel, warmer
from .motion import Skeleton
from .signal import unwrap_into, unwrap_state

__all__ = ["DEFAULT_NOISE_CUTOFF_HZ", "TRUNCATE", "gaussian_sigma", "lowpass_kernel",
           "frequency_response", "fir_into", "LowPass", "Rows", "FrontEnd", "smooth",
           "warm_filters"]

DEFAULT_NOISE_CUTOFF_HZ = 6.0  # Winter's cut-off for gait; human motion energy lies below
TRUNCATE = 3.0  # taps kept: +-3 sigma (the dropped tails hold < 0.3 % of the weight)


def _check(cutoff_hz: float, fps: float) -> None:
    if not np.isfinite(cutoff_hz) or cutoff_hz <= 0:
        raise UsageError(f"noise cut-off must be a positive number of Hz, got {cutoff_hz}")
    if not np.isfinite(fps) or fps <= 0:
        raise UsageError(f"frame rate must be positive, got {fps}")


def gaussian_sigma(cutoff_hz: float, fps: float) -> float:
    """Standard deviation (frames) of the discrete Gaussian whose gain is 50 % at
    `cutoff_hz`; 0 when the cut-off is at or above the Nyquist frequency (nothing to do)."""
    _check(cutoff_hz, fps)
    if cutoff_hz >= fps / 2:
        return 0.0
    w = 2.0 * np.pi * cutoff_hz / fps
    return float(np.sqrt(np.log(2.0) / (1.0 - np.cos(w))))


def lowpass_kernel(cutoff_hz: float, fps: float) -> np.ndarray:
    """Taps (2h + 1, symmetric, summing to 1) of the discrete Gaussian low-pass with 50 %
    gain at `cutoff_hz` at `fps`, truncated at `TRUNCATE` sigma; [1.0] when nothing to do."""
    from scipy.special import ive

    sigma = gaussian_sigma(cutoff_hz, fps)
    h = int(np.ceil(TRUNCATE * sigma))
    if h == 0:
        return np.ones(1)
    taps = ive(np.abs(np.arange(-h, h + 1)), sigma * sigma)
    return np.asarray(taps / taps.sum(), dtype=np.float64)


def frequency_response(taps: np.ndarray, freqs_hz: np.ndarray, fps: float) -> np.ndarray:
    """Gain of the symmetric FIR `taps` at `freqs_hz` (real: the filter has zero phase)."""
    h = (len(taps) - 1) // 2
    n = np.arange(-h, h + 1)
    w = 2.0 * np.pi * np.asarray(freqs_hz, dtype=np.float64)[..., None] / fps
    return np.asarray(np.cos(w * n) @ taps)


@kernel
def fir_into(padded: np.ndarray, taps: np.ndarray, width: int, out: np.ndarray) -> None:
    """out[i, j] = sum_k taps[k] padded[i + k, j] for the first `width` columns, summed in k
    order (the same bits for any split of a signal into blocks); the columns after them
    (carried along, not filtered) are copied from the centre row padded[i + h]."""
    h = (taps.shape[0] - 1) // 2
    for i in range(out.shape[0]):
        for j in range(width):
            out[i, j] = taps[0] * padded[i, j]
        for k in range(1, taps.shape[0]):
            t = taps[k]
            for j in range(width):
                out[i, j] += t * padded[i + k, j]
        for j in range(width, out.shape[1]):
            out[i, j] = padded[i + h, j]


_CHUNK = 256  # rows appended to the filter's buffer at a time


class LowPass:
    """The streaming zero-phase FIR over rows of signals: rows in, the rows whose next
    `delay` rows have arrived out. A window's ends repeat its first and last row `delay`
    times. The last `carry` columns ride along unfiltered (a frame's seq and time)."""

    def __init__(self, taps: np.ndarray, carry: int = 0) -> None:
        self.taps = np.ascontiguousarray(taps, dtype=np.float64)
        self.delay = (len(self.taps) - 1) // 2
        self.carry = int(carry)
        self._pad = np.empty((0, 0))  # the window's padded rows from `_lo` on
        self._n = 0  # rows of `_pad` in use
        self._c = 0  # row of `_pad` at the centre of the next output
        self._open = False

    @property
    def pending(self) -> int:
        """Rows received whose output has not been given yet."""
        return self._n - self.delay - self._c if self._open else 0

    def push(self, rows: np.ndarray) -> np.ndarray:
        """Filter the rows that are now complete (possibly none)."""
        rows = np.asarray(rows, dtype=np.float64)
        if len(rows) == 0:
            return np.empty((0, rows.shape[1]))
        if not self._open:
            self._start(rows.shape[1], rows[0])
        if len(rows) <= _CHUNK:
            self._append(rows)
            return self._run()
        out = []  # a long block a chunk at a time: the buffer stays small (same bits)
        for lo in range(0, len(rows), _CHUNK):
            self._append(rows[lo : lo + _CHUNK])
            out.append(self._run())
        return np.concatenate(out)

    def drain(self) -> np.ndarray:
        """End of window: the pending rows, with the last row repeated; then a new window."""
        if not self._open:
            return np.empty((0, self._pad.shape[1]))
        last = self._pad[self._n - 1].copy()
        self._append(np.broadcast_to(last, (self.delay, len(last))))
        out = self._run()
        self.reset()
        return out

    def reset(self) -> None:
        """A new window (nothing pending is given)."""
        self._open = False
        self._n = self._c = 0

    def __getstate__(self) -> dict[str, object]:
        state = dict(self.__dict__)
        if self._open:  # the rows still needed, not the buffer's spare room
            lo = self._c - self.delay
            state.update(_pad=self._pad[lo : self._n].copy(), _n=self._n - lo, _c=self.delay)
        else:
            state.update(_pad=np.empty((0, 0)), _n=0, _c=0)
        return state

    def _start(self, width: int, first: np.ndarray) -> None:
        h = self.delay
        if self._pad.shape[1] != width or len(self._pad) < 4 * h + 64:
            self._pad = np.empty((4 * h + 64, width))
        self._pad[:h] = first
        self._n, self._c, self._open = h, h, True

    def _append(self, rows: np.ndarray) -> None:
        k, h = len(rows), self.delay
        if self._n + k > len(self._pad):
            lo = self._c - h  # rows before it are no longer needed
            keep = self._n - lo
            if keep + k > len(self._pad) // 2:
                grown = np.empty((2 * (keep + k) + 2 * h, self._pad.shape[1]))
                grown[:keep] = self._pad[lo : self._n]
                self._pad = grown
            else:
                self._pad[:keep] = self._pad[lo : self._n]
            self._n, self._c = keep, h
        self._pad[self._n : self._n + k] = rows
        self._n += k

    def _run(self) -> np.ndarray:
        h = self.delay
        m = max(0, self._n - h - self._c)
        out = np.empty((m, self._pad.shape[1]))
        if m:
            lo = self._c - h
            fir_into(self._pad[lo : self._c + m + h], self.taps,
                     self._pad.shape[1] - self.carry, out)
            self._c += m
        return out


def smooth(x: np.ndarray, cutoff_hz: float, fps: float) -> np.ndarray:
    """Signals (frames along axis 0) low-passed at `cutoff_hz`, ends edge-replicated."""
    x = np.asarray(x, dtype=np.float64)
    shape = x.shape
    rows = np.ascontiguousarray(x.reshape(len(x), -1))
    lp = LowPass(lowpass_kernel(cutoff_hz, fps))
    out = np.concatenate([lp.push(rows), lp.drain().reshape(-1, rows.shape[1])])
    return out.reshape(shape)


@dataclass
class Rows:
    """Frames through the front end: `seq`, `time`, `channels` (the model's channel
    layout; rotation columns unwrapped and filtered when the filter is on, raw when off)
    and `rotations` (the unwrapped, filtered rotation columns)."""

    seq: np.ndarray
    time: np.ndarray
    channels: np.ndarray
    rotations: np.ndarray

    def __len__(self) -> int:
        return int(len(self.seq))


class FrontEnd:
    """Per-stream stage before the features: unwrap the rotation channels (state carried
    across windows), low-pass them and the position channels, give each frame `delay`
    frames later. `noise_cutoff_hz` None or 0: no filter, no delay, raw channels.

    `last_seq` is the seq of the last frame put in this window: a decision made on a
    filtered frame f was made when frame f + delay arrived (`arrival`), or at most
    `last_seq` once the window is drained.
    """

    def __init__(self, skeleton: Skeleton, fps: float,
                 noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> None:
        self.n_channels = skeleton.n_channels
        self.rotation_columns = skeleton.rotation_columns().astype(np.int64)
        self.fps = float(fps)
        self.noise_cutoff_hz = float(noise_cutoff_hz) if noise_cutoff_hz else None
        taps = (np.ones(1) if self.noise_cutoff_hz is None
                else lowpass_kernel(self.noise_cutoff_hz, self.fps))
        # Rows in the filter: the channels (rotations unwrapped), then seq and time.
        self.lowpass: LowPass | None = LowPass(taps, carry=2) if len(taps) > 1 else None
        self.delay = 0 if self.lowpass is None else self.lowpass.delay
        self.unwrap_prev: np.ndarray | None = None
        self.unwrap_offset: np.ndarray | None = None
        self.last_seq: int | None = None

    def push(self, seq: np.ndarray, time: np.ndarray, channels: np.ndarray) -> Rows:
        """Put consecutive frames in; returns the frames now complete (maybe none)."""
        n = len(seq)
        cols = self.rotation_columns
        if n == 0:
            return self._rows(np.empty((0, self.n_channels + 2)))
        rotations = np.empty((n, len(cols)))
        if self.unwrap_prev is None or self.unwrap_offset is None:
            self.unwrap_prev, self.unwrap_offset = unwrap_state(channels[0, cols], None, None)
        unwrap_into(channels, cols, self.unwrap_prev, self.unwrap_offset, rotations)
        self.last_seq = int(seq[-1])
        if self.lowpass is None:
            return Rows(seq, time, channels, rotations)
        rows = np.empty((n, self.n_channels + 2))
        rows[:, : self.n_channels] = channels
        rows[:, cols] = rotations
        rows[:, -2] = seq
        rows[:, -1] = time
        return self._rows(self.lowpass.push(rows))

    def drain(self) -> Rows:
        """End of a window: every frame held, the window's last frame repeated."""
        if self.lowpass is None:
            return self._rows(np.empty((0, self.n_channels + 2)))
        return self._rows(self.lowpass.drain())

    def _rows(self, out: np.ndarray) -> Rows:
        channels = np.ascontiguousarray(out[:, : self.n_channels])
        return Rows(out[:, -2].astype(np.int64), out[:, -1].copy(), channels,
                    np.ascontiguousarray(channels[:, self.rotation_columns]))

    def arrival(self, decided_at: int) -> int:
        """The seq of the frame whose arrival made a decision on filtered frame `decided_at`."""
        if self.delay == 0 or self.last_seq is None:
            return decided_at
        return min(decided_at + self.delay, self.last_seq)

    def restart(self) -> None:
        """A new window (after a long gap or a source restart, once drained): the unwrap
        state is kept, the filter starts afresh."""
        if self.lowpass is not None:
            self.lowpass.reset()

    def reset(self) -> None:
        """A new stream: forget the unwrap state too."""
        self.restart()
        self.unwrap_prev = None
        self.unwrap_offset = None
        self.last_seq = None

    def run(self, channels: np.ndarray) -> Rows:
        """A whole clip as one window (the offline path): push, then drain."""
        channels = np.ascontiguousarray(channels, dtype=np.float64)
        n = len(channels)
        a = self.push(np.arange(n, dtype=np.int64), np.zeros(n), channels)
        b = self.drain()
        self.reset()
        if not len(b):
            return a
        return Rows(np.concatenate([a.seq, b.seq]), np.concatenate([a.time, b.time]),
                    np.concatenate([a.channels, b.channels]),
                    np.concatenate([a.rotations, b.rotations]))


@warmer
def warm_filters() -> None:
    """Compile (or load from the cache) the FIR kernel."""
    out = np.empty((1, 2))
    fir_into(np.ones((3, 2)), np.array([0.25, 0.5, 0.25]), 1, out)
