"""The expert-replay check's record in a bundle (the check itself runs the expert in closed loop:
`agents/expert_check.py`): which rules the log-replay expert broke on a clip, in which mode, at
which frame and with whom. `drivee2e split` leaves flagged clips out of the manifests."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

# the version of the check's rules and expert: a bundle checked by another version counts as
# unchecked, and `drivee2e curate` checks it again
CHECK_VERSION = 1
METADATA_KEY = "expert_check"


@dataclass(frozen=True)
class Flag:
    """One rule the expert broke on a clip: in which mode, at which 10 Hz frame, with whom."""

    mode: str
    rule: str
    frame: int
    partner: str = ""
    detail: str = ""

    def line(self) -> str:
        partner = f" with {self.partner}" if self.partner else ""
        detail = f" ({self.detail})" if self.detail else ""
        return f"{self.rule} at frame {self.frame}{partner}{detail}, {self.mode}"


def record(flags: tuple[Flag, ...]) -> dict[str, Any]:
    """The check's entry in a bundle's metadata."""
    return {"version": CHECK_VERSION, "flags": [asdict(f) for f in flags]}


def recorded_flags(metadata: Mapping[str, Any]) -> tuple[Flag, ...] | None:
    """The flags a bundle's metadata holds, or None when this version has not checked it."""
    entry = metadata.get(METADATA_KEY)
    if not isinstance(entry, Mapping) or entry.get("version") != CHECK_VERSION:
        return None
    return tuple(Flag(**flag) for flag in entry.get("flags", []))
