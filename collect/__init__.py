"""Expert-data collection: drive each clip's ego along its recorded path and log the sensor suite.

Importable as `drivee2e_data.collect`; filled in by the collector issue (sensors, MCAP logs).
"""
