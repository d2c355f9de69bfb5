"""navsvc: sensor fusion and map matching for vehicles, as a library, commands and a service.

Pure parts: ``fusion`` (the EKF), ``matching`` (online and offline matchers), ``sim``. I/O
around them: ``wire`` (JSON, NMEA, Oncore, traces), ``triplog``, ``api`` (FastAPI), ``cli``.
``session`` is the seam where they meet.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("navsvc")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0"
