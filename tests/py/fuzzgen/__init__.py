"""fuzzgen: a physics-fuzz campaign over indgen sessions (see README.md here)."""
