"""The torch data module: nuScenes-compatible samples read from the collected MCAP logs.

Importable as `drivee2e_data.loaders`; filled in by the loader issue (splits, open-loop metrics).
"""
