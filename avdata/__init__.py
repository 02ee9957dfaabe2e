"""avdata: autonomous-driving data in one format whose every frame and convention is explicit."""

from avdata.errors import AvdataError

__version__ = "0.1.0"

__all__ = ["AvdataError", "__version__"]
