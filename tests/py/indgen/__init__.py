"""indgen: an independent Unitree G1 left-arm session generator (numpy + mcap + zstandard).

Written without reference to g1viz's own simulator; see README.md in this directory.
"""
__version__ = "0.1.0"
