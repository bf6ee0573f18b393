"""Exports for other tools: the nuScenes devkit's table layout and the info pickles that
VAD/UniAD-style training code reads."""
