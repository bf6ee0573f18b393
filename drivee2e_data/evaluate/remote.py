"""An agent in another Python environment: a child process started from a command line,
spoken to over its stdin and stdout in the protocol of `agent_client.py` (which documents it).

A crash, a hang past the step timeout, or an answer that is not an action raises
`AgentFailure` with the reason and the end of the child's stderr; the child is then stopped and
started afresh for the next episode.
"""

from __future__ import annotations

import dataclasses
import os
import selectors
import shlex
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_data.evaluate import agent_client
from drivee2e_data.evaluate.agent import AgentFailure, Observation, Route, Waypoints
from drivee2e_data.logs.writer import rig_document
from drivee2e_data.sensors.rig import Rig
from drivee2e_data.sim.vehicle import Control

STARTUP_TIMEOUT_S = 120.0  # importing torch and loading a model can take a while
STEP_TIMEOUT_S = 30.0
STDERR_TAIL_CHARS = 600
MAX_TEXT_BYTES = 16 << 20  # an action is a few hundred bytes; a header past these is garbage
MAX_BLOB_BYTES = 256 << 20


class RemoteAgent:
    """`command` run as a child process (split like a shell would, no shell)."""

    def __init__(
        self,
        command: str,
        step_timeout_s: float = STEP_TIMEOUT_S,
        startup_timeout_s: float = STARTUP_TIMEOUT_S,
        cwd: Path | None = None,
    ) -> None:
        self.command, self.cwd = shlex.split(command), cwd
        if not self.command:
            raise AgentFailure("--agent-cmd is empty")
        self.step_timeout_s, self.startup_timeout_s = step_timeout_s, startup_timeout_s
        self.process: subprocess.Popen[bytes] | None = None
        self.name, self.sensors, self.image_size = "remote", (), None
        self._start()

    def _start(self) -> None:
        self.stderr = tempfile.TemporaryFile()
        try:
            self.process = subprocess.Popen(
                self.command,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self.stderr,
                cwd=self.cwd,
            )
        except OSError as error:
            raise AgentFailure(f"cannot start {self.command[0]!r}: {error}") from None
        self._buffer = b""
        hello = self._receive(self.startup_timeout_s, "hello")
        if hello.get("type") != "hello" or hello.get("protocol") != agent_client.PROTOCOL:
            self.close()
            raise AgentFailure(
                f"expected a protocol {agent_client.PROTOCOL} hello, got {hello!r:.200}"
            )
        self.name = str(hello.get("name") or "remote")
        self.sensors = tuple(str(s) for s in hello.get("sensors") or ())
        size = hello.get("image_size")
        self.image_size = (int(size[0]), int(size[1])) if size else None

    def setup(self, route: Route, rig: Rig | None) -> None:
        if self.process is None or self.process.poll() is not None:
            self._start()
        self._send({"type": "setup", "route": dataclasses.asdict(route),
                    "rig": rig_document(rig) if rig is not None else None})  # fmt: skip
        answer = self._receive(self.step_timeout_s, "setup")
        if answer.get("type") != "ok":
            raise self._failure(_answer_problem(answer, "ok"))

    def act(self, observation: Observation) -> Control | Waypoints:
        fields = {f.name: getattr(observation, f.name) for f in dataclasses.fields(observation)}
        self._send({"type": "step", "observation": fields})
        answer = self._receive(self.step_timeout_s, f"step {observation.step}")
        if answer.get("type") != "action":
            raise self._failure(_answer_problem(answer, "action"))
        try:
            if "waypoints" in answer:
                return Waypoints(np.asarray(answer["waypoints"], np.float64))
            control = answer["control"]
            return Control(
                float(control["steer"]), float(control["throttle"]), float(control["brake"])
            )
        except (KeyError, TypeError, ValueError) as error:
            raise self._failure(f"malformed action {answer!r:.200} ({error})") from None

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            try:
                self._send({"type": "close"})
                self.process.wait(timeout=5)
            except (AgentFailure, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()
        self.process = None

    def _send(self, document: dict[str, Any]) -> None:
        assert self.process is not None and self.process.stdin is not None
        try:
            self.process.stdin.write(agent_client.encode(document))
            self.process.stdin.flush()
        except (BrokenPipeError, OSError):
            raise self._failure("the agent process closed its input") from None

    def _receive(self, timeout_s: float, what: str) -> dict[str, Any]:
        """One message within `timeout_s`, or AgentFailure."""
        assert self.process is not None and self.process.stdout is not None
        stream = self.process.stdout
        deadline = time.monotonic() + timeout_s
        selector = selectors.DefaultSelector()
        selector.register(stream, selectors.EVENT_READ)
        try:
            needed = agent_client.HEADER.size
            while True:
                if len(self._buffer) >= agent_client.HEADER.size:
                    text_length, blob_length = agent_client.HEADER.unpack(self._buffer[:8])
                    needed = agent_client.HEADER.size + text_length + blob_length
                    if text_length > MAX_TEXT_BYTES or blob_length > MAX_BLOB_BYTES:
                        raise self._failure(
                            f"garbled message during {what} (header announces {text_length} + "
                            f"{blob_length} bytes)"
                        )
                    if len(self._buffer) >= needed:
                        break
                left = deadline - time.monotonic()
                if left <= 0 or not selector.select(left):
                    raise self._failure(f"no answer to {what} within {timeout_s:g} s")
                chunk = os.read(stream.fileno(), 1 << 20)
                if not chunk:
                    code = self.process.wait()
                    raise self._failure(f"the agent process exited (code {code}) during {what}")
                self._buffer += chunk
        finally:
            selector.close()
        text_length = agent_client.HEADER.unpack(self._buffer[:8])[0]
        text = self._buffer[8 : 8 + text_length]
        blob = self._buffer[8 + text_length : needed]
        self._buffer = self._buffer[needed:]
        try:
            return agent_client.decode(text, blob)
        except (ValueError, KeyError, TypeError, IndexError) as error:
            raise self._failure(f"garbled message during {what} ({error})") from None

    def _failure(self, reason: str) -> AgentFailure:
        """Stop the child and say why, with the end of what it wrote to stderr."""
        if self.process is not None:
            if self.process.poll() is None:
                self.process.kill()
            self.process.wait()
            self.process = None
        self.stderr.seek(0)
        tail = self.stderr.read().decode(errors="replace").strip()[-STDERR_TAIL_CHARS:]
        return AgentFailure(f"{reason}" + (f"; its stderr ends: {tail}" if tail else ""))


def _answer_problem(answer: dict[str, Any], expected: str) -> str:
    if answer.get("type") == "error":
        return f"the agent reported: {answer.get('message', '')}"
    return f"expected {expected!r}, got {answer!r:.200}"
