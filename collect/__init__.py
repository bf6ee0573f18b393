"""Expert-data collection: drive each clip's ego along its recorded path with the sensor suite
and write one MCAP log per clip, in a local process pool or on Ray, resumably."""
