"""indgen: an independent Unitree G1 left-arm session generator (numpy + mcap + zstandard).

Written without reference to g1viz's own simulator; see README.md in this directory.
"""
__version__ = "0.1.0"

import os as _os


def shared_dir():
    """The shared read-only data folder: $G1VIZ_SHARED, else ../shared beside the repository."""
    env = _os.environ.get("G1VIZ_SHARED")
    if env:
        return env
    repo = _os.path.dirname(_os.path.dirname(_os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))))
    return _os.path.join(_os.path.dirname(repo), "shared")
