"""drivee2e-data: real intersection traffic to simulated expert data and a closed-loop benchmark.

The data model (`scenario`, `hdmap`), its storage (`store`) and the sources that fill it live here;
the collector and the torch data module are `drivee2e_data.collect` and `drivee2e_data.loaders`.
"""

from drivee2e_data.errors import (
    DriveE2EError,
    MapFormatError,
    ScenarioFormatError,
    SchemaVersionError,
)

__version__ = "0.1.0"

__all__ = [
    "DriveE2EError",
    "MapFormatError",
    "ScenarioFormatError",
    "SchemaVersionError",
    "__version__",
]
