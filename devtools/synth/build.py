"""Every sample file and every expected-findings file, built in memory.

Importing the sample modules registers their files in the catalog; the order of the imports below is
the order of the files (that of sample_pcaps/README.md), in which `python -m devtools.synth` writes them.
"""

from __future__ import annotations

# isort: off
from . import basic_samples, format_samples, trace_samples  # noqa: F401  (imported to register their files)
from . import pd_samples, pd_range_samples, pd_vendor_samples, txn_samples  # noqa: F401
from . import audit_samples  # noqa: F401
from . import edge_samples  # noqa: F401

# isort: on
from .catalog import EXPECTED, INTENTS, PARAMETER_SETS, SAMPLES, STATIC_EXPECTED
from .expect import dumps


def build_all() -> dict[str, bytes]:
    """sample name -> bytes of sample_pcaps/<name>."""
    return {s.name: s.build() for s in SAMPLES}


def build_expected() -> dict[str, str]:
    """sample name -> text of sample_pcaps/expected/<name>.json."""
    out = {}
    for name, findings in STATIC_EXPECTED.items():
        doc = {"file": name, "profiles": [{"profile": "generic", "findings": [list(f) for f in sorted(findings)]}]}
        if name in INTENTS:
            doc |= {k: v for k, v in INTENTS[name]().render(name).items() if k in ("transactions", "loose")}
        out[name] = dumps(doc)
    for name, render in EXPECTED.items():
        out[name] = dumps(render())
    return out


def build_sets() -> dict[str, bytes]:
    """set name -> bytes of sample_pcaps/sets/<name> (intended parameter sets for audit --expect)."""
    return {name: build() for name, build in PARAMETER_SETS.items()}
