"""The pybullet side: intersection twins, actor blueprints and one world that replays a clip.

`World` is the one stateful object; everything it draws comes from `IntersectionMap` and `Scenario`.
"""
