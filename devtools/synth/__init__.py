"""Deterministic generator of sample PROFINET IO / PROFIdrive captures.

`python -m devtools.synth [OUTDIR]` regenerates every file of sample_pcaps/ and
sample_pcaps/expected/ byte for byte. Nothing here imports the analyser (pd_analyze).
The imports flow one way, each module from those above it:

    net_encode, rpc_encode,       pure encoders: Ethernet/VLAN/SLL/IPv4/UDP, CL DCE/RPC,
    pnio_encode, pd_encode        PNIO records, PROFIdrive parameter records
    encode                        one import point re-exporting every encoder
    capture_files                 frames into pcap, pcapng, gzip bytes
    sim_capture                   clock, hosts, link media, the capture being built
    rpc_session                   CL-RPC calls between a controller and a device
    pnio_session                  PNIO record services and PROFIdrive parameter access over those calls
    expect                        Intent: what a capture is built to contain, rendered to JSON
    fixtures                      shared hosts, sessions, background traffic, standard exchanges
    catalog                       the registries: SAMPLES, INTENTS, STATIC_EXPECTED, EXPECTED
    basic_samples                 samples 1-9 (worked_example ... other_port_response): record services
    format_samples                samples 10-15 (two_interfaces ... truncated_snaplen): formats, link types
    trace_samples                 fault_trace and crafted_strings (notebook, HTML report)
    pd_samples                    PROFIdrive: commissioning, negative responses, B5 and PNIO errors
    pd_range_samples              PROFIdrive: one injected range violation per transaction
    pd_vendor_samples             PROFIdrive: global/DPV1 index, AKD-like and Yaskawa-like drives
    txn_samples                   transactions: interleaved channels, retries and duplicates, timeouts
    edge_samples                  edges: cut writes, channels of one AR, busy drives, padding, whole-request errors
    build                         imports every sample module; build_all(), build_expected()
    __main__                      the command line
    mixed_capture                 a large mixed capture for benchmarks and scale tests
    fault_truth                   what protocol.md 6-7 says the analyser must report of a transaction, decided
                                  from what the generator put on the wire (the fault-rich capture's truth)
    fault_kinds                   the drives' parameters; the requests and answers of each kind of transaction
    fault_actor                   one controller's session with one drive, making transactions of a kind
    fault_rich                    a commissioning capture with faults on every drive (issue #23's shape),
                                  streamed, and its truth (python -m devtools.synth.fault_rich OUT.pcap)
"""
