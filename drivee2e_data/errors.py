"""One exception hierarchy for the whole project, rooted in `DriveE2EError`.

Every message names where the problem is (file, row or key, index) and what was expected,
so a user can fix the input without reading the code.
"""

from __future__ import annotations


class DriveE2EError(Exception):
    """Base of every error this project raises on purpose."""


class ScenarioFormatError(DriveE2EError):
    """A scenario, track or signal timeline is malformed (shape, NaN, order, unknown value)."""


class MapFormatError(ScenarioFormatError):
    """An intersection map is malformed (bad polyline, duplicate id, dangling reference)."""


class SchemaVersionError(DriveE2EError):
    """Data on disk was written by a newer schema than this code reads."""


class LogFormatError(DriveE2EError):
    """An MCAP log is incomplete or breaks the contract (a topic missing at a frame, a count off)."""
