"""Benchmark metrics as pure functions over tensors: open-loop L2 and collision rate (and, later,
closed-loop infractions and scores)."""

# the open-loop metrics' conventions (`metrics.openloop`), here, free of torch, so that the
# CLI's arguments name them without importing it
CONVENTIONS = ("stp3", "uniad")
# the planned waypoints' spacing (2 Hz), here for the same reason: the constant-velocity agent
# plans with it in closed-loop workers, where torchmetrics (13 s to import on a GPU host whose
# Lightning brings torchvision) has no use
STEP_S = 0.5
