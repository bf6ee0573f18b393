"""A GL context made through EGL here, at a priority: the variable that asks for it, a context
that draws, and the renderer's images the same bytes as in glcontext's context."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sim import egl_context, gl_context
from drivee2e_data.sim.egl_context import PRIORITY_VARIABLE, Priority

needs_gl = pytest.mark.skipif(not gl_context.gl_available(), reason="no OpenGL context (EGL)")


def test_the_variable_names_the_priority_and_a_bad_value_names_the_variable(monkeypatch):
    monkeypatch.delenv(PRIORITY_VARIABLE, raising=False)
    assert egl_context.requested_priority() is None
    monkeypatch.setenv(PRIORITY_VARIABLE, "LOW")
    assert egl_context.requested_priority() is Priority.LOW
    monkeypatch.setenv(PRIORITY_VARIABLE, "lowest")
    with pytest.raises(DriveE2EError, match=f"{PRIORITY_VARIABLE}='lowest': expected one of high"):
        egl_context.requested_priority()


def test_a_priority_asked_for_is_kept_over_the_pools(monkeypatch):
    monkeypatch.delenv(PRIORITY_VARIABLE, raising=False)
    egl_context.use_priority(Priority.LOW)
    assert egl_context.requested_priority() is Priority.LOW
    monkeypatch.setenv(PRIORITY_VARIABLE, "high")  # the user's
    egl_context.use_priority(Priority.LOW)
    assert egl_context.requested_priority() is Priority.HIGH


class _FakeEGL:
    """eglCreateContext and eglQueryContext of a driver that grants `granted` (None: refuses
    any priority asked for)."""

    def __init__(self, granted: Priority | None) -> None:
        self.granted, self.asked = granted, []

    def eglCreateContext(self, display, config, share, attributes) -> int:
        values = list(attributes)
        self.asked.append(values)
        if egl_context.EGL_CONTEXT_PRIORITY_LEVEL_IMG in values and self.granted is None:
            return 0  # EGL_BAD_ATTRIBUTE, EGL_BAD_ACCESS
        return 77

    def eglQueryContext(self, display, context, attribute, value) -> int:
        value._obj.value = self.granted.egl_value
        return 1


def test_a_refused_priority_still_gives_a_context_of_the_drivers_own():
    granting = _FakeEGL(Priority.LOW)
    assert egl_context._priority_context(granting, 1, 2, Priority.LOW) == (77, Priority.LOW)
    assert len(granting.asked) == 1
    refusing = _FakeEGL(None)
    assert egl_context._priority_context(refusing, 1, 2, Priority.HIGH) == (77, None)
    with_priority, without = refusing.asked
    assert with_priority[-3:] == [egl_context.EGL_CONTEXT_PRIORITY_LEVEL_IMG, 0x3101, 0x3038]
    assert egl_context.EGL_CONTEXT_PRIORITY_LEVEL_IMG not in without
    unasked = _FakeEGL(None)
    assert egl_context._priority_context(unasked, 1, 2, None) == (77, None)  # not offered
    assert len(unasked.asked) == 1


@needs_gl
def test_a_context_made_at_a_priority_draws_and_says_what_it_was_given():
    context, given = egl_context.create(Priority.LOW, device=0)
    try:
        assert given in (None, Priority.LOW)  # None: the driver offers no priorities
        with context:
            framebuffer = context.simple_framebuffer((8, 4))
            framebuffer.use()
            framebuffer.clear(0.2, 0.4, 0.6, 1.0)
            pixels = np.frombuffer(framebuffer.read(components=3), np.uint8).reshape(4, 8, 3)
            framebuffer.release()
        assert pixels[0, 0].tolist() == [51, 102, 153] and (pixels == pixels[0, 0]).all()
    finally:
        context.release()


# a cube 20 m ahead drawn by the GL renderer, its colour, depth and ids hashed (in a process of
# its own: a process's GL context is made once, and released only with every renderer of it)
DRAW_A_CUBE = """
import hashlib, pybullet
from drivee2e_data.sim import egl_context, gl_renderer
from tests.test_gl_renderer import NOON, _look_along_x
client = pybullet.connect(pybullet.DIRECT)
shape = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=[1, 1, 1],
                                   rgbaColor=[1, 0, 0, 1], physicsClientId=client)
pybullet.createMultiBody(0, -1, shape, [20, 0, 1], physicsClientId=client)
renderer = gl_renderer.GLRenderer(pybullet, client, [], NOON)
renderer.sync(1)
rgb, depth, body = renderer.draw(*_look_along_x(pybullet, client), 64, 48, True, 200.0)
assert (body >= 0).any()
print(egl_context.requested_priority(), hashlib.sha256(
    rgb.tobytes() + depth.tobytes() + body.tobytes()).hexdigest())
"""


@needs_gl
def test_the_renderer_draws_the_same_bytes_in_a_low_priority_context():
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    outputs = []
    for priority in ("", "low"):
        environment = {**os.environ, PRIORITY_VARIABLE: priority}
        done = subprocess.run([sys.executable, "-c", DRAW_A_CUBE], cwd=root, env=environment,
                              capture_output=True, text=True, timeout=120)  # fmt: skip
        assert done.returncode == 0, done.stderr
        outputs.append(done.stdout.split())
    (default, default_hash), (low, low_hash) = outputs
    assert (default, low) == ("None", "Priority.LOW") and default_hash == low_hash
