"""Benchmark metrics as pure functions over tensors: open-loop L2 and collision rate (and, later,
closed-loop infractions and scores)."""
