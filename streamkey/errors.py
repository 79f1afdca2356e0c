"""The exception tree of streamkey.

StreamkeyError
├── InputError            bad data from outside (a file, a packet, a mapping): exit code 2
│   ├── BVHError          a BVH file that cannot be read; names the line and what was expected
│   ├── AMCError          an ASF/AMC file that cannot be read
│   └── RoleError         joint roles (feet, pelvis, ...) that could not be resolved
└── UsageError            the library or CLI was used wrongly (also a ValueError)
"""

from __future__ import annotations

__all__ = ["StreamkeyError", "InputError", "BVHError", "AMCError", "RoleError", "UsageError"]


class StreamkeyError(Exception):
    """Root of every error streamkey raises on purpose."""


class InputError(StreamkeyError):
    """Input data (file, packet, mapping) is malformed; the message says where and why."""


class BVHError(InputError):
    """A BVH file is malformed: the message names the file, line and what was expected."""


class AMCError(InputError):
    """An ASF or AMC file is malformed: the message names the file, line and what was expected."""


class RoleError(InputError):
    """Some joint roles needed by a method could not be found among the skeleton's joints."""


class UsageError(StreamkeyError, ValueError):
    """A parameter or call is invalid (caller's fault, not the data's)."""
