"""The sensor suite of the ego: rig calibrations first; cameras, LiDAR, radar and annotations follow."""
