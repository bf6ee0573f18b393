"""Serve a driving model to `drivee2e evaluate --agent-cmd` from its own Python environment.

Copy this one file next to your model (it needs only the standard library and numpy), then:

    from agent_client import Waypoints, serve

    class MyAgent:
        name = "my-agent"
        sensors = ("CAM_FRONT",)          # cameras by rig name, and/or "LIDAR_TOP"
        image_size = (800, 450)           # or None for 1600x900

        def setup(self, route, rig): ...  # route: waypoints_xy_m, commands, ...; rig: a dict
        def act(self, observation):       # observation.images["CAM_FRONT"] is JPEG bytes;
                                          # .image("CAM_FRONT", size=(W, H)): as the Dataset decodes
            return Waypoints(xy)          # (N, 2) ego frame at 2 Hz, or Control(steer, throttle, brake)

    if __name__ == "__main__":
        serve(MyAgent())

and evaluate with `drivee2e evaluate DATA --agent-cmd "python my_agent.py"`. Or serve a class
by name: `python agent_client.py MODULE:CLASS [--checkpoint F]`.

The protocol (version 1), on the child's stdin and stdout: every message is an 8-byte header
(two big-endian uint32: JSON length, blob length), a UTF-8 JSON object, then the blob bytes.
The JSON's "blobs" list says where each binary field lies: {"path": [...keys], "offset",
"length", "kind": "bytes" | "array", "dtype", "shape"}; arrays are C-ordered little-endian.
Child first sends {"type": "hello", "protocol": 1, "name", "sensors", "image_size"}; then the
harness sends "setup" (answered "ok"), one "step" per 10 Hz step (answered "action" with
"control": {steer, throttle, brake} or "waypoints": [[x, y], ...]), and "close". An answer
{"type": "error", "message"} ends the episode with that message. Anything the model prints
goes to stderr: stdout carries only the protocol.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import struct
import sys
import traceback
from typing import Any, BinaryIO

import numpy as np

PROTOCOL = 1
HEADER = struct.Struct(">II")


class Control:
    def __init__(self, steer: float = 0.0, throttle: float = 0.0, brake: float = 0.0) -> None:
        self.steer, self.throttle, self.brake = float(steer), float(throttle), float(brake)


class Waypoints:
    def __init__(self, xy_m: Any) -> None:
        self.xy_m = np.asarray(xy_m, np.float64)


class Message:
    """A received message's fields as attributes (nested objects too)."""

    def __init__(self, fields: dict[str, Any]) -> None:
        for key, value in fields.items():
            setattr(
                self, key, Message(value) if isinstance(value, dict) and key != "images" else value
            )

    def image(self, camera: str, reduction: int = 1, size: tuple[int, int] | None = None) -> Any:
        """The camera's JPEG decoded to RGB `(H, W, 3)` (needs OpenCV in your environment): with
        `size` (width, height) as the project's Dataset decodes it to that size (the largest
        JPEG reduction that divides the image and keeps `size`, then an area resize: the pixels
        a model trained on `DriveE2EDataset(..., image_size=size)` read); else at 1/`reduction`
        size (1, 2, 4, 8; one that does not divide the size ends in a partial block of padding:
        1600x900 at 1/8 is 113 rows for 112.5)."""
        import cv2

        jpeg = self.images[camera]  # type: ignore[attr-defined]
        if size is not None:
            width, height = _jpeg_size(jpeg)
            fits = [r for r in (8, 4, 2) if width % r == 0 and height % r == 0
                    and width // r >= size[0] and height // r >= size[1]]  # fmt: skip
            reduction = fits[0] if fits else 1
        flags = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2,
                 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}[reduction]  # fmt: skip
        bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), flags)
        if size is not None and (bgr.shape[1], bgr.shape[0]) != tuple(size):
            bgr = cv2.resize(bgr, tuple(size), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(bgr[:, :, ::-1])


def _jpeg_size(jpeg: bytes) -> tuple[int, int]:
    """A JPEG's (width, height) from its frame header (a start-of-frame marker, not C4/C8/CC)."""
    position = 2
    while position + 9 <= len(jpeg) and jpeg[position] == 0xFF:
        marker = jpeg[position + 1]
        if marker == 0xFF:
            position += 1
        elif 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return (int.from_bytes(jpeg[position + 7 : position + 9], "big"),
                    int.from_bytes(jpeg[position + 5 : position + 7], "big"))  # fmt: skip
        else:
            position += 2 + int.from_bytes(jpeg[position + 2 : position + 4], "big")
    raise ValueError("not a JPEG with a frame header")


def encode(document: dict[str, Any]) -> bytes:
    """One message: numpy arrays and bytes anywhere in `document` travel as blobs."""
    blobs: list[dict[str, Any]] = []
    chunks: list[bytes] = []
    offset = 0

    def pack(value: Any, path: list[Any]) -> Any:
        nonlocal offset
        if isinstance(value, dict):
            return {key: pack(item, [*path, key]) for key, item in value.items()}
        if isinstance(value, list | tuple):
            return [pack(item, [*path, k]) for k, item in enumerate(value)]
        if isinstance(value, bytes | np.ndarray):
            if isinstance(value, bytes):
                data, entry = value, {"kind": "bytes"}
            else:
                array = np.ascontiguousarray(value)
                little = array.astype(array.dtype.newbyteorder("<"), copy=False)
                data = little.tobytes()
                entry = {"kind": "array", "dtype": little.dtype.str, "shape": list(array.shape)}
            blobs.append({"path": path, "offset": offset, "length": len(data), **entry})
            chunks.append(data)
            offset += len(data)
            return None
        if isinstance(value, np.generic):
            return value.item()
        return value

    body = pack(document, [])
    body["blobs"] = blobs
    text = json.dumps(body, separators=(",", ":")).encode()
    return HEADER.pack(len(text), offset) + text + b"".join(chunks)


def decode(text: bytes, blob: bytes) -> dict[str, Any]:
    """A message's JSON with its blobs put back (bytes, or numpy arrays)."""
    document = json.loads(text.decode())
    for entry in document.pop("blobs", []):
        data = blob[entry["offset"] : entry["offset"] + entry["length"]]
        if entry["kind"] == "array":
            value: Any = (
                np.frombuffer(data, np.dtype(entry["dtype"])).reshape(entry["shape"]).copy()
            )
        else:
            value = bytes(data)
        target = document
        for key in entry["path"][:-1]:
            target = target[key]
        target[entry["path"][-1]] = value
    return document


def read_message(stream: BinaryIO) -> dict[str, Any] | None:
    header = stream.read(HEADER.size)
    if len(header) < HEADER.size:
        return None
    text_length, blob_length = HEADER.unpack(header)
    text = stream.read(text_length)
    blob = stream.read(blob_length)
    return decode(text, blob)


def action_document(action: Any) -> dict[str, Any]:
    """An agent's return value as an "action" message."""
    if isinstance(action, dict):
        if "waypoints" in action:
            return {
                "type": "action",
                "waypoints": np.asarray(action["waypoints"], np.float64).tolist(),
            }
        return {
            "type": "action",
            "control": {k: float(action.get(k, 0.0)) for k in ("steer", "throttle", "brake")},
        }
    if hasattr(action, "xy_m"):
        return {"type": "action", "waypoints": np.asarray(action.xy_m, np.float64).tolist()}
    if all(hasattr(action, k) for k in ("steer", "throttle", "brake")):
        return {
            "type": "action",
            "control": {k: float(getattr(action, k)) for k in ("steer", "throttle", "brake")},
        }
    raise TypeError(f"act returned {type(action).__name__}: expected Waypoints or Control")


def serve(agent: Any, stdin: BinaryIO | None = None, stdout: BinaryIO | None = None) -> None:
    """Answer the harness until it closes: call `agent.setup` and `agent.act` per message."""
    if stdout is None:
        stdout = os.fdopen(os.dup(1), "wb")
        os.dup2(2, 1)  # the model's own prints go to stderr
        sys.stdout = sys.stderr
    stdin = stdin or sys.stdin.buffer

    def send(document: dict[str, Any]) -> None:
        stdout.write(encode(document))
        stdout.flush()

    size = getattr(agent, "image_size", None)
    send({"type": "hello", "protocol": PROTOCOL, "name": str(getattr(agent, "name", type(agent).__name__)),
          "sensors": list(getattr(agent, "sensors", ())), "image_size": list(size) if size else None})  # fmt: skip
    while True:
        message = read_message(stdin)
        if message is None or message.get("type") == "close":
            return
        try:
            if message["type"] == "setup":
                agent.setup(Message(message["route"]), message.get("rig"))
                send({"type": "ok"})
            elif message["type"] == "step":
                send(action_document(agent.act(Message(message["observation"]))))
            else:
                send({"type": "error", "message": f"unknown message type {message['type']!r}"})
        except Exception as error:  # the harness ends this episode with the reason
            where = traceback.extract_tb(error.__traceback__)[-1]
            send({"type": "error", "message": f"{type(error).__name__}: {error} "
                  f"({os.path.basename(where.filename)}:{where.lineno})"})  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="serve an agent class to drivee2e evaluate")
    parser.add_argument("agent", help="MODULE:CLASS")
    parser.add_argument("--checkpoint", default=None)
    args = parser.parse_args(argv)
    module_name, _, class_name = args.agent.partition(":")
    sys.path.insert(0, os.getcwd())
    agent_class = getattr(importlib.import_module(module_name), class_name)
    serve(agent_class(args.checkpoint) if args.checkpoint else agent_class())


if __name__ == "__main__":
    main()
