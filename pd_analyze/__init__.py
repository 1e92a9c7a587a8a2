"""pd-analyze: offline analyser of PROFIdrive parameter access in PROFINET IO captures."""

__version__ = "0.1.0"

__all__ = ["Analysis", "analyze"]


def __getattr__(name: str) -> object:
    # The API pulls in pandas: import it on first use, so `pd-analyze dump` starts fast.
    if name in __all__:
        from pd_analyze.analysis import api as analysis

        return getattr(analysis, name)
    raise AttributeError(name)
