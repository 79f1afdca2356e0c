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

The front end is on by default (`DEFAULT_NOISE_CUTOFF_HZ`, 5 Hz), offline and online, in
the library and on every command: the same take with a little sensor noise must get the same
keys. 5 Hz rather than Winter's 6 Hz: on the robustness bench (the shared clips at other
rates, with noise, calibration and stillness added) it meets more goal cells (74 of 96
against 66) with the same online-versus-offline agreement. At 5 Hz the delay is 14 frames
at 120 Hz, 7 at 60 Hz, 4 at 30 Hz (117, 117 and 133 ms), counted in every online event's
latency bound. `noise_cutoff_hz=None` (or 0;
`--noise-cutoff 0` on the command line) turns it off.

`FrontEnd` is the per-stream stage before the features: it unwraps the rotation channels,
low-passes them and the root position, and holds each frame for `delay` frames. The
session-state stage (`segments.SegmentDetector`: calibration holds, still stretches, takes),
run by the pipeline beside the keyframers, sees the same rows with the same delay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import UsageError
from .jit import kernel, warmer
from .motion import Skeleton, reference_lead
from .signal import unwrap_into, unwrap_state

__all__ = ["DEFAULT_NOISE_CUTOFF_HZ", "RECOMMENDED_NOISE_CUTOFF_HZ", "TRUNCATE",
           "gaussian_sigma", "lowpass_kernel", "frequency_response", "fir_into", "LowPass",
           "Rows", "FrontEnd", "smooth", "warm_filters"]

RECOMMENDED_NOISE_CUTOFF_HZ = 5.0  # below Winter's 6 Hz for gait markers: chosen by measurement
# On by default, offline and online alike: the same take with a little sensor noise must get
# the same keys (`noise_cutoff_hz=None` or `--noise-cutoff 0` turns it off).
DEFAULT_NOISE_CUTOFF_HZ: float | None = RECOMMENDED_NOISE_CUTOFF_HZ
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


@kernel
def joint_quaternions(rows: np.ndarray, cols: np.ndarray, axes: np.ndarray, prev: np.ndarray,
                      out: np.ndarray) -> None:
    """Unit quaternions (w, x, y, z) of the 3-rotation joints: joint j composes the angles
    rows[:, cols[j]] (degrees) about the axes axes[j] (0 X, 1 Y, 2 Z), intrinsically, into
    out[:, 4j : 4j + 4]; each on the side of the sphere of the one before it (`prev`, the
    last row's, updated; w = 2 marks a stream start), so the signal has no sign flips."""
    for f in range(rows.shape[0]):
        for j in range(cols.shape[0]):
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
            for k in range(3):
                half = 0.5 * np.radians(rows[f, cols[j, k]])
                c, s = np.cos(half), np.sin(half)
                a = axes[j, k]
                if a == 0:  # (w, x, y, z) * (c, s, 0, 0)
                    w, x, y, z = w * c - x * s, x * c + w * s, y * c + z * s, z * c - y * s
                elif a == 1:  # * (c, 0, s, 0)
                    w, x, y, z = w * c - y * s, x * c - z * s, y * c + w * s, z * c + x * s
                else:  # * (c, 0, 0, s)
                    w, x, y, z = w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s
            if prev[j, 0] <= 1.0 and (w * prev[j, 0] + x * prev[j, 1] + y * prev[j, 2]
                                      + z * prev[j, 3]) < 0.0:
                w, x, y, z = -w, -x, -y, -z
            prev[j, 0], prev[j, 1], prev[j, 2], prev[j, 3] = w, x, y, z
            out[f, 4 * j], out[f, 4 * j + 1], out[f, 4 * j + 2], out[f, 4 * j + 3] = w, x, y, z


@kernel
def joint_angles(quats: np.ndarray, axes: np.ndarray, ref: np.ndarray, cols: np.ndarray,
                 out: np.ndarray) -> None:
    """Angles (degrees) of the quaternions quats[:, 4j : 4j + 4] (normalised here) in joint
    j's intrinsic axis order axes[j], into out[:, cols[j]]: of the two Tait-Bryan triples of
    each rotation, shifted by multiples of 360, the one nearest ref[:, cols[j]] (the raw
    unwrapped angles, so the channels stay as continuous as they came; `ref` may be `out`)."""
    r = np.empty((3, 3))  # the rotation matrix of one joint (scratch)
    for f in range(quats.shape[0]):
        for j in range(axes.shape[0]):
            w, x, y, z = (quats[f, 4 * j], quats[f, 4 * j + 1], quats[f, 4 * j + 2],
                          quats[f, 4 * j + 3])
            n = np.sqrt(w * w + x * x + y * y + z * z)
            w, x, y, z = w / n, x / n, y / n, z / n
            r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (
                x * z + w * y)
            r[1, 0], r[1, 1], r[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (
                y * z - w * x)
            r[2, 0], r[2, 1], r[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (
                x * x + y * y)
            a, b, c = axes[j, 0], axes[j, 1], axes[j, 2]
            e = 1.0 if (b - a) % 3 == 1 else -1.0  # an even (cyclic) order or not
            cb = np.sqrt(r[a, a] * r[a, a] + r[a, b] * r[a, b])  # |cos beta|
            beta = np.arctan2(e * r[a, c], cb)  # accurate near +-90 degrees, unlike asin
            if cb > 1e-12:
                alpha = np.arctan2(-e * r[b, c], r[c, c])
                gamma = np.arctan2(-e * r[a, b], r[a, a])
            else:  # gimbal lock: only alpha +- gamma is known; gamma 0
                alpha = np.arctan2(e * r[c, b], r[b, b])
                gamma = 0.0
            one0, one1, one2 = np.degrees(alpha), np.degrees(beta), np.degrees(gamma)
            two0, two1, two2 = one0 + 180.0, 180.0 - one1, one2 + 180.0
            r0, r1, r2 = ref[f, cols[j, 0]], ref[f, cols[j, 1]], ref[f, cols[j, 2]]
            one0 += 360.0 * np.floor(0.5 + (r0 - one0) / 360.0)
            one1 += 360.0 * np.floor(0.5 + (r1 - one1) / 360.0)
            one2 += 360.0 * np.floor(0.5 + (r2 - one2) / 360.0)
            two0 += 360.0 * np.floor(0.5 + (r0 - two0) / 360.0)
            two1 += 360.0 * np.floor(0.5 + (r1 - two1) / 360.0)
            two2 += 360.0 * np.floor(0.5 + (r2 - two2) / 360.0)
            d1 = (one0 - r0) ** 2 + (one1 - r1) ** 2 + (one2 - r2) ** 2
            d2 = (two0 - r0) ** 2 + (two1 - r1) ** 2 + (two2 - r2) ** 2
            if d2 < d1:
                one0, one1, one2 = two0, two1, two2
            out[f, cols[j, 0]], out[f, cols[j, 1]], out[f, cols[j, 2]] = one0, one1, one2


@kernel
def pack_rows(channels: np.ndarray, rot_cols: np.ndarray, rotations: np.ndarray,
              joint_cols: np.ndarray, axes: np.ndarray, prev: np.ndarray, plain: np.ndarray,
              seq: np.ndarray, time: np.ndarray, rows: np.ndarray) -> None:
    """Rows for the filter (`FrontEnd`): the joints' quaternions and the plain channels
    (filtered), then the channels with their rotations unwrapped, seq and time (carried)."""
    c = channels.shape[1]
    nq = 4 * joint_cols.shape[0]
    w = rows.shape[1] - c - 2
    for f in range(channels.shape[0]):
        for i in range(c):
            rows[f, w + i] = channels[f, i]
        for i in range(rot_cols.shape[0]):
            rows[f, w + rot_cols[i]] = rotations[f, i]
        for i in range(plain.shape[0]):
            rows[f, nq + i] = rows[f, w + plain[i]]
        rows[f, w + c] = seq[f]
        rows[f, w + c + 1] = time[f]
    joint_quaternions(rows[:, w : w + c], joint_cols, axes, prev, rows)


@kernel
def unpack_rows(rows: np.ndarray, joint_cols: np.ndarray, axes: np.ndarray, plain: np.ndarray,
                rot_cols: np.ndarray, channels: np.ndarray, rotations: np.ndarray,
                seq: np.ndarray, time: np.ndarray) -> None:
    """`pack_rows` filtered, back to channels (rotations: their angles nearest the raw
    unwrapped ones), the rotation columns, seq and time."""
    c = channels.shape[1]
    nq = 4 * joint_cols.shape[0]
    w = rows.shape[1] - c - 2
    for f in range(rows.shape[0]):
        for i in range(c):
            channels[f, i] = rows[f, w + i]
        for i in range(plain.shape[0]):
            channels[f, plain[i]] = rows[f, nq + i]
        seq[f] = np.int64(rows[f, w + c])
        time[f] = rows[f, w + c + 1]
    joint_angles(rows, axes, channels, joint_cols, channels)
    for f in range(rows.shape[0]):
        for i in range(rot_cols.shape[0]):
            rotations[f, i] = channels[f, rot_cols[i]]


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
        return self._n - self._c if self._open else 0

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
    across windows), low-pass the rotations and the position channels, give each frame
    `delay` frames later. `noise_cutoff_hz` None or 0: no filter, no delay, raw channels.

    A joint with three rotation channels is filtered as a rotation, not as three angles: its
    unit quaternion (kept on one side of the sphere from frame to frame) is low-passed and
    normalised, and turned back into the angles nearest the raw ones. Euler angles flip
    (a, b, c) -> (a + 180, 180 - b, c + 180) for the same rotation, and mocap solvers do;
    averaging angles across such a flip makes a pose that is neither (a foot turned by up to
    0.7 body heights on the dance takes), averaging quaternions does not. Joints with one
    or two rotation channels, and positions, are filtered as they are.

    `last_seq` is the seq of the last frame put in this window: a decision made on a
    filtered frame f was made when frame f + delay arrived (`arrival`), or at most
    `last_seq` once the window is drained.

    A window's first frame (a stream's, or the first after a long gap) is held until its
    second arrives (the filter holds it longer anyway; off, one frame): a lead frame, the
    reference T-pose a sender of a whole cgspeed BVH file starts with or an all-zero
    dropout (`motion.reference_lead`), is not captured motion. It is dropped (counted in
    `leads`) and the window starts at the next frame, so the take's frames are those of the
    take streamed alone: its jump is neither filtered into the take's first frames nor seen
    by a keyframer. Offline, `motion.without_lead` applies the same rule.
    """

    def __init__(self, skeleton: Skeleton, fps: float,
                 noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> None:
        c = self.n_channels = skeleton.n_channels
        self.rotation_columns = skeleton.rotation_columns().astype(np.int64)
        self.fps = float(fps)
        self.skeleton = skeleton
        self.noise_cutoff_hz = float(noise_cutoff_hz) if noise_cutoff_hz else None
        taps = (np.ones(1) if self.noise_cutoff_hz is None
                else lowpass_kernel(self.noise_cutoff_hz, self.fps))
        self.joint_columns, self.joint_axes = _three_rotation_joints(skeleton)
        used = set(self.joint_columns.ravel().tolist())
        # Filtered as they are: the other rotation channels and the positions.
        self.plain_columns = np.array(
            [i for i in range(c) if i not in used and (i in set(self.rotation_columns.tolist())
                                                       or i in set(skeleton.position_columns()
                                                                   .tolist()))],
            dtype=np.int64)
        # A row in the filter: the joints' quaternions and the plain channels (filtered),
        # then the unwrapped channels, seq and time (carried).
        self.n_quat = 4 * len(self.joint_columns)
        self.width = self.n_quat + len(self.plain_columns)
        self.lowpass: LowPass | None = (LowPass(taps, carry=c + 2) if len(taps) > 1
                                        else None)
        self.delay = 0 if self.lowpass is None else self.lowpass.delay
        self.unwrap_prev: np.ndarray | None = None
        self.unwrap_offset: np.ndarray | None = None
        self.quat_prev = np.full((len(self.joint_columns), 4), 2.0)  # w = 2: none yet
        self.last_seq: int | None = None
        self.leads = 0  # lead frames dropped at the start of a window (all windows)
        self._fresh = True  # no frame of the window passed on yet: lead frames looked for
        self._lead: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # unchecked

    def push(self, seq: np.ndarray, time: np.ndarray, channels: np.ndarray) -> Rows:
        """Put consecutive frames in; returns the frames now complete (maybe none)."""
        if len(seq) == 0 or not self._fresh:
            return self._push(seq, time, channels)
        if self._lead is not None:
            seq, time, channels = (np.concatenate([self._lead[0], seq]),
                                   np.concatenate([self._lead[1], time]),
                                   np.concatenate([self._lead[2], channels]))
            self._lead = None
        while len(seq) >= 2 and reference_lead(self.skeleton, channels[0], channels[1]):
            seq, time, channels = seq[1:], time[1:], channels[1:]
            self.leads += 1
        if len(seq) > 1:
            self._fresh = False
            return self._push(seq, time, channels)
        self._lead = (seq.copy(), time.copy(), channels.copy())  # its successor decides
        self.last_seq = int(seq[-1])
        return self._rows(np.empty((0, self.width + self.n_channels + 2)))

    def _push(self, seq: np.ndarray, time: np.ndarray, channels: np.ndarray) -> Rows:
        n = len(seq)
        cols = self.rotation_columns
        if n == 0:
            return self._rows(np.empty((0, self.width + self.n_channels + 2)))
        rotations = np.empty((n, len(cols)))
        if self.unwrap_prev is None or self.unwrap_offset is None:
            self.unwrap_prev, self.unwrap_offset = unwrap_state(channels[0, cols], None, None)
        unwrap_into(channels, cols, self.unwrap_prev, self.unwrap_offset, rotations)
        self.last_seq = int(seq[-1])
        if self.lowpass is None:
            return Rows(seq, time, channels, rotations)
        rows = np.empty((n, self.width + self.n_channels + 2))
        pack_rows(channels, cols, rotations, self.joint_columns, self.joint_axes,
                  self.quat_prev, self.plain_columns, np.asarray(seq, dtype=np.float64),
                  np.asarray(time, dtype=np.float64), rows)
        return self._rows(self.lowpass.push(rows))

    def drain(self) -> Rows:
        """End of a window: every frame held, the window's last frame repeated."""
        if self._lead is not None:  # a one-frame stream: no successor to check it against
            lead, self._lead, self._fresh = self._lead, None, False
            held = self._push(*lead)  # the frame itself when the filter is off
            if self.lowpass is None:
                return held
        if self.lowpass is None or self.lowpass.pending == 0:
            return self._rows(np.empty((0, self.width + self.n_channels + 2)))
        return self._rows(self.lowpass.drain())

    def _rows(self, out: np.ndarray) -> Rows:
        m = len(out)
        rows = Rows(np.empty(m, dtype=np.int64), np.empty(m), np.empty((m, self.n_channels)),
                    np.empty((m, len(self.rotation_columns))))
        if m:
            unpack_rows(out, self.joint_columns, self.joint_axes, self.plain_columns,
                        self.rotation_columns, rows.channels, rows.rotations, rows.seq,
                        rows.time)
        return rows

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
        self._fresh = True
        self._lead = None

    def reset(self) -> None:
        """A new stream: forget the unwrap and quaternion sign state too."""
        self.restart()
        self.unwrap_prev = None
        self.unwrap_offset = None
        self.quat_prev[:] = 2.0
        self.last_seq = None

    def run(self, channels: np.ndarray) -> Rows:
        """A whole clip as one window (the offline path): push, then drain."""
        channels = np.ascontiguousarray(channels, dtype=np.float64)
        n = len(channels)
        a = self.push(np.arange(n, dtype=np.int64), np.zeros(n), channels)
        b = self.drain()
        self.reset()
        return a if not len(b) else _concat([a, b])


def _concat(parts: list[Rows]) -> Rows:
    return Rows(np.concatenate([r.seq for r in parts]), np.concatenate([r.time for r in parts]),
                np.concatenate([r.channels for r in parts]),
                np.concatenate([r.rotations for r in parts]))


_AXES = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}


def _three_rotation_joints(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Columns (J, 3) and axes (J, 3), in compose order, of the joints with three distinct
    rotation channels."""
    cols, axes = [], []
    assert skeleton.rotation_order is not None
    for j, order in enumerate(skeleton.rotation_order):
        if len(order) == 3 and len(set(order)) == 3:
            cols.append([skeleton.channel_index(j, ch) for ch in order])
            axes.append([_AXES[ch] for ch in order])
    return (np.array(cols, dtype=np.int64).reshape(-1, 3),
            np.array(axes, dtype=np.int64).reshape(-1, 3))


@warmer
def warm_filters() -> None:
    """Compile (or load from the cache) the FIR kernel and the front end's, filtering
    (`pack_rows`, `unpack_rows`: a stream with a noise cut-off) and not."""
    out = np.empty((1, 2))
    fir_into(np.ones((3, 2)), np.array([0.25, 0.5, 0.25]), 1, out)
    cols, axes = np.array([[0, 1, 2]]), np.array([[2, 0, 1]])
    q, e = np.empty((1, 4)), np.empty((1, 3))
    joint_quaternions(np.ones((1, 3)), cols, axes, np.full((1, 4), 2.0), q)
    joint_angles(q, axes, np.ones((1, 3)), cols, e)
    skeleton = Skeleton(["root"], [-1], np.zeros((1, 3)),
                        [["Xposition", "Zrotation", "Xrotation", "Yrotation"]])
    for cutoff in (None, RECOMMENDED_NOISE_CUTOFF_HZ):
        FrontEnd(skeleton, 120.0, cutoff).run(np.zeros((3, 4)))
