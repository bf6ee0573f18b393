"""What a closed-loop run is given: the agent, its traffic and clip variant, the recording and
where its network runs (`EvaluationOptions`); what of it makes two runs the same run."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from drivee2e_data.curation.occlusion import Variant


@dataclass(frozen=True)
class EvaluationOptions:
    agent: str = "expert"
    checkpoint: str | None = None
    agent_cmd: str | None = None
    reactive: bool = False
    variant: str = Variant.COMPLETE.value
    min_speed: bool = False
    record: str = ""  # "" (none), "mcap" or "mp4": RUN/records/<clip>.<kind>
    seed: int = 0
    renderer: str = "auto"
    step_timeout_s: float = 30.0
    exact_images: bool = False  # JPEGs at the collection size even for agents that read less
    # the network of a servable agent on one policy server per GPU (evaluate/policy_server.py):
    # "auto" where torch sees a GPU and several workers run, "on", "off"
    policy_server: str = "auto"

    def identity(self) -> dict[str, Any]:
        """What makes two runs the same run (recording, timeouts and where the network runs do
        not change scores)."""
        document = asdict(self)
        for key in ("record", "renderer", "step_timeout_s", "policy_server"):
            document.pop(key)
        return document
