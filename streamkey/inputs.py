"""The file boundary shared by every reader: safe opening, a strict number grammar, limits.

`read_text_file` refuses anything but a regular file (a FIFO, device, socket or directory,
also behind a symlink) without blocking, refuses files over `MAX_FILE_BYTES` before reading
them, and turns every OS error into the reader's error class with `PATH: reason`. Numbers
follow one ASCII grammar (`[+-]digits[.digits][e[+-]digits]`): Python's `float()` and
`str.isdigit()` also accept `²`, Arabic-Indic digits, `1_000`, `nan` and `infinity`.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

__all__ = ["MAX_FILE_BYTES", "MAX_HEADER_CHARS", "VALUE_LIMIT", "FRAME_TIME_RANGE",
           "read_text_file", "parse_number", "parse_count", "numbers_only", "display_name",
           "os_reason"]

MAX_FILE_BYTES = 64 * 2**20  # CMU clips are < 10 MiB; parsing costs ~8x the size in memory
MAX_HEADER_CHARS = 2**20  # a BVH hierarchy: ~10,000 joints
VALUE_LIMIT = 1e6  # |channel value|, |offset coordinate|: beyond this FK sums overflow squares
FRAME_TIME_RANGE = (1e-4, 10.0)  # seconds; fps 0.1 .. 10,000

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_COUNT = re.compile(r"[0-9]{1,12}", re.ASCII)
_NUMBER_CHARS = re.compile(r"[0-9eE+\-.\s]*", re.ASCII)


def os_reason(exc: OSError) -> str:
    """A short reason for an OS error, as `ls` would say it."""
    if exc.errno == errno.ENOENT:
        return "no such file"
    if exc.errno == errno.ENOTDIR:
        return "not a directory (a component of the path is a file)"
    if exc.errno == errno.ELOOP:
        return "too many levels of symbolic links"
    return (exc.strerror or str(exc)).lower()


def read_text_file(path: str | os.PathLike[str], kind: str,
                   error: type[Exception]) -> str:
    """UTF-8 text of a regular file of at most `MAX_FILE_BYTES`; else `error('PATH: why')`."""
    p = Path(path)
    what = f"expected {'an' if kind[0] in 'AEIOU' else 'a'} {kind} file"
    try:
        info = os.stat(p)
        if stat.S_ISDIR(info.st_mode):
            raise error(f"{p}: is a directory, {what}")
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{p}: is not a regular file (a FIFO, device or socket), {what}")
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise error(f"{p}: is not a regular file, {what}")
            data = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise error(f"{p}: {os_reason(exc)}") from None
    if len(data) > MAX_FILE_BYTES:
        raise error(f"{p}: larger than the {MAX_FILE_BYTES >> 20} MiB limit for {kind} files")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{p}:{line}: expected UTF-8 text, got undecodable bytes ({exc.reason})"
                    ) from None


def parse_number(word: str) -> float | None:
    """The finite float of `word` under the ASCII number grammar, or None."""
    if not _NUMBER.fullmatch(word):
        return None
    value = float(word)
    return value if abs(value) < float("inf") else None


def parse_count(word: str) -> int | None:
    """A non-negative ASCII integer (at most 12 digits), or None."""
    return int(word) if _COUNT.fullmatch(word) else None


def numbers_only(text: str) -> bool:
    """True if `text` holds nothing but ASCII digits, signs, points, exponents and spaces."""
    return _NUMBER_CHARS.fullmatch(text) is not None


def display_name(text: str) -> str:
    """`text` with undecodable file-name bytes (surrogate escapes) shown as U+FFFD."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
