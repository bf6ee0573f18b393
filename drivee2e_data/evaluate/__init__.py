"""Closed-loop evaluation: the `Agent` protocol, the episode loop that replays a clip around a
driving model, and the runner that scores a split into result tables."""
