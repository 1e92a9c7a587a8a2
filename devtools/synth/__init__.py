"""Deterministic generator of sample PROFINET IO / PROFIdrive captures.

Layers: net_encode/rpc_encode/pnio_encode/pd_encode (pure encoders,
re-exported by encode), capture_files (pcap, pcapng, gzip), scenario (clock, hosts, PNIO sessions),
samples (the files in sample_pcaps/). `python -m devtools.synth [OUTDIR]`
regenerates every sample byte for byte.
"""

# The PROFIdrive samples (pd_*.pcap) register themselves in samples.SAMPLES on import.
from . import pd_samples as pd_samples
from . import txn_samples as txn_samples
