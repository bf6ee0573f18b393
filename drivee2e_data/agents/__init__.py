"""Driving policies and their training loops: the constant-velocity baseline and AD-MLP (ego
history and status to the planned waypoints)."""
