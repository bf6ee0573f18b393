"""Benchmark metrics as pure functions over tensors: open-loop L2 and collision rate (and, later,
closed-loop infractions and scores)."""

# the open-loop metrics' conventions (`metrics.openloop`), here, free of torch, so that the
# CLI's arguments name them without importing it
CONVENTIONS = ("stp3", "uniad")
