"""pd-analyze: offline analyser of PROFIdrive parameter access in PROFINET IO captures."""

__version__ = "0.1.0"
